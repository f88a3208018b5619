"""The neural MPM's training task, run by the one Trainer (runout.training.trainer): windows of
the dataset, a position loss over K chained calls, Adam with an exponential learning-rate
decay, checkpoints written atomically and resumed exactly, held-out rollouts from rest as the
measure (runout.evaluate.heldout).

The loss of a window is the mean squared distance (in cells, (m / cell_size)^2) between the
predicted and the MPM's soil positions over the K calls' K m frames, so the engine learns
from its own predictions as it will be rolled out. The draws of step n come from a generator
seeded with (seed, n): a resumed run draws what an unbroken one would have. The learning rate
falls from lr to lr_final over lr_decay_steps steps (a new run's default: its `steps`), stored
in the checkpoint, so a run resumed with a larger `steps` goes on at lr_final instead of
starting its decay again. A run resumed with another --data list than its last session's
measures its training ranges (data_ranges) again over the new list and says so. A run stops at `steps`, at `max_hours` of wall time, at
`max_cpu_hours` of its own CPU time (the measure of the equal-CPU pilots: what the process
used on every thread, training and validation, over every session of the run), or on Ctrl-C
or SIGTERM, and is validated and saved on the step it ends on. With `ema` > 0 an exponential moving average of the weights
is what is validated and saved as the model (runout.training.average), the last step's
weights kept beside it for the resume. train.log.jsonl holds one row
per event: start, loss (every log_every steps), valid (the measure's dataset, then a row with
`data` for each further dataset) and stop.
"""

from __future__ import annotations

import math
import sys
import time
from contextlib import nullcontext
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

import numpy as np
import torch
from tqdm.auto import tqdm

from runout.defaults import PARTICLE_TYPE_KINEMATIC, PARTICLE_TYPE_SOIL
from runout.errors import InputError
from runout.neural_mpm.checkpoint import read_checkpoint, save_checkpoint
from runout.neural_mpm.engine import NeuralMPM, NeuralMPMConfig
from runout.neural_mpm.settings import TrainSettings
from runout.neural_mpm.windows import WindowSampler
from runout.training.average import WeightAverage, last_step_weights
from runout.training.precision import NO_NATIVE_BF16, cpu_has_native_bf16
from runout.train_settings import motion_exponents
from runout.training.trainer import Budget, Hook, LogFile, Trainer

CHECKPOINT = "checkpoint.pt"
BEST = "best.pt"
LOG = "train.log.jsonl"


def learning_rate(step: int, s: TrainSettings) -> float:
    """lr decayed exponentially from s.lr at step 0 to s.lr_final at s.lr_decay_steps (None:
    s.steps), constant after."""
    span = s.lr_decay_steps or s.steps
    return s.lr * (s.lr_final / s.lr) ** (min(step, span) / span)


def window_loss(engine: NeuralMPM, window, calls: int, front_weight: float = 0.0,
                toe_weight: float = 0.0) -> torch.Tensor:
    """Mean squared soil position error over the window's frames, in cells squared; with
    front_weight, plus that weight times the fronts' term (front_term); with toe_weight, plus
    that weight times the toes' term (toe_term)."""
    pred = engine.advance(window.x, window.velocities, window.points, calls)
    soil = ~window.points.fixed
    cell = engine.config.cell_size
    err = (pred[:, soil] - window.targets[:, soil]) / cell
    squared = (err ** 2).sum(-1)
    loss = squared.mean()
    scene = window.points.scene[soil]
    if front_weight > 0:
        loss = loss + front_weight * front_term(pred[:, soil, 0] / cell, window.targets[:, soil, 0] / cell, scene,
                                                window.points.batch)
    if toe_weight > 0:
        loss = loss + toe_weight * toe_term(squared, window.targets[:, soil, 0], scene, window.points.batch)
    return loss


TOE_SHARE = 0.05  # the toes of toe_term: each side's outermost 5 % of a scene's soil, by true x


def toe_term(squared: torch.Tensor, x_true: torch.Tensor, scene: torch.Tensor, batch: int,
             share: float = TOE_SHARE) -> torch.Tensor:
    """Mean over scenes of the mean squared position error of the points in each side's toe,
    summed over the two sides: squared [frames, P] each soil point's squared error (cells^2),
    x_true [frames, P] its true x, scene [P] its scene in a batch of `batch`. A frame's toe on
    the right is the points whose true x is at or beyond the scene's (1 - share) quantile, on
    the left at or below its `share` quantile. Unlike the farthest point (front_term), each
    point is still compared with its own true position, so the term weights the toes without
    rewarding a narrower spread."""
    total = squared.new_zeros(())
    used = 0
    for b in range(batch):
        mine = scene == b
        if not bool(mine.any()):
            continue
        x, err = x_true[:, mine], squared[:, mine]
        edges = torch.quantile(x, torch.tensor([share, 1.0 - share], dtype=x.dtype), dim=1)  # [2, frames]
        for toe in (x <= edges[0, :, None], x >= edges[1, :, None]):
            total = total + (err * toe).sum() / toe.sum()
        used += 1
    return total / max(used, 1)


def front_term(x: torch.Tensor, x_true: torch.Tensor, scene: torch.Tensor, batch: int) -> torch.Tensor:
    """Mean over scenes and frames of the squared differences between the predicted and the
    true largest x and between their smallest: x, x_true [frames, P] (in cells) of the soil
    points, scene [P] each point's scene in a batch of `batch`. The runout fronts (L_f, the
    farthest point) are a handful of points that the mean over all points barely weighs; this
    term's gradient reaches the point that is the predicted front."""
    index = scene.expand(x.shape[0], -1)
    total = x.new_zeros(())
    for reduce in ("amax", "amin"):
        empty = x.new_zeros(x.shape[0], batch)
        front = empty.scatter_reduce(1, index, x, reduce, include_self=False)
        front_true = empty.scatter_reduce(1, index, x_true, reduce, include_self=False)
        total = total + ((front - front_true) ** 2).mean()
    return total


def training_state(optimizer, step: int, cpu_seconds: float, best: float, settings: TrainSettings) -> dict:
    return {"optimizer": optimizer.state_dict(), "step": step, "cpu_seconds": cpu_seconds, "best": best,
            "train": asdict(settings)}


def train(settings: TrainSettings, config: NeuralMPMConfig | None = None, resume: bool = False,
          hooks: tuple[Hook, ...] = ()) -> NeuralMPM:
    """Train (or resume) the run in settings.out; returns the engine at the last step. The
    run ends validated and saved, whatever ends it (steps, time, a hook, a signal: then
    Interrupted). Each of `hooks` is called with the Trainer after every step, before logging,
    validation and saving."""
    torch.set_num_threads(settings.threads)
    run = Run.start(settings, config, resume)
    trainer = Trainer(
        run, run.settings.steps, hooks=(*hooks, log_losses, validate_when_due, log_stop), save_every=settings.save_every,
        budget=Budget(settings.max_hours, settings.max_cpu_hours, run.cpu_before), label="neural MPM",
        progress=settings.progress, best=run.best,
    )
    trainer.run(run.start_step)
    trainer.conclude()
    if run.average is not None:  # the engine a run gives is the one it saves: the average
        run.average.copy_to(run.engine)
    return run.engine


@dataclass
class Run:
    """The neural MPM's training task: the engine, Adam, the data, the held-out scenes, the
    step it starts from, the best held-out error and the CPU time (s) of its earlier sessions."""

    settings: TrainSettings
    engine: NeuralMPM
    optimizer: torch.optim.Optimizer
    sampler: WindowSampler
    truths: list
    log: LogFile
    start_step: int = 0
    best: float = math.inf
    cpu_before: float = 0.0
    extra: dict = field(default_factory=dict)  # dataset -> held-out scenes of the other datasets (logged, not the measure)
    average: WeightAverage | None = None  # --ema: the weight average validated and saved as the model

    def __post_init__(self):
        self.logged_at = time.monotonic()  # of the last loss row

    @classmethod
    def start(cls, settings: TrainSettings, config: NeuralMPMConfig | None, resume: bool) -> "Run":
        out = Path(settings.out)
        if not resume and (out / CHECKPOINT).exists():
            raise InputError(f"{out / CHECKPOINT}: already exists; pass --resume to continue it or choose another --out.")
        out.mkdir(parents=True, exist_ok=True)
        state = read_checkpoint(out / CHECKPOINT) if resume and (out / CHECKPOINT).is_file() else None
        settings = native_bf16(with_schedule(settings, state, out / CHECKPOINT))
        config = NeuralMPMConfig.from_dict(state["config"]) if state is not None else config or NeuralMPMConfig()
        init = read_checkpoint(settings.init) if state is None and settings.init else None
        if init is not None:  # the file's engine; only how its input velocities are sharpened may change
            config = replace(NeuralMPMConfig.from_dict(init["config"]), velocity_sweeps=config.velocity_sweeps)
        sampler = WindowSampler.from_splits(datasets(settings), "train", config.history, config.material_width,
                                            shares(settings)).weight_by_motion(
                                                motion_exponents(settings.motion_weighting, len(datasets(settings))))
        if config.velocity_scale <= 0:  # a new run: the unit of velocity from its data
            config = replace(config, velocity_scale=sampler.velocity_statistics()["scale"])
        with torch.random.fork_rng():  # the initial weights follow the run's seed
            torch.manual_seed(settings.seed)
            engine = NeuralMPM(config)
        optimizer = torch.optim.Adam(engine.parameters(), lr=settings.lr)
        engine.data_ranges = trained_ranges(settings, sampler, state, out / CHECKPOINT)
        run = cls(settings, engine, optimizer, sampler, _heldout(settings), LogFile(out / LOG), extra=_heldout_extra(settings))
        averaged = None
        if init is not None:
            engine.load_state_dict(init["model"])
            engine.data_ranges = union_ranges(engine.data_ranges, init.get("data_ranges"))
        if state is not None:
            engine.load_state_dict(state["model"])
            averaged = last_step_weights(engine, state)
            optimizer.load_state_dict(state["optimizer"])
            run.start_step, run.cpu_before, run.best = state["step"], state["cpu_seconds"], state["best"]
            run.log.keep_until(run.start_step)  # the rows of steps after the checkpoint's are redone
        if settings.ema > 0:
            run.average = WeightAverage(engine, settings.ema, averaged)
        run.log.write(event="start", step=run.start_step, config=config.as_dict(), settings=asdict(settings),
                      parameters=sum(p.numel() for p in engine.parameters()), train_scenes=len(sampler))
        return run

    @property
    def checkpoint(self) -> Path:
        return Path(self.settings.out) / CHECKPOINT

    def learning_rate(self, step: int) -> float:
        return learning_rate(step, self.settings)

    def step(self, step: int) -> float:
        """Training step `step`: a batch of windows drawn by its own generator, one Adam step; the loss."""
        s = self.settings
        generator = torch.Generator().manual_seed(s.seed * 1_000_003 + step)
        span = s.calls * self.engine.config.frames_per_call
        window = self.sampler.draw(s.batch_size, span, s.rest_share, s.mirror_share, generator,
                                   s.noise * self.engine.config.velocity_scale)
        with self.engine.bfloat16(s.bf16):
            loss = window_loss(self.engine, window, s.calls, s.front_loss, s.toe_loss)
        self.optimizer.zero_grad(set_to_none=True)
        loss.backward()
        self.optimizer.step()
        if self.average is not None:
            self.average.update(self.engine)
        return loss.item()

    def scored(self):
        """The engine as validated and saved: with the weight average inside the block under --ema."""
        return self.average.applied(self.engine) if self.average is not None else nullcontext(self.engine)

    def validate(self, trainer: Trainer) -> float:
        """The held-out scenes from rest (the weight average's under --ema), logged; the
        measure's position error (m)."""
        with self.scored() as engine:
            result = evaluate(engine, self.truths)
            self.log.write(event="valid", step=trainer.done, cpu_hours=trainer.budget.cpu_seconds() / 3600,
                           **_headline(result))
            for data, truths in self.extra.items():
                scores = _headline(evaluate(engine, truths))
                self.log.write(event="valid", data=data, step=trainer.done,
                               cpu_hours=trainer.budget.cpu_seconds() / 3600, **scores)
        return result["position_error_m"]

    def save(self, trainer: Trainer, name: str = CHECKPOINT) -> None:
        """The checkpoint (atomically): the model (the average under --ema, and then the last
        step's weights as train_model) and the state to resume."""
        state = training_state(self.optimizer, trainer.done, trainer.budget.cpu_seconds(), trainer.best, self.settings)
        if self.average is not None:
            state["train_model"] = {k: v.detach().clone() for k, v in self.engine.state_dict().items()}  # a copy: the
            # state dict shares the parameters' storage, which scored() fills with the average
        with self.scored() as engine:
            save_checkpoint(Path(self.settings.out) / name, engine, **state)

    def save_best(self, trainer: Trainer) -> None:
        self.save(trainer, BEST)


def log_losses(trainer: Trainer) -> None:
    """Every log_every steps, the mean loss since the last row, with the steps per second and CPU hours."""
    run = trainer.task
    every = run.settings.log_every
    if trainer.done % every == 0:
        now = time.monotonic()
        loss = float(np.mean(trainer.losses))
        run.log.write(event="loss", step=trainer.done, loss=loss, lr=trainer.lr, steps_per_s=every / (now - run.logged_at),
                      cpu_hours=trainer.budget.cpu_seconds() / 3600)
        trainer.losses, run.logged_at = [], now
        trainer.bar.set_postfix(loss=f"{loss:.4g}", lr=f"{trainer.lr:.3g}")


def validate_when_due(trainer: Trainer) -> None:
    """Every valid_every steps and on the last, the held-out scores; the Trainer keeps the best in best.pt."""
    run = trainer.task
    if run.truths and (trainer.done % run.settings.valid_every == 0 or trainer.ending):
        trainer.score(run.validate(trainer))


def log_stop(trainer: Trainer) -> None:
    """The stop row on the step the run ends on: why ("steps", "signal", "time") and the CPU hours."""
    if trainer.ending:
        trainer.task.log.write(event="stop", step=trainer.done, reason=trainer.end,
                               cpu_hours=trainer.budget.cpu_seconds() / 3600)


def native_bf16(settings: TrainSettings) -> TrainSettings:
    """--bf16 on a CPU without native bfloat16 trains in float32, with one warning: there
    bfloat16 would slow training about 14 times instead of speeding it."""
    if not settings.bf16 or cpu_has_native_bf16():
        return settings
    tqdm.write(NO_NATIVE_BF16, file=sys.stderr)
    return replace(settings, bf16=False)


def with_schedule(settings: TrainSettings, state: dict | None, path: Path) -> TrainSettings:
    """The settings with the length of the learning-rate decay fixed: as given, else a resumed
    run's stored value (a run older than the setting: its `steps`, as it always was), else a new
    run's `steps`. A resumed run that keeps or changes a stored schedule says so on stderr."""
    stored = ((state or {}).get("train") or {}).get("lr_decay_steps")
    given = settings.lr_decay_steps
    if given is not None and stored is not None and given != stored:
        tqdm.write(f"--lr-decay-steps {given:g} replaces the {stored:g} steps of the learning-rate decay that "
                   f"{path} was trained with.", file=sys.stderr)
    elif given is None and stored is not None and stored != settings.steps:
        tqdm.write(f"{path} keeps its learning-rate schedule: from {settings.lr:g} to {settings.lr_final:g} over "
                   f"{stored:g} steps, whatever --steps says (--lr-decay-steps changes it).", file=sys.stderr)
    return replace(settings, lr_decay_steps=given if given is not None else stored if stored is not None else settings.steps)


def trained_ranges(settings: TrainSettings, sampler: WindowSampler, state: dict | None, path: Path) -> dict | None:
    """What the engine is trained on: measured over the run's datasets for a new run and for a
    resume given other datasets than its last session's (which says so on stderr), else the
    checkpoint's record. Only the record changes: the engine's velocity_scale stays the checkpoint's."""
    if state is None:
        return _ranges(settings, sampler)
    stored = (state.get("train") or {}).get("data")
    folders = [Path(d) for d in datasets(settings)]
    if stored is None or [Path(d) for d in datasets(replace(settings, data=stored))] == folders:
        return state.get("data_ranges")
    tqdm.write(f"{path} was trained on {stored}; its training ranges are measured again over --data {settings.data}.",
               file=sys.stderr)
    return _ranges(settings, sampler)


def union_ranges(run: dict | None, init: dict | None) -> dict | None:
    """What an engine started from another's weights has been trained on: its own data's ranges
    and its --init file's (the velocity statistics stay the run's)."""
    from runout.learned.training_range import union

    if run is None or init is None:
        return run
    try:
        both = union([{k: v for k, v in r.items() if k != "velocity_m_per_frame"} for r in (run, init)])
    except (ValueError, KeyError) as exc:
        raise InputError(f"--init: the file's training ranges do not join the run's data ({exc}).") from None
    return {**both, "velocity_m_per_frame": run["velocity_m_per_frame"]}


def datasets(settings: TrainSettings) -> list[str]:
    """The dataset folders of a run, the measure's first."""
    return [d.strip() for d in settings.data.split(",") if d.strip()]


def shares(settings: TrainSettings) -> list[float] | None:
    if settings.data_shares is None:
        return None
    try:
        return [float(v) for v in settings.data_shares.split(",")]
    except ValueError:
        raise InputError(f"--data-shares {settings.data_shares!r} must be numbers joined by commas, one per dataset "
                         "(e.g. 3,1).") from None


def training_ranges(data: str | Path, config: NeuralMPMConfig | None = None) -> dict:
    """What an engine trained on DATA/train.npz (folders joined by commas) was trained on
    (runout.learned.training_range)."""
    config = config or NeuralMPMConfig()
    settings = TrainSettings(data=str(data))
    sampler = WindowSampler.from_splits(datasets(settings), "train", config.history, config.material_width)
    return _ranges(settings, sampler)


def _ranges(settings: TrainSettings, sampler: WindowSampler) -> dict:
    """What the engine is trained on (runout.learned.training_range), with the spacing of its
    points: each dataset measured, then their union."""
    from runout.learned.training_range import measure, union
    parts = []
    for k, (data, meta) in enumerate(zip(datasets(settings), sampler.metas)):
        members = sampler.members[k].tolist()
        fixed = [sampler.fixed[i].numpy() for i in members]
        types = [np.where(f, PARTICLE_TYPE_KINEMATIC, PARTICLE_TYPE_SOIL) for f in fixed]
        parts.append(measure([sampler.material[i].numpy() for i in members], types, meta, 0.0, f"{data}/train.npz"))
    velocity = sampler.velocity_statistics()
    return {**union(parts), "velocity_m_per_frame": {"mean": velocity["mean"], "std": velocity["std"]}}


def _heldout(settings: TrainSettings) -> list:
    from runout.dataset import split_trajectories
    return list(split_trajectories(datasets(settings)[0], "valid", settings.valid_count)) if settings.valid_every else []


EXTRA_VALID_COUNT = 8  # held-out scenes of each further dataset, logged beside the measure


def _heldout_extra(settings: TrainSettings) -> dict:
    from runout.dataset import split_trajectories
    if not settings.valid_every:
        return {}
    count = min(settings.valid_count, EXTRA_VALID_COUNT)
    return {data: list(split_trajectories(data, "valid", count)) for data in datasets(settings)[1:]}


def _headline(result: dict) -> dict:
    return {k: result[k] for k in ("position_error_m", "front_error", "runout_error", "displacement_m",
                                   "displacement_mpm_m")}


def rollout_like(engine: NeuralMPM, truth):
    """The engine's rollout from rest of a truth trajectory's frame 0, over all its frames."""
    return engine.rollout_trajectory(truth, truth.n_frames, stop_speed=None)


def evaluate(engine: NeuralMPM, truths: list) -> dict:
    """runout.evaluate.heldout.score of the engine's rollouts from rest of the truths."""
    from runout.evaluate.heldout import score
    engine.eval()
    try:
        predicted = [rollout_like(engine, t) for t in truths]
    finally:
        engine.train()
    return score(predicted, truths, engine.point_spacing)
