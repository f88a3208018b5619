"""The one training loop (runout.training.trainer): it stops on its steps, a wall-time or a
CPU-time budget, a hook or a signal, and saves the step it stops on."""

from __future__ import annotations

import os
import signal

import pytest
import torch

from runout.errors import Interrupted
from runout.training.trainer import Budget, LogFile, Trainer


class CountingTask:
    """A task whose step costs `cpu` seconds of CPU time; it records the steps saved."""

    def __init__(self, tmp_path, cpu: float = 0.0, on_step=None):
        self.weight = torch.nn.Parameter(torch.zeros(1))
        self.optimizer = torch.optim.SGD([self.weight], lr=0.1)
        self.checkpoint = tmp_path / "checkpoint.pt"
        self.cpu, self.on_step = cpu, on_step
        self.saved, self.best_saved = [], []

    def learning_rate(self, step: int) -> float:
        return 0.1 / (step + 1)

    def step(self, step: int) -> float:
        spin_until = os.times().user + os.times().system + self.cpu
        while os.times().user + os.times().system < spin_until:
            pass
        if self.on_step:
            self.on_step(step)
        return float(step)

    def save(self, trainer) -> None:
        self.saved.append(trainer.done)

    def save_best(self, trainer) -> None:
        self.best_saved.append((trainer.done, trainer.best))


def test_a_run_takes_its_steps_sets_each_learning_rate_and_saves_when_due_and_at_the_end(tmp_path):
    task = CountingTask(tmp_path)
    seen = []
    trainer = Trainer(task, steps=7, save_every=3, progress=False,
                      hooks=(lambda t: seen.append((t.done, t.lr, task.optimizer.param_groups[0]["lr"])),))
    assert trainer.run(2) == 7
    assert [done for done, _, _ in seen] == [3, 4, 5, 6, 7]
    assert all(lr == set_lr == task.learning_rate(done - 1) for done, lr, set_lr in seen)
    assert task.saved == [3, 6, 7] and trainer.end == "steps"
    trainer.conclude()  # a finished run says nothing


@pytest.mark.parametrize("limit, words", [({"max_cpu_hours": 0.01 / 3600}, "--max-cpu-hours 2.77778e-06 reached"),
                                          ({"max_hours": 1e-9}, "--max-hours 1e-09 reached")])
def test_a_spent_budget_stops_the_run_saved_after_the_step_in_hand(tmp_path, capsys, limit, words):
    task = CountingTask(tmp_path, cpu=0.004)
    trainer = Trainer(task, steps=1000, save_every=100, budget=Budget(**limit), progress=False)
    done = trainer.run(0)
    assert 1 <= done < 10 and task.saved == [done] and trainer.end == "time"
    trainer.conclude()
    said = capsys.readouterr().out
    assert words in said and f"after step {done}" in said and "--resume" in said


def test_the_cpu_budget_counts_the_runs_earlier_sessions():
    assert Budget(max_cpu_hours=1.0, cpu_before=3601.0).spent() is not None
    assert Budget(max_cpu_hours=1.0, cpu_before=0.0).spent() is None
    assert Budget(max_cpu_hours=1.0, cpu_before=10.0).cpu_seconds() >= 10.0


def test_a_hook_ends_the_run_after_its_step_saved(tmp_path):
    task = CountingTask(tmp_path)

    def stop_at_4(trainer):
        if trainer.done == 4:
            trainer.stop_reason = "the hook's reason"

    ending = []
    trainer = Trainer(task, steps=10, save_every=100, progress=False, hooks=(stop_at_4, lambda t: ending.append(t.ending)))
    assert trainer.run(0) == 4 and task.saved == [4] and ending == [False, False, False, True]


@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM])
def test_ctrl_c_or_sigterm_saves_the_step_in_hand_and_is_interrupted(tmp_path, signum):
    before = signal.getsignal(signum)
    task = CountingTask(tmp_path, on_step=lambda step: step == 2 and os.kill(os.getpid(), signum))
    trainer = Trainer(task, steps=10, save_every=100, progress=False)
    assert trainer.run(0) == 3 and task.saved == [3] and trainer.end == "signal"
    with pytest.raises(Interrupted, match=r"after step 3, which .*checkpoint.pt holds"):
        trainer.conclude()
    assert signal.getsignal(signum) is before  # the handler before the run is back


def test_a_better_score_is_kept_and_its_best_file_written(tmp_path):
    task = CountingTask(tmp_path)
    scores = iter([3.0, 2.0, 2.5, 1.0])
    trainer = Trainer(task, steps=4, progress=False, hooks=(lambda t: t.score(next(scores)),))
    trainer.run(0)
    assert task.best_saved == [(1, 3.0), (2, 2.0), (4, 1.0)] and trainer.best == 1.0


def test_a_resumed_log_drops_the_lines_after_the_checkpoints_step(tmp_path):
    log = LogFile(tmp_path / "log.jsonl")
    for step in (0, 100, 200, 300):
        log.write(event="loss", step=step)
    assert [row["step"] for row in log.keep_until(200)] == [0, 100, 200]
    assert (tmp_path / "log.jsonl").read_text().count("\n") == 3
