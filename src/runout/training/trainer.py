"""The one training loop of every learned engine: the Trainer runs an engine's training *task*.

A task holds what differs between engines: the model and its optimiser (built new or resumed),
the learning rate of each step, one optimiser step (its loss), and its checkpoint (written
atomically in the engine's format, runout.learned.files.save_plain) and best file. The GNS's
task is runout.train's GnsTask, the neural MPM's runout.neural_mpm.training's Run.

Each step the Trainer sets the task's learning rate, takes the step, asks whether to stop, and
calls the hooks with itself (the engine's log lines and held-out scores; a hook may end the run
by setting `stop_reason`). It saves every `save_every` steps and on the step it ends on,
whatever ends it: the last step, a budget (`max_hours` of wall time of this session,
`max_cpu_hours` of the run's CPU time, every session's), a hook, or Ctrl-C / SIGTERM (after the
step in hand; a second signal stops at once). Under torchrun every process stops on the step
any one of them was asked to. `conclude` then raises Interrupted for a signal (exit 130 at the
command line) or says where a budget or hook left the run; `--resume` continues exactly.
"""

from __future__ import annotations

import json
import math
import signal
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Protocol

import torch
import torch.distributed as dist
from tqdm.auto import tqdm

from runout.errors import Interrupted
from runout.outputs import write_atomic


@dataclass
class Context:
    """Where this process runs and whether it is the one that writes (rank 0 under torchrun)."""

    device: torch.device = field(default_factory=lambda: torch.device("cpu"))
    rank: int = 0
    world: int = 1

    @property
    def writer(self) -> bool:
        return self.rank == 0


class TrainingTask(Protocol):
    """What an engine's training gives the Trainer."""

    optimizer: torch.optim.Optimizer
    checkpoint: Path  # the file the run resumes from

    def learning_rate(self, step: int) -> float: ...

    def step(self, step: int) -> torch.Tensor | float:
        """Training step `step` (0 for the first): one optimiser step at the learning rate
        already set; its loss."""

    def save(self, trainer: "Trainer") -> None:
        """The checkpoint of the run after trainer.done steps."""

    def save_best(self, trainer: "Trainer") -> None:
        """The best file: the run at trainer.done steps, whose held-out score trainer.best is the best so far."""


Hook = Callable[["Trainer"], None]


class LogFile:
    """A run's log file: one JSON object per line, each with the step it belongs to."""

    def __init__(self, path: Path):
        self.path = path

    def write(self, **row) -> None:
        with self.path.open("a") as f:
            f.write(json.dumps(row) + "\n")

    def keep_until(self, step: int) -> list[dict]:
        """Drop the lines of steps after `step` (a run resumed from there redoes them); the lines kept."""
        if not self.path.exists():
            return []
        kept = [json.loads(line) for line in self.path.read_text().splitlines() if line]
        kept = [row for row in kept if row["step"] <= step]
        write_atomic(self.path, "".join(json.dumps(row) + "\n" for row in kept))
        return kept


@dataclass
class Budget:
    """What a run may spend before it stops, saved: `max_hours` of wall time from now (this
    session), `max_cpu_hours` of CPU time of the whole run (this process's on every thread,
    after `cpu_before` seconds of its earlier sessions). None: no limit."""

    max_hours: float | None = None
    max_cpu_hours: float | None = None
    cpu_before: float = 0.0

    def __post_init__(self):
        self._wall, self._cpu = time.monotonic(), time.process_time()

    def cpu_seconds(self) -> float:
        """The run's CPU time so far (s), every session's."""
        return self.cpu_before + time.process_time() - self._cpu

    def spent(self) -> str | None:
        """The limit reached, in words ("--max-hours 2 reached"), or None."""
        if self.max_hours is not None and time.monotonic() - self._wall > self.max_hours * 3600:
            return f"--max-hours {self.max_hours:g} reached"
        if self.max_cpu_hours is not None and self.cpu_seconds() > self.max_cpu_hours * 3600:
            return f"--max-cpu-hours {self.max_cpu_hours:g} reached (the run's CPU time)"
        return None


class StopRequest:
    """Ctrl-C (SIGINT) or SIGTERM during training ask the loop to stop after the step it is
    in, so the checkpoint it saves is that of a whole step; a second signal stops at once.
    Installed only in the main thread (signals reach no other)."""

    SIGNALS = (signal.SIGINT, signal.SIGTERM)

    def __enter__(self) -> "StopRequest":
        self.requested = False
        self._previous = {}
        if threading.current_thread() is threading.main_thread():
            self._previous = {s: signal.signal(s, self._ask) for s in self.SIGNALS}
        return self

    def _ask(self, signum, frame) -> None:
        self.requested = True
        signal.signal(signum, signal.default_int_handler if signum == signal.SIGINT else signal.SIG_DFL)

    def agreed(self, budget: Budget, ctx: Context) -> tuple[bool, str | None]:
        """(asked by a signal, the budget's limit reached or None); under torchrun every
        process stops if any one was asked to (or ran out of time)."""
        spent = budget.spent()
        if ctx.world == 1:
            return self.requested, spent
        flag = torch.tensor([float(self.requested), float(spent is not None)], device=ctx.device)
        dist.all_reduce(flag, op=dist.ReduceOp.MAX)
        return bool(flag[0].item()), (spent or "another process's time limit reached") if flag[1].item() else None

    def __exit__(self, *exc) -> None:
        for s, handler in self._previous.items():
            signal.signal(s, handler)


@dataclass
class Trainer:
    """The loop and its periodic duties (module docstring). `done` is the number of steps
    taken, `lr` the learning rate of the last, `losses` those of the steps since the last log
    line (a log hook empties it), `best` the best held-out score so far (lower is better)."""

    task: TrainingTask
    steps: int  # the step counter's final value
    hooks: tuple[Hook, ...] = ()
    save_every: int = 1000
    budget: Budget = field(default_factory=Budget)
    ctx: Context = field(default_factory=Context)
    label: str = "training"  # the progress bar's
    progress: bool = True
    best: float = math.inf
    done: int = 0
    lr: float = 0.0
    losses: list = field(default_factory=list)
    saved_at: int = -1  # step of the last checkpoint written
    stop_reason: str | None = None  # why the run stops before its last step (a hook may set it)
    interrupted: bool = False  # a signal stopped it
    bar: tqdm | None = field(default=None, repr=False)  # the progress bar, while run() runs

    @property
    def ending(self) -> bool:
        """Whether this step is the run's last: the final step, or a stop asked for (a signal, the budget, a hook)."""
        return self.done == self.steps or self.interrupted or self.stop_reason is not None

    @property
    def end(self) -> str:
        """Why the run ended: "steps", "signal" or "time" (a budget, or a hook)."""
        return "steps" if self.done == self.steps else "signal" if self.interrupted else "time"

    def due(self, every: int) -> bool:
        """Whether a duty of period `every` steps (0: never) falls on this step; the last step always does."""
        return bool(every) and (self.done % every == 0 or self.done == self.steps)

    def run(self, start: int) -> int:
        """Steps from `start` to `steps`, or until a stop; the step it ends on is saved.
        Returns the steps taken."""
        self.done = start
        self.bar = bar = tqdm(total=self.steps, initial=start, desc=self.label, unit="step", dynamic_ncols=True,
                              disable=not (self.progress and self.ctx.writer))
        try:
            with StopRequest() as stop:
                for step in range(start, self.steps):
                    self.lr = self.task.learning_rate(step)
                    for group in self.task.optimizer.param_groups:
                        group["lr"] = self.lr
                    self.losses.append(self.task.step(step))
                    self.done = step + 1
                    bar.update(1)
                    self.interrupted, spent = stop.agreed(self.budget, self.ctx)
                    self.stop_reason = self.stop_reason or spent
                    for hook in self.hooks:
                        hook(self)
                    if self.due(self.save_every) or self.ending:
                        self.save()
                    if self.ending:
                        break
        finally:
            bar.close()
        return self.done

    def save(self) -> None:
        """The task's checkpoint of this step, once."""
        if self.saved_at != self.done:
            self.task.save(self)
            self.saved_at = self.done

    def score(self, value: float) -> None:
        """A held-out score of this step (lower is better): the best so far is kept, and the task's best file written."""
        if value < self.best:
            self.best = value
            self.task.save_best(self)

    def conclude(self) -> None:
        """After run(): Interrupted if a signal stopped it; where a budget or hook left it, on stderr."""
        if self.done >= self.steps:
            return
        if self.interrupted:
            raise Interrupted(f"training stopped after step {self.done}, which {self.task.checkpoint} holds, "
                              "and --resume continues exactly from there.")
        if self.ctx.writer:
            tqdm.write(f"{self.stop_reason} after step {self.done}; {self.task.checkpoint} holds it and --resume "
                       "continues from there.")
