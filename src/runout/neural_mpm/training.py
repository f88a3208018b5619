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
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import numpy as np
import torch
from tqdm.auto import tqdm

from runout.defaults import PARTICLE_TYPE_KINEMATIC, PARTICLE_TYPE_SOIL
from runout.neural_mpm.checkpoint import read_checkpoint, save_checkpoint
from runout.neural_mpm.engine import NeuralMPM, NeuralMPMConfig
from runout.neural_mpm.windows import WindowSampler

CHECKPOINT = "checkpoint.pt"
BEST = "best.pt"
LOG = "train.log.jsonl"


@dataclass(frozen=True)
class TrainSettings:
    data: str = "data/ft8"
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
    """Train (or resume) the run in settings.out; returns the engine at the last step."""
    torch.set_num_threads(settings.threads)
    out = Path(settings.out)
    out.mkdir(parents=True, exist_ok=True)
    state = read_checkpoint(out / CHECKPOINT) if resume and (out / CHECKPOINT).is_file() else None
    config = NeuralMPMConfig.from_dict(state["config"]) if state is not None else config or NeuralMPMConfig()
    sampler = WindowSampler.from_split(settings.data, "train", config.history, config.material_width)
    if config.velocity_scale <= 0:  # a new run: the unit of velocity from its data
        config = replace(config, velocity_scale=sampler.velocity_statistics()["scale"])
    with torch.random.fork_rng():  # the initial weights follow the run's seed
        torch.manual_seed(settings.seed)
        engine = NeuralMPM(config)
    optimizer = torch.optim.Adam(engine.parameters(), lr=settings.lr)
    start, cpu_before, best = 0, 0.0, math.inf
    engine.data_ranges = _ranges(settings, sampler) if state is None else state.get("data_ranges")
    if state is not None:
        engine.load_state_dict(state["model"])
        optimizer.load_state_dict(state["optimizer"])
        start, cpu_before, best = state["step"], state["cpu_seconds"], state["best"]
    log = RunLog(out)
    log.write(event="start", step=start, config=config.as_dict(), settings=asdict(settings),
              parameters=sum(p.numel() for p in engine.parameters()), train_scenes=len(sampler))
    truths = _heldout(settings)
    stop = _StopOnSignal()
    t_wall, t_cpu = time.monotonic(), time.process_time()
    cpu_used = lambda: cpu_before + time.process_time() - t_cpu  # noqa: E731
    span = settings.calls * config.frames_per_call
    losses: list[float] = []
    step = start
    bar = tqdm(total=settings.steps, initial=start, disable=not settings.progress, desc="neural MPM", unit="step")
    t_log = time.monotonic()
    while step < settings.steps:
        lr = learning_rate(step, settings)
        for group in optimizer.param_groups:
            group["lr"] = lr
        generator = torch.Generator().manual_seed(settings.seed * 1_000_003 + step)
        window = sampler.draw(settings.batch_size, span, settings.rest_share, settings.mirror_share, generator)
        loss = window_loss(engine, window, settings.calls)
        optimizer.zero_grad(set_to_none=True)
        loss.backward()
        optimizer.step()
        losses.append(loss.item())
        step += 1
        bar.update(1)
        if step % settings.log_every == 0:
            now = time.monotonic()
            log.write(event="loss", step=step, loss=float(np.mean(losses)), lr=lr,
                      steps_per_s=settings.log_every / (now - t_log), cpu_hours=cpu_used() / 3600)
            losses, t_log = [], now
        if truths and (step % settings.valid_every == 0 or step == settings.steps):
            result = evaluate(engine, truths)
            log.write(event="valid", step=step, cpu_hours=cpu_used() / 3600, **_headline(result))
            if result["position_error_m"] < best:
                best = result["position_error_m"]
                save_checkpoint(out / BEST, engine, **training_state(optimizer, step, cpu_used(), best, settings))
        out_of_time = (settings.max_hours is not None and time.monotonic() - t_wall > settings.max_hours * 3600
                       or settings.max_cpu_hours is not None and cpu_used() > settings.max_cpu_hours * 3600)
        if step % settings.save_every == 0 or out_of_time or stop.asked or step == settings.steps:
            save_checkpoint(out / CHECKPOINT, engine, **training_state(optimizer, step, cpu_used(), best, settings))
        if out_of_time or stop.asked:
            log.write(event="stop", step=step, reason="time" if out_of_time else "signal", cpu_hours=cpu_used() / 3600)
            break
    bar.close()
    stop.restore()
    return engine


def _ranges(settings: TrainSettings, sampler: WindowSampler) -> dict:
    """What the engine is trained on (runout.learned.training_range), with the spacing of its points."""
    from runout.learned.training_range import measure
    fixed = [f.numpy() for f in sampler.fixed]
    types = [np.where(f, PARTICLE_TYPE_KINEMATIC, PARTICLE_TYPE_SOIL) for f in fixed]
    ranges = measure([m.numpy() for m in sampler.material], types, sampler.meta, 0.0, f"{settings.data}/train.npz")
    velocity = sampler.velocity_statistics()
    return {**ranges, "velocity_m_per_frame": {"mean": velocity["mean"], "std": velocity["std"]}}


def _heldout(settings: TrainSettings) -> list:
    from runout.dataset import split_trajectories
    return list(split_trajectories(settings.data, "valid", settings.valid_count)) if settings.valid_every else []


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
