"""No path to data loss, and one sentence for every bad input (issue 55): each case below runs
a command the way a user could get it wrong and checks the exit code, that stderr ends in one
sentence with no traceback, and that every file the user made is still there byte for byte.

Categories: output folders (what --force and re-runs may remove), paths (folders, files and
symbolic links where something else is expected), scenes and specs (the one reader of
TOML/JSON), datasets and checkpoints, options (train --resume), interruption (Ctrl-C at start-up).
"""

from __future__ import annotations

import errno
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
import pytest
import torch

import runout
from runout.cli import main
from runout.outputs import MARKER
from runout.scene import load_scene
from runout.simfiles import read_simulations
from test_cli_exits import DAM, MODEL, TINY, one_sentence, run
from test_gns_synthetic import write_dataset
from test_outputs import mpm_runs  # noqa: F401  (fixture: a static stand-in for the MPM)

SPEC = """scene = "{scene}"
[target]
trajectory = "target"
[parameters.m1_downstream_lower.c]
lower = 10.0
upper = 80.0
"""


def files(root: Path) -> dict[str, bytes]:
    """Every file below root (links not followed) and its bytes."""
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file() and not p.is_symlink()}


def kept(before: dict[str, bytes], root: Path) -> bool:
    """Every file of `before` is still below root, byte for byte."""
    after = files(root)
    return all(after.get(name) == data for name, data in before.items())


def refused(argv, capsys, root: Path, words: str) -> None:
    """`runout ARGV` exits 2 with one sentence holding `words` and changes nothing below root."""
    before = files(root)
    code, err = run(argv, capsys)
    assert code == 2 and one_sentence(err) and words in err, err
    assert files(root) == before


def scene_with(tmp_path: Path, name: str, old: str, new: str) -> Path:
    text = DAM.read_text()
    assert old in text
    path = tmp_path / name
    path.write_text(text.replace(old, new, 1))
    return path


# ----------------------------------------------------------------------------- output folders


def test_a_rerun_without_vtk_keeps_the_users_file_in_vtk(tmp_path, capsys, mpm_runs):
    out = tmp_path / "run"
    assert run(["mpm", DAM, "--out", out, "--vtk", "--no-animate"], capsys)[0] == 0
    (out / "vtk" / "my_view.pvsm").write_text("<ParaView state>")
    before = {k: v for k, v in files(tmp_path).items() if "my_view" in k}
    code, err = run(["mpm", DAM, "--out", out, "--no-animate"], capsys)
    assert code == 0 and kept(before, tmp_path)
    assert sorted(p.name for p in (out / "vtk").iterdir()) == ["my_view.pvsm"]  # the run's frames went
    assert "vtk" not in json.loads((out / MARKER).read_text())["written"]


def test_train_into_its_own_dataset_is_refused_even_with_force(tmp_path, capsys):
    data = write_dataset(tmp_path / "data", frames=12, n_train=1)
    (data / MARKER).write_text(json.dumps({"command": "generate", "written": ["train.npz", "valid.npz", "metadata.json"]}))
    train = ["train", "--data", data, "--steps", "1", "--force", *TINY]
    refused([*train, "--out", data], capsys, tmp_path, f"--out {data} is --data {data}")
    refused([*train, "--out", data / "run"], capsys, tmp_path, "lies inside --data")


def test_invert_into_its_target_trajectory_is_refused_even_with_force(tmp_path, capsys, mpm_runs):
    assert run(["mpm", DAM, "--out", tmp_path / "target", "--no-animate"], capsys)[0] == 0
    spec = tmp_path / "spec.toml"
    spec.write_text(SPEC.format(scene=DAM))
    argv = ["invert", spec, "--engine", "mpm-fd", "--out", tmp_path / "target", "--force"]
    refused(argv, capsys, tmp_path, "is its target")


def test_a_scene_folder_as_out_is_refused(tmp_path, capsys, mpm_runs):
    (tmp_path / "scenes").mkdir()
    scene = tmp_path / "scenes" / "dam.toml"
    scene.write_text(DAM.read_text())
    refused(["mpm", scene, "--out", tmp_path / "scenes", "--force"], capsys, tmp_path, "holds the scene")
    assert not mpm_runs


def test_force_over_a_dataset_removes_only_its_own_files_inside_its_folders(tmp_path, capsys, mpm_runs):
    out = tmp_path / "data"
    for name in ("parts/part_00000.npz", "parts/my_notes.txt", "scenes/scene_00000.toml", "scenes/my_slope.toml"):
        (out / name).parent.mkdir(parents=True, exist_ok=True)
        (out / name).write_text(name)
    (out / MARKER).write_text(json.dumps({"command": "generate", "written": ["parts", "scenes"]}))
    mine = {k: v for k, v in files(tmp_path).items() if "my_" in k}
    code, err = run(["mpm", DAM, "--out", out, "--no-animate", "--force"], capsys)
    assert code == 0 and "--force removes parts, scenes" in err and kept(mine, tmp_path)
    assert not (out / "parts" / "part_00000.npz").exists() and not (out / "scenes" / "scene_00000.toml").exists()


@pytest.mark.parametrize("make, words", [
    (lambda p: os.symlink(p.parent / "nowhere", p), "is a symbolic link to"),
    (lambda p: os.symlink(p, p), "is a symbolic link that loops back on itself"),
])
def test_a_broken_symbolic_link_as_out_is_named(tmp_path, capsys, mpm_runs, make, words):
    make(tmp_path / "out")
    refused(["mpm", DAM, "--out", tmp_path / "out"], capsys, tmp_path, words)
    refused(["mpm", DAM, "--out", tmp_path / "out" / "run"], capsys, tmp_path, words)
    assert (tmp_path / "out").is_symlink() and not mpm_runs


def test_a_read_only_folder_as_out_is_named(tmp_path, capsys, mpm_runs, monkeypatch):
    def read_only(**_):  # the tests run as root, whom a chmod does not stop: the system's answer, faked
        raise PermissionError(errno.EACCES, "Permission denied")

    monkeypatch.setattr(tempfile, "mkstemp", read_only)
    refused(["mpm", DAM, "--out", tmp_path / "out"], capsys, tmp_path, f"cannot write in {tmp_path}, a read-only folder")


# ----------------------------------------------------------------------------- paths of inputs


@pytest.mark.parametrize("argv, words", [
    (["mpm", "{folder}", "--out", "{tmp}/o"], "is a folder; give the scene file itself"),
    (["invert", "{folder}", "--out", "{tmp}/o"], "is a folder; give the inverse spec file itself"),
    (["rollout", "--model", "{folder}", str(DAM), "--out", "{tmp}/o"], "is a folder; give the checkpoint file itself"),
    (["train", "--data", str(DAM), "--out", "{tmp}/o"], "is a file; give the dataset folder itself"),
    (["mpm", "{tmp}/dangling.toml", "--out", "{tmp}/o"], "is a symbolic link to"),
    (["mpm", "{tmp}/loop.toml", "--out", "{tmp}/o"], "is a symbolic link that loops back on itself"),
    (["inspect", "{tmp}/dangling.toml"], "is a symbolic link to"),
])
def test_an_input_of_the_wrong_kind_is_named(tmp_path, capsys, argv, words):
    (tmp_path / "folder").mkdir()
    os.symlink(tmp_path / "gone.toml", tmp_path / "dangling.toml")
    os.symlink(tmp_path / "loop.toml", tmp_path / "loop.toml")
    argv = [a.format(folder=tmp_path / "folder", tmp=tmp_path) for a in argv]
    refused(argv, capsys, tmp_path, words)


# ----------------------------------------------------------------------------- scenes and specs


@pytest.mark.parametrize("name, text, words", [
    ("deep.json", "[" * 5000 + "]" * 5000, "nests tables and lists deeper than the 32 levels allowed"),
    ("deep40.json", '{"domain": ' + "[" * 40 + "]" * 40 + "}", "domain" + "[0]" * 32 + " lies 33 tables and lists deep"),
    ("deep.toml", "a = " + "[" * 5000 + "]" * 5000, "nests tables and lists deeper than the 32 levels allowed"),
    ("digits.toml", "[time]\nframes = " + "9" * 5000, "a whole number has more than 4300 digits"),
])
def test_a_file_beyond_the_readers_bounds_is_one_sentence(tmp_path, capsys, name, text, words):
    (tmp_path / name).write_text(text)
    refused(["mpm", tmp_path / name, "--out", tmp_path / "o"], capsys, tmp_path, words)


@pytest.mark.parametrize("key, value, words", [
    ("width = 800.0", "width = " + "9" * 400, "domain.width = 999999999999… (400 digits) is outside the allowed range"),
    ("cell_size = 10.0", "cell_size = 1e-310", "domain.cell_size = 1e-310 is outside the allowed range (0, 50] m"),
    ("cell_size = 10.0", "cell_size = 5e-324", "(a positive size is at least 2.23e-308)"),
    ("[[regions]]", "[[regions]]\nvelocity = [true, 0]", "regions[0].velocity must be a pair [vx, vy] of numbers"),
    ("[[regions]]", "[[regions]]\nvelocity = [80.0, 80.0]", "has a speed of 113.137 m/s, outside the allowed range [0, 100] m/s"),
])
def test_a_bad_scene_value_is_one_sentence(tmp_path, capsys, mpm_runs, key, value, words):
    scene = scene_with(tmp_path, "scene.toml", key, value)
    refused(["mpm", scene, "--out", tmp_path / "o"], capsys, tmp_path, words)
    assert not mpm_runs


def test_the_speed_limit_is_on_the_vectors_length(tmp_path):
    assert load_scene(scene_with(tmp_path, "fast.toml", "[[regions]]", "[[regions]]\nvelocity = [70.0, 70.0]"))  # 99 m/s


def test_a_spec_that_is_not_utf8_is_one_sentence(tmp_path, capsys):
    spec = tmp_path / "spec.toml"
    spec.write_bytes(SPEC.format(scene=DAM).encode() + b"# caf\xe9\n")
    refused(["invert", spec, "--engine", "mpm-fd", "--out", tmp_path / "o"], capsys, tmp_path,
            "is not UTF-8 text (byte 0xe9 on line 7)")


# ----------------------------------------------------------------------------- datasets and checkpoints


@pytest.mark.parametrize("ptype", [float("nan"), 1e30, 2.5])
def test_a_particle_type_that_is_no_whole_number_is_one_sentence(tmp_path, capsys, ptype):
    data = write_dataset(tmp_path / "data", frames=12, n_train=1)
    positions, _, material = read_simulations(data / "train.npz")[0]
    np.savez(data / "train.npz", simulation_trajectory_0=np.array([positions, np.float64(ptype), material], dtype=object))
    refused(["inspect", data], capsys, tmp_path, f"simulation 0 particle_type = {ptype:g} must be a whole number")


@pytest.mark.parametrize("field, value, words", [
    ("friction_angle_deg", "wide", "data_ranges.friction_angle_deg = 'wide' must be a pair [lowest, highest] degrees"),
    ("friction_angle_deg", [10.0], "data_ranges.friction_angle_deg = [10.0] must be a pair"),
    ("cohesion_kpa", [50.0, 10.0], "data_ranges.cohesion_kpa = [50.0, 10.0] must rise from the lowest to the highest value"),
    ("materials_per_scene", [1, 2.5], "data_ranges.materials_per_scene[1] = 2.5 must be a whole number"),
    ("domain_m", [400.0, float("nan")], "data_ranges.domain_m[1] = nan must be a finite number"),
    ("source", 7, "data_ranges.source = 7 must be text"),
    ("extra", 1, "unknown key 'extra' in the checkpoint's data_ranges"),
])
def test_a_bad_data_range_in_a_checkpoint_is_one_sentence(tmp_path, capsys, field, value, words):
    ckpt = torch.load(MODEL, weights_only=True)
    ckpt["data_ranges"] = {**ckpt["data_ranges"], field: value}
    torch.save(ckpt, tmp_path / "model.pt")
    refused(["rollout", "--model", tmp_path / "model.pt", DAM, "--out", tmp_path / "o", "--frames", "3"], capsys, tmp_path,
            words)


# ----------------------------------------------------------------------------- options


@pytest.fixture(scope="module")
def two_steps(tmp_path_factory):
    """A dataset and a run of 2 steps of a tiny model at --lr 0.001."""
    torch.set_num_threads(1)
    root = tmp_path_factory.mktemp("two_steps")
    data = write_dataset(root / "data", frames=12, n_train=1)
    main([str(a) for a in ["train", "--data", data, "--out", root / "run", "--steps", "2", "--lr", "0.001", "--no-progress", *TINY]])
    return data, root / "run"


@pytest.mark.parametrize("option", [["--latent", "16"], ["--lr", "0.5"], ["--lr-decay-steps", "10"]])
def test_resume_refuses_an_option_it_would_ignore(two_steps, capsys, option):
    data, out = two_steps
    argv = ["train", "--data", data, "--out", out, "--steps", "3", "--resume", "--no-progress", *TINY, *option]
    refused(argv, capsys, out.parent, f"{option[0]} {option[1]} differs from the")


def test_resume_without_lr_continues_the_checkpoints_schedule(two_steps, capsys, tmp_path):
    data, out = two_steps
    copy = tmp_path / "run"
    copy.mkdir()
    for p in out.iterdir():
        (copy / p.name).write_bytes(p.read_bytes())
    argv = ["train", "--data", data, "--out", copy, "--steps", "3", "--resume", "--no-progress", *TINY, "--lr", "0.001"]
    assert run(argv[:-2], capsys)[0] == 0  # --lr left out
    last = json.loads((copy / "log.jsonl").read_text().splitlines()[-1])
    assert last["step"] == 3 and last["lr"] == pytest.approx(0.001, rel=1e-3)


# ----------------------------------------------------------------------------- interruption


@pytest.mark.parametrize("argv", [["mpm", str(DAM), "--out", "OUT"], ["generate", "--stage", "base", "--count", "10", "--out", "OUT"]])
def test_ctrl_c_while_the_command_line_loads_is_exit_130_in_one_sentence(tmp_path, argv):
    """A Ctrl-C in the first fraction of a second lands in the imports; here it is raised where
    `import typer` runs, in a fresh process."""
    code = ("import builtins, sys\n"
            "real = builtins.__import__\n"
            "def interrupted(name, *args, **kwargs):\n"
            "    if name == 'typer':\n"
            "        raise KeyboardInterrupt\n"
            "    return real(name, *args, **kwargs)\n"
            "builtins.__import__ = interrupted\n"
            f"sys.argv = ['runout', *{[a.replace('OUT', str(tmp_path / 'out')) for a in argv]!r}]\n"
            "import runout.__main__\n")
    env = {**os.environ, "PYTHONPATH": str(Path(runout.__file__).parents[1])}  # this runout, from any folder
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=tmp_path, env=env)
    assert done.returncode == 130 and "Traceback" not in done.stderr
    assert done.stderr == "error: interrupted (Ctrl-C) while runout was starting; nothing was written.\n"
    assert not (tmp_path / "out").exists()
