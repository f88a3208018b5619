"""Training the neural MPM: windows of the dataset, a position loss over K chained calls,
Adam with an exponential learning-rate decay, checkpoints written atomically and resumed
exactly, held-out rollouts from rest as the measure (runout.evaluate.heldout).

The loss of a window is the mean squared distance (in cells, (m / cell_size)^2) between the
predicted and the MPM's soil positions over the K calls' K m frames, so the engine learns
from its own predictions as it will be rolled out. The draws of step n come from a generator
seeded with (seed, n): a resumed run draws what an unbroken one would have. A run stops at
`steps`, at `max_hours` of wall time, at `max_cpu_hours` of its own CPU time (the measure
of the equal-CPU pilots: what the process used on every thread, training and validation),
or on Ctrl-C, and saves the step it ends on.
"""

from __future__ import annotations

import json
import math
import signal
import time
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

import numpy as np
import torch
from tqdm.auto import tqdm

from runout.defaults import PARTICLE_TYPE_KINEMATIC, PARTICLE_TYPE_SOIL
from runout.errors import InputError
from runout.neural_mpm.checkpoint import read_checkpoint, save_checkpoint
from runout.neural_mpm.engine import NeuralMPM, NeuralMPMConfig
from runout.neural_mpm.windows import WindowSampler

CHECKPOINT = "checkpoint.pt"
BEST = "best.pt"
LOG = "train.log.jsonl"


@dataclass(frozen=True)
class TrainSettings:
    data: str = "data/ft8"  # dataset folder, or several joined by commas (the first one's valid split is the measure)
    data_shares: str | None = None  # the part of the batches from each dataset, e.g. "3,1" (default: by their scenes)
    out: str = "runs/neural-mpm"
    steps: int = 20_000
    batch_size: int = 8
    calls: int = 2  # K: chained calls in the loss
    lr: float = 1e-3
    lr_final: float = 1e-4
    rest_share: float = 0.1  # windows that start at frame 0
    mirror_share: float = 0.5
    seed: int = 0
    valid_every: int = 2_000
    valid_count: int = 16
    save_every: int = 250
    log_every: int = 100
    max_hours: float | None = None
    max_cpu_hours: float | None = None
    threads: int = 1
    progress: bool = True


def learning_rate(step: int, s: TrainSettings) -> float:
    """lr decayed exponentially from s.lr at step 0 to s.lr_final at s.steps."""
    return s.lr * (s.lr_final / s.lr) ** (min(step, s.steps) / s.steps)


def window_loss(engine: NeuralMPM, window, calls: int) -> torch.Tensor:
    """Mean squared soil position error over the window's frames, in cells squared."""
    pred = engine.advance(window.x, window.velocities, window.points, calls)
    soil = ~window.points.fixed
    err = (pred[:, soil] - window.targets[:, soil]) / engine.config.cell_size
    return (err ** 2).sum(-1).mean()


def training_state(optimizer, step: int, cpu_seconds: float, best: float, settings: TrainSettings) -> dict:
    return {"optimizer": optimizer.state_dict(), "step": step, "cpu_seconds": cpu_seconds, "best": best,
            "train": asdict(settings)}


class RunLog:
    def __init__(self, out: Path):
        self.path = out / LOG

    def write(self, **row) -> None:
        with open(self.path, "a") as f:
            f.write(json.dumps(row) + "\n")


def train(settings: TrainSettings, config: NeuralMPMConfig | None = None, resume: bool = False) -> NeuralMPM:
    """Train (or resume) the run in settings.out; returns the engine at the last step. The
    run ends validated and saved, whatever ends it (steps, time, a signal)."""
    torch.set_num_threads(settings.threads)
    run = Run.start(settings, config, resume)
    stop = _StopOnSignal()
    bar = tqdm(total=settings.steps, initial=run.step, disable=not settings.progress, desc="neural MPM", unit="step")
    try:
        while run.step < settings.steps:
            run.take_step()
            bar.update(1)
            ending = run.out_of_time() or stop.asked or run.step == settings.steps
            if run.truths and (run.step % settings.valid_every == 0 or ending):
                run.validate()
            if run.step % settings.save_every == 0 or ending:
                run.save(CHECKPOINT)
            if ending:
                reason = "steps" if run.step == settings.steps else "signal" if stop.asked else "time"
                run.log.write(event="stop", step=run.step, reason=reason, cpu_hours=run.cpu_used() / 3600)
                break
    finally:
        bar.close()
        stop.restore()
    return run.engine


@dataclass
class Run:
    """A training run's state between steps: the engine, Adam, the data, the held-out scenes,
    the best held-out error so far and the CPU time used (s, over every session of the run)."""

    settings: TrainSettings
    engine: NeuralMPM
    optimizer: torch.optim.Optimizer
    sampler: WindowSampler
    truths: list
    log: "RunLog"
    step: int = 0
    best: float = math.inf
    cpu_before: float = 0.0
    losses: list = field(default_factory=list)
    extra: dict = field(default_factory=dict)  # dataset -> held-out scenes of the other datasets (logged, not the measure)

    def __post_init__(self):
        self._t_wall, self._t_cpu, self._t_log = time.monotonic(), time.process_time(), time.monotonic()

    @classmethod
    def start(cls, settings: TrainSettings, config: NeuralMPMConfig | None, resume: bool) -> "Run":
        out = Path(settings.out)
        out.mkdir(parents=True, exist_ok=True)
        state = read_checkpoint(out / CHECKPOINT) if resume and (out / CHECKPOINT).is_file() else None
        config = NeuralMPMConfig.from_dict(state["config"]) if state is not None else config or NeuralMPMConfig()
        sampler = WindowSampler.from_splits(datasets(settings), "train", config.history, config.material_width,
                                            shares(settings))
        if config.velocity_scale <= 0:  # a new run: the unit of velocity from its data
            config = replace(config, velocity_scale=sampler.velocity_statistics()["scale"])
        with torch.random.fork_rng():  # the initial weights follow the run's seed
            torch.manual_seed(settings.seed)
            engine = NeuralMPM(config)
        optimizer = torch.optim.Adam(engine.parameters(), lr=settings.lr)
        engine.data_ranges = _ranges(settings, sampler) if state is None else state.get("data_ranges")
        run = cls(settings, engine, optimizer, sampler, _heldout(settings), RunLog(out), extra=_heldout_extra(settings))
        if state is not None:
            engine.load_state_dict(state["model"])
            optimizer.load_state_dict(state["optimizer"])
            run.step, run.cpu_before, run.best = state["step"], state["cpu_seconds"], state["best"]
        run.log.write(event="start", step=run.step, config=config.as_dict(), settings=asdict(settings),
                      parameters=sum(p.numel() for p in engine.parameters()), train_scenes=len(sampler))
        return run

    def cpu_used(self) -> float:
        return self.cpu_before + time.process_time() - self._t_cpu

    def out_of_time(self) -> bool:
        s = self.settings
        return (s.max_hours is not None and time.monotonic() - self._t_wall > s.max_hours * 3600
                or s.max_cpu_hours is not None and self.cpu_used() > s.max_cpu_hours * 3600)

    def take_step(self) -> None:
        s = self.settings
        lr = learning_rate(self.step, s)
        for group in self.optimizer.param_groups:
            group["lr"] = lr
        generator = torch.Generator().manual_seed(s.seed * 1_000_003 + self.step)
        span = s.calls * self.engine.config.frames_per_call
        window = self.sampler.draw(s.batch_size, span, s.rest_share, s.mirror_share, generator)
        loss = window_loss(self.engine, window, s.calls)
        self.optimizer.zero_grad(set_to_none=True)
        loss.backward()
        self.optimizer.step()
        self.losses.append(loss.item())
        self.step += 1
        if self.step % s.log_every == 0:
            now = time.monotonic()
            self.log.write(event="loss", step=self.step, loss=float(np.mean(self.losses)), lr=lr,
                           steps_per_s=s.log_every / (now - self._t_log), cpu_hours=self.cpu_used() / 3600)
            self.losses, self._t_log = [], now

    def validate(self) -> None:
        """The held-out scenes from rest; best.pt keeps the best so far."""
        result = evaluate(self.engine, self.truths)
        self.log.write(event="valid", step=self.step, cpu_hours=self.cpu_used() / 3600, **_headline(result))
        for data, truths in self.extra.items():
            self.log.write(event="valid", data=data, step=self.step, cpu_hours=self.cpu_used() / 3600,
                           **_headline(evaluate(self.engine, truths)))
        if result["position_error_m"] < self.best:
            self.best = result["position_error_m"]
            self.save(BEST)

    def save(self, name: str) -> None:
        state = training_state(self.optimizer, self.step, self.cpu_used(), self.best, self.settings)
        save_checkpoint(Path(self.settings.out) / name, self.engine, **state)


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


class _StopOnSignal:
    """Ctrl-C or SIGTERM ask the loop to stop after the current step (saved)."""

    def __init__(self):
        self.asked = False
        self._old = {s: signal.signal(s, self._ask) for s in (signal.SIGINT, signal.SIGTERM)}

    def _ask(self, *_):
        self.asked = True

    def restore(self):
        for s, handler in self._old.items():
            signal.signal(s, handler)
