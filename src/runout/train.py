"""The GNS's training task, run by the one Trainer (runout.training.trainer) on CPU, one GPU
and many GPUs (torchrun + DistributedDataParallel).

Each step draws `batch_size` windows per process (at the frame stride: positions K frames
apart; windows of a scene at rest included, runout.gns.windows), perturbs their input
positions with random-walk noise whose velocity std is `noise` times the data's velocity std
(the mean of its x and y std of K-frame differences, m per step), corrects the target
acceleration, and minimises
the squared error of the normalised acceleration over the non-kinematic points with Adam and
the paper's learning rate lr(i) = (1e-4 - 1e-6) 0.1^(i / 5e6) + 1e-6. With pushforward N,
each step first draws n uniformly from 0..N, rolls the model out n steps from the true
windows without gradient, and trains on the window so produced (noise on top) against the
true frame n steps further on. With mirror S, each window is first reflected left-right about
the domain's centre with probability S (runout.gns.windows.mirrored). The random numbers of a
step come from generators seeded by (seed, step, rank), and n from one seeded by (seed, step)
alone, so every process unrolls as many steps, and a run resumed from any checkpoint repeats
exactly what an unbroken run would have done (bitwise on CPU). Under torchrun, the forward goes through the DDP wrapper, which
averages gradients across processes. The Trainer's hooks: log_losses, score_on_valid (best.pt)
and keep_when_due (snapshots), after any given to train(cfg, hooks=...).
"""

from __future__ import annotations

import os
import shutil
import sys
import time
from contextlib import nullcontext
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import torch
import torch.distributed as dist
from torch.nn.parallel import DistributedDataParallel
from tqdm.auto import tqdm

from runout import checks
from runout.dataset import split_trajectories
from runout.defaults import FRAME_DT
from runout.errors import InputError
from runout.gns.checkpoint import read_checkpoint, save_checkpoint, simulator_from_checkpoint
from runout.gns.checkpoint_checks import check_resumable, check_schema
from runout.gns.features import Constraints
from runout.gns.fine_tuning import renormalise, restride, widen_material_features
from runout.gns.rollout import rollout_trajectory
from runout.gns.schema import FeatureSchema
from runout.gns.simulator import GraphNetworkSimulator, Normalisation
from runout.gns.training import masked_loss, pushforward, training_inputs
from runout.gns.windows import TrainingWindows, mirrored
from runout.learned.training_range import measure as measure_ranges
from runout.metrics import compare
from runout.simfiles import read_metadata
from runout.train_settings import (  # noqa: F401  (the settings, re-exported)
    OPTION_NAMES, PUSHFORWARD_LIMITS, SETTING_LIMITS, Limit, TrainConfig, check_settings, onset_at, option_name,
    schedule_phase,
)
from runout.training.average import WeightAverage, last_step_weights
from runout.training.precision import NO_NATIVE_BF16, cpu_has_native_bf16
from runout.training.trainer import Budget, Context, Hook, LogFile, Trainer  # noqa: F401  (Context re-exported)

CHECKPOINT = "checkpoint.pt"
BEST = "best.pt"
LOG = "log.jsonl"
SNAPSHOTS = "snapshots"  # --keep-every: copies of the checkpoint, step-<N>.pt


def learning_rate(step: int, cfg: TrainConfig) -> float:
    i = step + cfg.lr_step_offset
    return (cfg.lr_init - cfg.lr_final) * 0.1 ** (i / cfg.lr_decay_steps) + cfg.lr_final


def train(cfg: TrainConfig, hooks: tuple[Hook, ...] = ()) -> GraphNetworkSimulator:
    """Train (or resume, or fine-tune) and return the trained simulator (rank 0's copy).
    Each of `hooks` is called with the Trainer after every step, before logging,
    validation and saving."""
    ctx = _start_processes(cfg.device)
    try:
        return _train(cfg, ctx, hooks)
    finally:
        if ctx.world > 1:
            dist.destroy_process_group()


def _start_processes(device: str) -> Context:
    world = int(os.environ.get("WORLD_SIZE", "1"))
    rank = int(os.environ.get("RANK", "0"))
    local = int(os.environ.get("LOCAL_RANK", "0"))
    if device == "auto":
        device = f"cuda:{local}" if torch.cuda.is_available() else "cpu"
    elif device == "cuda" and world > 1:
        device = f"cuda:{local}"
    dev = torch.device(device)
    if dev.type == "cuda":
        torch.cuda.set_device(dev)
    if world > 1:
        dist.init_process_group("nccl" if dev.type == "cuda" else "gloo")
    return Context(dev, rank, world)


def _train(cfg: TrainConfig, ctx: Context, hooks: tuple[Hook, ...] = ()) -> GraphNetworkSimulator:
    meta = read_metadata(cfg.data)
    data = TrainingWindows(Path(cfg.data) / "train.npz", ctx.device, material_names=meta.get("material_features"),
                            rest_windows=cfg.rest_windows, frame_dt=float(meta.get("dt", FRAME_DT)))
    simulator, state, cfg = _build(cfg, meta, data)
    cfg = _native_bf16(cfg, ctx)
    data = data.with_stride(simulator.frame_stride)
    data.check_windows(cfg.pushforward)
    if state is None or simulator.data_ranges is None or _data_moved(cfg, state, ctx):  # new data: record what
        simulator.data_ranges = measure_ranges(  # the model learns from
            [m.cpu().numpy() for m in data.material], [t.cpu().numpy() for t in data.particle_type],
            meta, simulator.radius, f"measured on {data.path}",
        )
    simulator.to(ctx.device).train()
    if cfg.compile:  # in place: the module's state_dict keys, and so the checkpoint, stay those of the eager network
        simulator.network.compile(dynamic=True)
    averaged = last_step_weights(simulator, state)
    average = WeightAverage(simulator, cfg.ema, averaged) if cfg.ema > 0 else None
    optimizer = torch.optim.Adam(simulator.parameters(), lr=cfg.lr_init)
    if state:
        optimizer.load_state_dict(state["optimizer"])
        torch.set_rng_state(state["rng"]["torch"])
    task = GnsTask(
        simulator=simulator, model=DistributedDataParallel(simulator) if ctx.world > 1 else simulator,
        optimizer=optimizer, data=data, bounds=torch.tensor(meta["bounds"], dtype=torch.float32, device=ctx.device),
        cfg=cfg, ctx=ctx, log=RunLog(Path(cfg.out), ctx, state["step"] if state else 0), average=average,
    )
    trainer = Trainer(
        task, cfg.steps, hooks=(*hooks, log_losses, score_on_valid, keep_when_due), save_every=cfg.save_every,
        budget=Budget(max_hours=cfg.max_hours if cfg.max_hours > 0 else None), ctx=ctx, label="GNS training",
        progress=cfg.progress, best=state.get("best_valid", float("inf")) if state else float("inf"),
    )
    trainer.run(state["step"] if state else 0)
    task.log.close()
    trainer.conclude()
    if average is not None:  # the model a run gives is the one it saves: the average
        average.copy_to(simulator)
    return simulator.eval()


@dataclass
class GnsTask:
    """The GNS's training task for the Trainer (runout.training.trainer): each step draws a
    batch and takes one Adam step (_train_step), then updates the weight average; its
    checkpoint holds the model (the average with --ema, and the last step's weights as
    train_model), Adam's state, the step, the settings, the RNG and the best validation score."""

    simulator: GraphNetworkSimulator
    model: torch.nn.Module  # the simulator, or its DDP wrapper under torchrun
    optimizer: torch.optim.Optimizer
    data: TrainingWindows
    bounds: torch.Tensor  # [dim, 2] m
    cfg: TrainConfig
    ctx: Context
    log: "RunLog"
    average: WeightAverage | None = None  # --ema: the weight average saved as the model

    @property
    def checkpoint(self) -> Path:
        return Path(self.cfg.out) / CHECKPOINT

    def learning_rate(self, step: int) -> float:
        return learning_rate(step, self.cfg)

    def step(self, step: int) -> torch.Tensor:
        loss = _train_step(self.model, self.simulator, self.optimizer, self.data, self.bounds, self.cfg, step, self.ctx)
        if self.average is not None:
            self.average.update(self.simulator)
        return loss.detach()

    def save(self, trainer: Trainer) -> None:
        """OUT/checkpoint.pt (written atomically); every keep_every steps also a copy in snapshots/."""
        if not self.ctx.writer:
            return
        weights = ({"model": self.average.state_dict(self.simulator), "train_model": self.simulator.state_dict()}
                   if self.average else {})
        path = save_checkpoint(
            self.checkpoint, self.simulator, optimizer=self.optimizer.state_dict(), step=trainer.done,
            train=_settings(self.cfg), rng={"seed": self.cfg.seed, "torch": torch.get_rng_state()},
            best_valid=trainer.best, **weights,
        )
        if self.cfg.keep_every and trainer.done % self.cfg.keep_every == 0:
            keep(path, Path(self.cfg.out) / SNAPSHOTS / f"step-{trainer.done}.pt")

    def save_best(self, trainer: Trainer) -> None:
        """OUT/best.pt: the weights scored (the average with --ema), with the run's settings
        (provenance; --init reads lr_step_offset from them)."""
        with self.average.applied(self.simulator) if self.average else nullcontext(self.simulator) as model:
            save_checkpoint(Path(self.cfg.out) / BEST, model, step=trainer.done, best_valid=trainer.best,
                            train=_settings(self.cfg))


def keep(checkpoint: Path, snapshot: Path) -> None:
    """A copy of the checkpoint just written, itself written atomically (copy, then rename)."""
    snapshot.parent.mkdir(exist_ok=True)
    tmp = snapshot.with_name(snapshot.name + ".tmp")
    shutil.copyfile(checkpoint, tmp)
    os.replace(tmp, snapshot)


def log_losses(trainer: Trainer) -> None:
    """Every log_every steps (and at every save), the mean loss of each group of steps."""
    cfg = trainer.task.cfg
    if trainer.due(cfg.log_every) or trainer.done % cfg.save_every == 0:
        trainer.task.log.losses(trainer.done, trainer.losses, trainer.lr, cfg.log_every, trainer.bar)
        trainer.losses = []


def score_on_valid(trainer: Trainer) -> None:
    """Every valid_every steps, rollouts from rest of the valid split's first scenes (with the
    weight average under --ema); the Trainer keeps the best in best.pt."""
    task, cfg = trainer.task, trainer.task.cfg
    if cfg.valid_every and trainer.done % cfg.valid_every == 0 and task.ctx.writer:
        with task.average.applied(task.simulator) if task.average else nullcontext(task.simulator) as model:
            mse = _valid_rollouts(model, cfg, task.log, trainer.done)
        if mse is not None:
            trainer.score(mse)


def keep_when_due(trainer: Trainer) -> None:
    """Every keep_every steps, the checkpoint, which GnsTask.save keeps a copy of (the Trainer
    saves every save_every steps and at the end)."""
    if trainer.due(trainer.task.cfg.keep_every):
        trainer.save()


def continued_onset(init: Path | None) -> dict:
    """The onset schedule for a run started from INIT (--init): a start trained with an onset
    schedule goes on in the phase it had reached (the campaign's run is deep in its later
    phases), instead of replaying the schedule from its first phase, which draws 40 % of the
    windows from the first frames and made the fine-tune overdrive (docs/training.md,
    fine-tune chunk 1). {} for a fresh start or a start trained without a schedule."""
    if init is None:
        return {}
    ckpt = read_checkpoint(init)
    schedule = ckpt.get("train", {}).get("onset_schedule", ())
    if not schedule:
        return {}
    share, frames = schedule_phase(schedule, int(ckpt.get("step", 0)), schedule[0][1:])
    return {"onset_schedule": ((0, share, frames),)}


def _native_bf16(cfg: TrainConfig, ctx: Context) -> TrainConfig:
    """--bf16 on a CPU without native bfloat16 trains in float32, with a warning: there PyTorch
    multiplies bfloat16 in a generic kernel, 14 times slower than float32 (AVX2-only AMD EPYC,
    measured 2026-12-02), so the option would slow training instead of speeding it."""
    if not cfg.bf16 or ctx.device.type != "cpu" or cpu_has_native_bf16():
        return cfg
    if ctx.writer:
        tqdm.write(NO_NATIVE_BF16)
    return replace(cfg, bf16=False)


def _train_step(model, simulator, optimizer, data, bounds, cfg, step, ctx) -> torch.Tensor:
    sampler, noise_gen = _generators(cfg.seed, step, ctx)
    batch = data.sample(cfg.batch_size, sampler, unrolled_steps(cfg.seed, step, cfg.pushforward), *onset_at(cfg, step))
    batch = mirrored(batch, bounds[0], cfg.mirror, sampler, graphs=cfg.batch_size)
    constraints = Constraints.of(batch.particle_type, bounds, batch.window[:, 0], batch.graph, simulator.point_spacing)
    autocast = torch.autocast(ctx.device.type, dtype=torch.bfloat16) if cfg.bf16 else nullcontext()
    with autocast:  # the model's own rollout from the true window, without gradient (none when batch.unroll is 0)
        window = pushforward(simulator, batch.window, batch.unroll, batch.particle_type, batch.material, constraints,
                             batch.graph)
    held = (batch.held - batch.unroll).clamp(min=0) if cfg.exact_rest and batch.held is not None else None
    noisy, target = training_inputs(simulator, window, batch.future[:, -1], constraints, noise_gen, held)
    with autocast:  # through `model`, the DDP wrapper under torchrun, so gradients synchronise
        predicted = model(noisy, batch.particle_type, batch.material, constraints.bounds, batch.graph, cfg.checkpoint_layers)
    loss = masked_loss(predicted, target, constraints)
    optimizer.zero_grad(set_to_none=True)
    loss.backward()
    optimizer.step()
    return loss


def unrolled_steps(seed: int, step: int, pushforward: int) -> int:
    """Pushforward steps of training step `step`: uniform in 0..pushforward, from a generator
    seeded by (seed, step) only, so every process of a torchrun draws the same number."""
    if pushforward == 0:
        return 0
    key = hash((seed, step)) & 0x7FFF_FFFF_FFFF_FFFF
    return int(torch.randint(pushforward + 1, (1,), generator=torch.Generator().manual_seed(key)))


def _generators(seed: int, step: int, ctx: Context) -> tuple[torch.Generator, torch.Generator]:
    """Window sampler (CPU) and noise generator (training device) for one step and rank."""
    key = hash((seed, step, ctx.rank)) & 0x7FFF_FFFF_FFFF_FFFF
    sampler = torch.Generator().manual_seed(key)
    noise = torch.Generator(device=ctx.device).manual_seed(key ^ 0x5DEECE66D)
    return sampler, noise


def _build(cfg: TrainConfig, meta: dict, data: TrainingWindows):
    """The simulator to train, the resumed training state (or None) and the settings, after
    checking the options against each other and the data's particle types against the
    model's type table."""
    check_settings(cfg, ("frame_stride", "pushforward"))  # the two a run cannot go on with; the rest are the caller's (lr 0 freezes a model)
    _check_conflicts(cfg)
    simulator, state, cfg = _start(cfg, meta, data)
    source = Path(cfg.out) / CHECKPOINT if cfg.resume else cfg.init
    model = f"the model in {source}" if source else "a new model"
    checks.particle_types([t.cpu().numpy() for t in data.particle_type], simulator.schema.particle_types, data.path, model)
    return simulator, state, cfg


def _check_conflicts(cfg: TrainConfig) -> None:
    """InputError for options that would be ignored: --init or --radius with --resume, --radius with --init."""
    if cfg.resume and cfg.init is not None:
        raise InputError(f"--resume continues {Path(cfg.out) / CHECKPOINT} from its own weights and would ignore "
                         f"--init {cfg.init}; give only one of them.")
    if cfg.radius is not None and (cfg.resume or cfg.init is not None):
        raise InputError(f"--radius {cfg.radius:g} m applies to new runs only, and --{'resume' if cfg.resume else 'init'} "
                         "keeps the radius its checkpoint was trained with; leave --radius out.")


RESUME_KEEPS = ("latent", "hidden", "message_passing_steps", "lr_init", "lr_decay_steps")  # network and lr schedule


def resumed_settings(cfg: TrainConfig, given: set[str]) -> TrainConfig:
    """The settings of `runout train --resume`: its checkpoint's network and learning-rate
    schedule hold (RESUME_KEEPS). An option of `given` (the settings named on the command
    line) that asks for another value would be ignored or break the exact continuation, so
    it is refused; a schedule setting left out takes the checkpoint's value, not the default."""
    path = Path(cfg.out) / CHECKPOINT
    ckpt = read_checkpoint(path)
    stored = {**ckpt["network"], **{k: v for k, v in _stored_settings(ckpt).items() if k in RESUME_KEEPS}}
    asked = {**asdict(cfg.network), "lr_init": cfg.lr_init, "lr_decay_steps": cfg.lr_decay_steps}
    for name in RESUME_KEEPS:
        if name in given and name in stored and asked[name] != stored[name]:
            option = option_name(name)
            raise InputError(f"{option} {checks.show(asked[name])} differs from the {checks.show(stored[name])} that {path} "
                             f"was trained with, and --resume continues its network and learning-rate schedule "
                             f"unchanged; leave {option} out or start a new run in another --out.")
    schedule = {k: stored[k] for k in ("lr_init", "lr_decay_steps") if k in stored and k not in given}
    return replace(cfg, **schedule)


def _data_moved(cfg: TrainConfig, state: dict, ctx: Context) -> bool:
    """Whether a resumed run is given another --data than its checkpoint's last session (then
    its training ranges are measured again, and rank 0 says so on stderr)."""
    stored = _stored_settings(state).get("data")
    if stored is None or Path(stored) == Path(cfg.data):
        return False
    if ctx.rank == 0:
        tqdm.write(f"{Path(cfg.out) / CHECKPOINT} was trained on {stored}; its training ranges are measured again "
                   f"over --data {cfg.data}.", file=sys.stderr)
    return True


def _stored_settings(ckpt: dict) -> dict:
    return ckpt["train"] if isinstance(ckpt.get("train"), dict) else {}


def _start(cfg: TrainConfig, meta: dict, data: TrainingWindows):
    """The simulator, training state and settings of a resumed, fine-tuned or new run."""
    out = Path(cfg.out)
    if cfg.resume:
        path = out / CHECKPOINT
        ckpt = read_checkpoint(path)
        simulator = simulator_from_checkpoint(ckpt, path)
        check_resumable(ckpt, simulator, path, TrainConfig)
        if cfg.frame_stride not in (None, simulator.frame_stride):
            raise InputError(
                f"{path} was trained at --frame-stride {simulator.frame_stride}, so it resumes only at that stride; "
                f"leave --frame-stride out or start a new run in another --out."
            )
        check_schema(simulator, data.schema(simulator.schema), path, data.path)
        _check_overburden(cfg, simulator, path)
        offset = ckpt["train"]["lr_step_offset"]
        return simulator, ckpt, replace(cfg, lr_step_offset=offset, frame_stride=simulator.frame_stride)
    if (out / CHECKPOINT).exists():
        raise InputError(f"{out / CHECKPOINT}: already exists; pass --resume to continue it or choose another --out.")
    if cfg.init is not None:
        base = read_checkpoint(cfg.init)
        simulator = simulator_from_checkpoint(base, cfg.init)
        if cfg.frame_stride not in (None, simulator.frame_stride):
            restride(simulator, cfg.frame_stride, _stride_statistics(meta, data, cfg.frame_stride, cfg.noise))
        else:  # --noise is a fraction of this data's velocity std, whatever the base model trained with; the
            # normalisation becomes this data's widened by this noise, the weights adjusted so that training
            # starts from the base's predictions (a noisier base's scales would shrink the targets)
            renormalise(simulator, _stride_statistics(meta, data, simulator.frame_stride, cfg.noise))
        wanted = data.schema(simulator.schema)
        if wanted.material_features != simulator.schema.material_features:
            widen_material_features(simulator, wanted.material_features, cfg.init)
        check_schema(simulator, wanted, cfg.init, data.path)
        _check_overburden(cfg, simulator, cfg.init)
        offset = int(base.get("step", 0)) + base.get("train", {}).get("lr_step_offset", 0)
        return simulator, None, replace(cfg, lr_step_offset=offset, frame_stride=simulator.frame_stride)
    stride = cfg.frame_stride or 1
    stats = _stride_statistics(meta, data, stride, cfg.noise)
    schema = data.schema(FeatureSchema(frame_stride=stride, overburden=cfg.overburden is not False))
    torch.manual_seed(cfg.seed)
    radius = cfg.radius if cfg.radius is not None else float(meta["default_connectivity_radius"])
    return GraphNetworkSimulator(schema, stats, radius, cfg.network), None, replace(cfg, frame_stride=stride)


def _check_overburden(cfg: TrainConfig, simulator: GraphNetworkSimulator, source) -> None:
    """InputError when --overburden / --no-overburden asks for a network input that the
    checkpoint it continues has not (or has): the node encoder's width is fixed by it."""
    if cfg.overburden is not None and cfg.overburden != simulator.schema.overburden:
        has = "has the" if simulator.schema.overburden else "has no"
        raise InputError(f"{source} {has} overburden input, so it trains only "
                         f"{'with' if simulator.schema.overburden else 'without'} it; leave --overburden out "
                         "or start a new run in another --out.")


def _stride_statistics(meta: dict, data: TrainingWindows, stride: int, noise: float) -> Normalisation:
    """Normalisation at `stride` frames per step, with velocity noise of `noise` times the
    mean of the x and y velocity std (m per step)."""
    stats = _statistics(meta, data, stride)
    return Normalisation.from_metadata(stats, noise * noise_scale(stats))


def noise_scale(stats: dict) -> float:
    """The velocity std that --noise is a fraction of: the mean of the x and y std (m per step)."""
    return float(sum(stats["vel_std"]) / len(stats["vel_std"]))


def _statistics(meta: dict, data: TrainingWindows, stride: int) -> dict:
    """The normalisation statistics of a new run: metadata.json's (1-frame differences, as the
    generator measured them) at stride 1, else those of the stride's differences measured now
    on the training data."""
    return meta if stride == 1 else data.with_stride(stride).moments()


def _settings(cfg: TrainConfig) -> dict:
    """The run's settings as plain data, stored in its checkpoints."""
    return {k: (str(v) if isinstance(v, Path) else v) for k, v in asdict(cfg).items()}


def _valid_rollouts(simulator: GraphNetworkSimulator, cfg: TrainConfig, log: "RunLog", step: int) -> float | None:
    """Roll out the first validation trajectories from rest; their mean position MSE (m^2),
    logged (None without a valid split)."""
    path = Path(cfg.data) / "valid.npz"
    if not path.is_file():
        return None
    results = []
    simulator.eval()
    for truth in split_trajectories(cfg.data, "valid", cfg.valid_trajectories):
        predicted = rollout_trajectory(simulator, truth, truth.n_frames, stop_speed=None)  # from rest
        results.append(compare(predicted, truth))
    simulator.train()
    mse = sum(r["position_mse_mean_m2"] for r in results) / len(results)
    runout = sum(abs(r["runout_error"]) for r in results) / len(results)
    log.validation(step, mse, runout)
    return mse


class RunLog:
    """log.jsonl (always) and TensorBoard (when installed), on rank 0.
    On resume, log lines beyond the checkpoint's step are dropped: they are redone."""

    def __init__(self, out: Path, ctx: Context, start: int):
        self.ctx = ctx
        self.file = LogFile(out / LOG)
        self.tensorboard = None
        if not ctx.writer:
            return
        out.mkdir(parents=True, exist_ok=True)
        before = max((float(r.get("wall_s", 0.0)) for r in self.file.keep_until(start)), default=0.0)
        self.tensorboard = _tensorboard_writer(out)
        self.t0 = time.perf_counter() - before  # wall_s counts on across resumed chunks

    def losses(self, step: int, losses: list[torch.Tensor], lr: float, every: int, bar) -> None:
        """Record the mean loss of each group of `every` steps (averaged over processes); the
        last on the progress bar."""
        values = torch.stack(losses)
        if self.ctx.world > 1:
            dist.all_reduce(values)
            values /= self.ctx.world
        if not self.ctx.writer:
            return
        values = values.tolist()
        groups = [values[k : k + every] for k in range(0, len(values), every)]
        first = step - len(values)
        for k, group in enumerate(groups):
            last = min(first + (k + 1) * every, step)
            self._write({"step": last, "loss": sum(group) / len(group), "lr": lr})
            if self.tensorboard:
                self.tensorboard.add_scalar("train/loss", sum(group) / len(group), last)
        bar.set_postfix(loss=f"{values[-1]:.4g}", lr=f"{lr:.3g}")

    def validation(self, step: int, mse: float, runout_error: float) -> None:
        self._write({"step": step, "valid_position_mse_m2": mse, "valid_runout_error": runout_error})
        if self.tensorboard:
            self.tensorboard.add_scalar("valid/position_mse_m2", mse, step)
            self.tensorboard.add_scalar("valid/runout_error", runout_error, step)

    def _write(self, record: dict) -> None:
        self.file.write(**record, wall_s=round(time.perf_counter() - self.t0, 3))

    def close(self) -> None:
        if self.tensorboard:
            self.tensorboard.close()


def _tensorboard_writer(out: Path):
    try:
        from torch.utils.tensorboard import SummaryWriter
    except ImportError:  # tensorboard is optional; log.jsonl is always written
        return None
    return SummaryWriter(str(out / "tensorboard"))
