"""Every way a command can end: a usage error, a bad value, a run that fails (divergence,
out of memory, disk full) and Ctrl-C each print one sentence and exit non-zero (2 bad
input, 1 failed run, 130 interrupted, after saving what a rerun resumes from)."""

from __future__ import annotations

import errno
import os
import signal
import subprocess
import sys
from importlib import metadata
from pathlib import Path

import numpy as np
import pytest
import torch

import runout.mpm
import runout.train
import runout.trajectory
from runout.cli import main
from runout.gns.checkpoint import read_checkpoint
from runout.scene import fill_points
from runout.trajectory import trajectory_for_scene
from test_gns_synthetic import write_dataset

REPO = Path(__file__).resolve().parents[1]
DAM = REPO / "examples" / "small_dam.toml"
MODEL = REPO / "models" / "slope.pt"
TINY = ["--latent", "8", "--hidden", "8", "--message-passing-steps", "1", "--valid-every", "0", "--log-every", "1"]


def run(argv, capsys) -> tuple[int, str]:
    """Exit code and stderr of `runout ARGV` run in this process."""
    try:
        main([str(a) for a in argv])
        code = 0
    except SystemExit as done:
        code = done.code
    return code, capsys.readouterr().err


def one_sentence(text: str) -> bool:
    """The error line (after any progress bar) is one sentence, and no traceback came before it."""
    lines = text.strip().splitlines()
    last = lines[-1] if lines else ""
    return last.startswith("error: ") and last.endswith(".") and ". " not in last and "Traceback" not in text


def static_run(scenes, frames=4, **_):
    """A stand-in for runout.mpm.simulate: the scene's points, not moving."""
    out = []
    for s in scenes:
        p = fill_points(s)
        positions = np.repeat(p.position[None], frames, axis=0)
        traj = trajectory_for_scene(s, positions, p.particle_type, p.material_id)
        traj.info = {"substeps_per_frame": 1, "wall_time_s": 0.0}
        out.append(traj)
    return out


# ----------------------------------------------------------------------------- exit 2


def test_a_usage_error_is_one_sentence_and_exit_2_in_a_fresh_process(tmp_path):
    done = subprocess.run([sys.executable, "-m", "runout", "mpm", str(DAM)], capture_output=True, text=True, cwd=tmp_path)
    assert done.returncode == 2
    assert done.stderr.strip() == "error: Missing option '--out' (see `runout mpm --help`)."


def test_an_unknown_option_is_exit_2(capsys):
    code, err = run(["rollout", "--bogus"], capsys)
    assert code == 2 and one_sentence(err) and "--bogus" in err


@pytest.mark.parametrize("option, value, words", [
    ("--latent", "0", "--latent = 0 is outside the allowed range [1, 1024]"),
    ("--noise", "-1", "--noise = -1 is outside the allowed range [0, 10] velocity std"),
    ("--mirror", "2", "--mirror = 2 is outside the allowed range [0, 1]"),
    ("--message-passing-steps", "500", "--message-passing-steps = 500 is outside the allowed range [1, 50]"),
    ("--lr", "0", "--lr = 0 is outside the allowed range (0, 1]"),
    ("--ema", "1", "--ema = 1 is outside the allowed range [0, 0.99999]"),
])
def test_a_bad_value_is_exit_2_before_any_work(tmp_path, capsys, option, value, words):
    code, err = run(["train", "--data", tmp_path / "none", "--out", tmp_path / "run", option, value], capsys)
    assert code == 2 and words in err and one_sentence(err)
    assert not (tmp_path / "run").exists()


# ----------------------------------------------------------------------------- exit 1


def test_a_diverging_rollout_is_exit_1_and_writes_nothing(tmp_path, capsys):
    ckpt = read_checkpoint(MODEL)
    first = next(k for k, v in ckpt["model"].items() if v.is_floating_point())
    ckpt["model"][first] = torch.full_like(ckpt["model"][first], 1e30)  # finite weights, infinite predictions
    torch.save(ckpt, tmp_path / "huge.pt")
    code, err = run(["rollout", "--model", tmp_path / "huge.pt", DAM, "--out", tmp_path / "o", "--frames", "12",
                     "--no-animation"], capsys)
    assert code == 1 and "non-finite positions" in err and one_sentence(err)
    assert not (tmp_path / "o" / "trajectory.npz").exists()


@pytest.mark.parametrize("error", [MemoryError(), torch.OutOfMemoryError("CUDA out of memory.")])
def test_out_of_memory_is_exit_1_with_advice(tmp_path, capsys, monkeypatch, error):
    def exhausted(*args, **kwargs):
        raise error

    monkeypatch.setattr(runout.mpm, "simulate", exhausted)
    code, err = run(["mpm", DAM, "--out", tmp_path / "o"], capsys)
    assert code == 1 and "ran out of memory" in err and one_sentence(err)


def test_a_full_disk_is_exit_1_naming_the_file(tmp_path, capsys, monkeypatch):
    def disk_full(traj, out_dir, *args):
        raise OSError(errno.ENOSPC, "No space left on device", str(Path(out_dir) / "trajectory.npz"))

    monkeypatch.setattr(runout.mpm, "simulate", static_run)
    monkeypatch.setattr(runout.trajectory, "save_trajectory", disk_full)
    code, err = run(["mpm", DAM, "--out", tmp_path / "o"], capsys)
    assert code == 1 and "no space left on the disk" in err and "trajectory.npz" in err and one_sentence(err)


def test_a_diverged_mpm_run_is_exit_1(tmp_path, capsys, monkeypatch):
    def diverged(scenes, **kwargs):
        trajs = static_run(scenes)
        trajs[0].positions[2:] = np.nan
        return trajs

    monkeypatch.setattr(runout.mpm, "simulate", diverged)
    code, err = run(["mpm", DAM, "--out", tmp_path / "o"], capsys)
    assert code == 1 and "diverged" in err and "frame 2" in err and one_sentence(err)


# ----------------------------------------------------------------------------- exit 130


def test_ctrl_c_in_a_run_without_saved_state_is_exit_130(tmp_path, capsys, monkeypatch):
    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(runout.mpm, "simulate", interrupted)
    code, err = run(["mpm", DAM, "--out", tmp_path / "o"], capsys)
    assert code == 130 and "interrupted (Ctrl-C)" in err and one_sentence(err)


def test_ctrl_c_in_training_saves_the_step_and_resume_is_exact(tmp_path, capsys, monkeypatch):
    torch.set_num_threads(1)
    data = write_dataset(tmp_path / "data", frames=12, n_train=2)
    code, _ = run(["train", "--data", data, "--out", tmp_path / "whole", "--steps", "5", *TINY], capsys)
    assert code == 0

    real_step = runout.train._train_step

    def step_then_ctrl_c(model, simulator, optimizer, data, bounds, cfg, step, ctx):
        loss = real_step(model, simulator, optimizer, data, bounds, cfg, step, ctx)
        if step == 1:
            os.kill(os.getpid(), signal.SIGINT)  # a real Ctrl-C, in the middle of the run
        return loss

    monkeypatch.setattr(runout.train, "_train_step", step_then_ctrl_c)
    argv = ["train", "--data", data, "--out", tmp_path / "cut", "--steps", "5", *TINY]
    code, err = run(argv, capsys)
    assert code == 130 and "after step 2" in err and "--resume" in err and one_sentence(err)
    assert read_checkpoint(tmp_path / "cut" / "checkpoint.pt")["step"] == 2
    monkeypatch.setattr(runout.train, "_train_step", real_step)
    assert run([*argv, "--resume"], capsys)[0] == 0
    whole, cut = (read_checkpoint(tmp_path / d / "checkpoint.pt")["model"] for d in ("whole", "cut"))
    assert all(torch.equal(whole[k], cut[k]) for k in whole)


def test_ctrl_c_in_generation_keeps_finished_batches_and_resumes(tmp_path, capsys, monkeypatch):
    calls = []

    def second_batch_interrupted(scenes, **kwargs):
        calls.append(len(scenes))
        if len(calls) == 2:
            raise KeyboardInterrupt
        return static_run(scenes, frames=scenes[0].time.frames)

    monkeypatch.setattr(runout.mpm, "simulate", second_batch_interrupted)
    argv = ["generate", "--stage", "base", "--count", "10", "--batch", "5", "--frames", "7", "--cell-size", "16",
            "--out", tmp_path / "data"]
    code, err = run(argv, capsys)
    assert code == 130 and "resumes" in err and one_sentence(err)
    assert (tmp_path / "data" / "parts" / "part_00000.npz").is_file()
    assert run(argv, capsys)[0] == 0
    assert len(calls) == 3  # the rerun ran only the unfinished batch
    assert (tmp_path / "data" / "train.npz").is_file()


# ----------------------------------------------------------------------------- dependencies


def test_the_installed_packages_are_the_ones_the_constraints_pin():
    """constraints.txt is what `make setup` installs; a drifted environment fails here."""
    pins = [line.split("==") for line in (REPO / "constraints.txt").read_text().splitlines()
            if line and not line.startswith("#")]
    assert {"typer", "numpy", "scipy", "matplotlib", "tqdm", "pytest"} <= {name.lower() for name, _ in pins}
    for name, version in pins:
        assert metadata.version(name) == version, f"{name} {metadata.version(name)} is installed, constraints.txt pins {version}"
