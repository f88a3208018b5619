"""Every value read from a file is checked before use (runout.checks): dataset metadata,
particle types against the model's type table, trajectory metadata, checkpoints (each
field typed and in range, finite weights), runout's own part and deposit files, scene files.
A bad one ends the command with exit 2 and one sentence naming the file and the field."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
import torch

import runout.mpm
from runout.errors import InputError
from runout.gns.checkpoint import load_simulator
from runout.inverse.history import HISTORY_JSON, RunInfo
from runout.inverse.optimise import deposit_path, minimise
from runout.inverse.problem import Evaluation
from runout.inverse.spec import FreeParameter, OptimiserSpec
from runout.simfiles import read_simulations, write_simulations
from runout.trajectory import save_trajectory, trajectory_from_features
from test_cli_exits import MODEL, TINY, one_sentence, run, static_run
from test_gns_synthetic import BOUNDS, FRAME_DT, falling_block, write_dataset

REPO = Path(__file__).resolve().parents[1]
DAM = REPO / "examples" / "small_dam.toml"


def edit_metadata(folder: Path, **changes) -> Path:
    meta = json.loads((folder / "metadata.json").read_text())
    meta.update(changes)
    (folder / "metadata.json").write_text(json.dumps(meta))  # NaN is written as JSON's NaN
    return folder


# ----------------------------------------------------------------------------- metadata.json


@pytest.mark.parametrize("changes, words", [
    ({"vel_std": [float("nan"), 0.1]}, "vel_std[0] = nan must be a finite number in (0, inf) m per frame"),
    ({"acc_std": [0.1, 0.0]}, "acc_std[1] = 0 is outside the allowed range (0, inf) m per frame"),
    ({"dt": float("nan")}, "dt = nan must be a finite number in (0, 10] s"),
    ({"dt": "0.0375"}, "dt = '0.0375' must be a finite number in (0, 10] s"),
    ({"bounds": [[0, 60]]}, "bounds = [[0, 60]] must be [[x_lo, x_hi], [y_lo, y_hi]] in m"),
    ({"bounds": [[60, 0], [0, 30]]}, "bounds x = [60, 0] must rise from x_lo to a larger x_hi"),
    ({"bounds": [[0, 60], [0, "top"]]}, "bounds y[1] = 'top' must be a finite number"),
    ({"default_connectivity_radius": -4.6}, "default_connectivity_radius = -4.6 is outside the allowed range (0, 30] m"),
    ({"default_connectivity_radius": 1e9}, "default_connectivity_radius = 1e+09 is outside the allowed range (0, 30] m"),
    ({"cell_size": 4.0, "default_connectivity_radius": 1.0}, "default_connectivity_radius = 1 is outside the allowed range [2, 20] m"),
    ({"dim": 3}, "dim = 3 is outside the allowed range [2, 2] (runout is two-dimensional)"),
    ({"sequence_length": 0}, "sequence_length = 0 is outside the allowed range [1, 1e+06] frames"),
    ({"material_features": ["density"]}, "material_features = ['density'] must be [tan_phi] or [tan_phi, c_over_100kPa]"),
])
def test_bad_metadata_is_refused_by_inspect_and_train(tmp_path, capsys, changes, words):
    data = edit_metadata(write_dataset(tmp_path / "data", frames=12, n_train=1), **changes)
    for argv in (["inspect", data], ["train", "--data", data, "--out", tmp_path / "run", "--steps", "1", *TINY]):
        code, err = run(argv, capsys)
        assert code == 2 and one_sentence(err) and "metadata.json" in err and words in err, err
    assert not (tmp_path / "run" / "checkpoint.pt").exists()


def test_metadata_whose_top_level_is_not_a_table_is_one_sentence(tmp_path, capsys):
    data = write_dataset(tmp_path / "data", frames=12, n_train=1)
    (data / "metadata.json").write_text("[1, 2]")
    code, err = run(["inspect", data], capsys)
    assert code == 2 and one_sentence(err) and "the top level is a list" in err


def test_inspect_prints_the_checks_and_the_particle_types(tmp_path):
    from typer.testing import CliRunner

    from runout.cli.app import app

    data = write_dataset(tmp_path / "data", frames=12, n_train=1)
    result = CliRunner().invoke(app, ["inspect", str(data)])
    assert result.exit_code == 0, result.output
    assert "particle types [3, 6]" in result.output
    assert "checked: every simulation" in result.output and "particle types within [0, 8]" in result.output
    assert "connectivity radius 4.6 m within (0, 30] m" in result.output


# ----------------------------------------------------------------------------- particle types


def with_particle_type(folder: Path, ptype: int) -> Path:
    """The dataset with one soil point of every train and valid simulation given `ptype`."""
    for split in ("train", "valid"):
        sims = read_simulations(folder / f"{split}.npz")
        for _, types, _ in sims:
            types[-1] = ptype
        write_simulations(folder / f"{split}.npz", sims)
    return folder


@pytest.mark.parametrize("ptype", [9, -1])
def test_a_particle_type_outside_the_table_is_refused_by_inspect_train_and_rollout(tmp_path, capsys, ptype):
    data = with_particle_type(write_dataset(tmp_path / "data", frames=12, n_train=1), ptype)
    words = f"simulation 0 particle_type = {ptype} is outside the allowed range [0, 8]"
    commands = [
        ["inspect", data],
        ["train", "--data", data, "--out", tmp_path / "run", "--steps", "1", *TINY],
        ["rollout", "--model", MODEL, data, "--split", "valid", "--out", tmp_path / "o", "--no-animation"],
    ]
    for argv in commands:
        code, err = run(argv, capsys)
        assert code == 2 and one_sentence(err) and words in err, err


def test_a_trajectory_with_a_type_outside_the_table_is_refused_by_rollout(tmp_path, capsys):
    positions, ptype, material = falling_block(12, 0.5, 0.1)
    ptype[0] = 40
    save_trajectory(trajectory_from_features(positions, ptype, material, FRAME_DT, BOUNDS), tmp_path / "traj")
    code, err = run(["rollout", "--model", MODEL, tmp_path / "traj", "--out", tmp_path / "o", "--no-animation"], capsys)
    assert code == 2 and one_sentence(err) and "trajectory.npz: simulation 0 particle_type = 40" in err


def test_a_checkpoint_whose_type_table_lacks_the_soil_type_is_refused(tmp_path):
    ckpt = torch.load(MODEL, weights_only=True)
    ckpt["schema"]["particle_types"] = 4
    torch.save(ckpt, tmp_path / "small.pt")
    with pytest.raises(InputError, match=r"schema.particle_types = 4 is outside the allowed range \[7, 64\]"):
        load_simulator(tmp_path / "small.pt")


# ----------------------------------------------------------------------------- trajectory metadata


@pytest.mark.parametrize("changes, words", [
    ({"dt": -1.0}, "dt = -1 is outside the allowed range (0, 10] s"),
    ({"bounds": "all"}, "bounds = 'all' must be [[x_lo, x_hi], [y_lo, y_hi]] in m"),
    ({"materials": [{"name": "a", "strength": 3}]}, "the materials table does not describe materials"),
])
def test_bad_trajectory_metadata_is_one_sentence(tmp_path, capsys, changes, words):
    positions, ptype, material = falling_block(12, 0.5, 0.1)
    save_trajectory(trajectory_from_features(positions, ptype, material, FRAME_DT, BOUNDS), tmp_path / "traj")
    edit_metadata(tmp_path / "traj", **changes)
    code, err = run(["rollout", "--model", MODEL, tmp_path / "traj", "--out", tmp_path / "o", "--no-animation"], capsys)
    assert code == 2 and one_sentence(err) and words in err, err


# ----------------------------------------------------------------------------- checkpoints


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    """A dataset and a run folder whose checkpoint.pt holds 2 steps of a tiny model."""
    torch.set_num_threads(1)
    root = tmp_path_factory.mktemp("trained")
    data = write_dataset(root / "data", frames=12, n_train=1)
    from runout.cli import main

    main(["train", "--data", str(data), "--out", str(root / "run"), "--steps", "2", *TINY])
    return data, root / "run" / "checkpoint.pt"


def tampered_run(trained, folder: Path, change) -> list:
    """`train --resume` argv on a copy of the trained run whose checkpoint `change` edited."""
    data, checkpoint = trained
    folder.mkdir()
    for name in ("checkpoint.pt", "log.jsonl", ".runout.json"):
        shutil.copy(checkpoint.parent / name, folder / name)
    ckpt = torch.load(folder / "checkpoint.pt", weights_only=True)
    change(ckpt)
    torch.save(ckpt, folder / "checkpoint.pt")
    return ["train", "--data", data, "--out", folder, "--steps", "4", "--resume", *TINY]


def _set(*keys, value):
    def change(ckpt):
        table = ckpt
        for key in keys[:-1]:
            table = table[key]
        table[keys[-1]] = value(table[keys[-1]]) if callable(value) else value
    return change


def _drop(key):
    return lambda ckpt: ckpt.pop(key)


@pytest.mark.parametrize("change, words", [
    (_set("step", value=-1), "step = -1 is outside the allowed range [0, 1e+09]"),
    (_set("step", value="2"), "step = '2' must be a whole number"),
    (_set("step", value=2.5), "step = 2.5 must be a whole number"),
    (_set("optimizer", value="adam"), "the checkpoint's 'optimizer' is a str; expected a table"),
    (_set("optimizer", "param_groups", value=None), "optimizer holds a dict as 'state' and nothing as 'param_groups'"),
    (_set("optimizer", "param_groups", 0, "lr", value="fast"), "optimizer.param_groups[0].lr = 'fast' must be a finite number"),
    (_set("optimizer", "param_groups", 0, "betas", value=(0.9, 1.5)), "optimizer.param_groups[0].betas[1] = 1.5 is outside"),
    (_set("optimizer", "param_groups", 0, "params", value=[0, "a"]), "optimizer.param_groups[0].params = [0, 'a'] must be a list"),
    (_set("optimizer", "state", 0, "exp_avg", value=lambda t: torch.full_like(t, float("nan"))),
     "optimizer.state[0].exp_avg holds NaN or infinite values"),
    (_set("optimizer", "state", 0, "exp_avg", value=torch.zeros(3)), "optimizer.state[0].exp_avg is a float32 tensor of shape (3,)"),
    (_set("optimizer", "state", 0, "step", value="one"), "optimizer.state[0].step = 'one' must be a finite number"),
    (_set("rng", value=[1, 2]), "the checkpoint's 'rng' is a list; expected a table"),
    (_set("rng", "torch", value=torch.zeros(3)), "rng.torch is a float32 tensor of shape (3,)"),
    (_set("rng", "seed", value="zero"), "rng.seed = 'zero' must be a whole number"),
    (_set("train", value="fast"), "the checkpoint's 'train' is a str; expected a table"),
    (_set("train", "lr_step_offset", value=-3), "train.lr_step_offset = -3 is outside the allowed range"),
    (_set("train", "steps", value="many"), "train.steps = 'many' must be a whole number"),
    (_set("train", "lr_init", value=True), "train.lr_init = True must be a finite number"),
    (_set("train", "noise", value=float("nan")), "train.noise = nan must be a finite number"),
    (_set("train", "network", value=[1]), "train.network = [1] must be a table of layer sizes"),
    (_drop("optimizer"), "the checkpoint lacks 'optimizer', so training cannot resume from it"),
    (_set("model", "type_embedding.weight", value=lambda t: torch.full_like(t, float("inf"))),
     "the model weight 'type_embedding.weight' holds NaN or infinite values"),
])
def test_a_tampered_checkpoint_is_refused_by_resume(trained, tmp_path, capsys, change, words):
    code, err = run(tampered_run(trained, tmp_path / "run", change), capsys)
    assert code == 2 and one_sentence(err) and "checkpoint.pt: " in err and words in err, err


def test_nan_weights_are_refused_on_load_naming_the_file(tmp_path, capsys):
    ckpt = torch.load(MODEL, weights_only=True)
    first = next(k for k, v in ckpt["model"].items() if v.is_floating_point())
    ckpt["model"][first] = torch.full_like(ckpt["model"][first], float("nan"))
    torch.save(ckpt, tmp_path / "nan.pt")
    code, err = run(["rollout", "--model", tmp_path / "nan.pt", DAM, "--out", tmp_path / "o", "--frames", "12"], capsys)
    assert code == 2 and one_sentence(err) and f"nan.pt: the model weight '{first}' holds NaN or infinite values" in err
    assert not (tmp_path / "o").exists()


def test_resume_with_init_is_refused(trained, tmp_path, capsys):
    argv = tampered_run(trained, tmp_path / "run", lambda ckpt: None)
    code, err = run([*argv, "--init", MODEL], capsys)
    assert code == 2 and one_sentence(err) and "would ignore --init" in err
    code, err = run([*argv, "--radius", "3"], capsys)
    assert code == 2 and one_sentence(err) and "--radius 3 m applies to new runs only" in err
    assert run(argv, capsys)[0] == 0  # the same run without the conflicting option resumes


# ----------------------------------------------------------------------------- runout's own files


@pytest.fixture
def generated(tmp_path, capsys, monkeypatch) -> list:
    """The argv of a finished `runout generate` of 2 parts (a static stand-in for the MPM)."""
    monkeypatch.setattr(runout.mpm, "simulate", lambda scenes, **kw: static_run(scenes, frames=scenes[0].time.frames))
    argv = ["generate", "--stage", "base", "--count", "10", "--batch", "5", "--frames", "7", "--cell-size", "16",
            "--out", tmp_path / "data"]
    assert run(argv, capsys)[0] == 0
    return argv


def test_a_part_with_an_object_array_is_one_sentence_on_resume_and_merge(tmp_path, capsys, generated):
    scenes = np.empty(2, dtype=object)
    scenes[0], scenes[1] = np.arange(3), "five"
    np.savez(tmp_path / "data" / "parts" / "part_00001.npz", scenes=scenes)
    for command in (generated, ["merge", tmp_path / "data", "--out", tmp_path / "merged"]):
        code, err = run(command, capsys)
        assert code == 2 and one_sentence(err) and "part_00001.npz: scenes is an array of dtype object" in err, err


def test_a_part_with_an_object_array_of_positions_is_one_sentence(tmp_path, capsys, generated):
    part = tmp_path / "data" / "parts" / "part_00000.npz"
    with np.load(part) as archive:
        members = dict(archive)
    positions = np.empty(1, dtype=object)
    positions[0] = members["positions_0"]
    np.savez(part, **{**members, "positions_0": positions})
    code, err = run(generated, capsys)
    assert code == 2 and one_sentence(err) and "part_00000.npz: simulation 0 positions is an array of dtype object" in err


def bowl(values: np.ndarray) -> Evaluation:
    """A stand-in evaluator: loss sum (v - 1)^2, its gradient and a one-point deposit."""
    return Evaluation(values, float(((values - 1.0) ** 2).sum()), 2 * (values - 1.0), 0.0, 0.0, 0,
                      np.zeros((1, 2), dtype=np.float32))


def test_a_deposit_with_an_object_array_is_one_sentence_on_resume(tmp_path):
    free = (FreeParameter("a", "c", 0.2, -0.5, 2.0), FreeParameter("b", "c", 2.5, 0.0, 3.0))
    start = np.array([p.normalise(p.initial) for p in free])
    info = RunInfo("d", "test", "", start.tolist())
    minimise(bowl, free, start, tmp_path, info, OptimiserSpec(max_iterations=2), "test")
    np.save(deposit_path(tmp_path, 1), np.array([np.zeros(2), "x"], dtype=object), allow_pickle=True)
    with pytest.raises(InputError, match="eval_0001.npy: not a readable .npy array of numbers") as err:
        minimise(bowl, free, start, tmp_path, info, OptimiserSpec(max_iterations=2), "test")
    assert one_sentence(f"error: {err.value}")
    (tmp_path / HISTORY_JSON).write_text("[]")
    with pytest.raises(InputError, match="history.json: the top level is a list"):
        minimise(bowl, free, start, tmp_path, info, OptimiserSpec(max_iterations=2), "test")


# ----------------------------------------------------------------------------- scene files


@pytest.mark.parametrize("command", ["mpm", "show"])
def test_a_json_scene_that_is_not_a_table_is_one_sentence(tmp_path, capsys, command):
    (tmp_path / "scene.json").write_text("[1, 2, 3]")
    code, err = run([command, tmp_path / "scene.json", "--out", tmp_path / "o"], capsys)
    assert code == 2 and one_sentence(err) and "[top level] is a list; it must be a table of keys" in err


# ----------------------------------------------------------------------------- --device


@pytest.mark.parametrize("argv", [
    ["rollout", "--model", MODEL, DAM, "--out", "{tmp}/o"],
    ["train", "--data", "{tmp}/data", "--out", "{tmp}/run"],
    ["mpm", DAM, "--out", "{tmp}/o"],
])
@pytest.mark.parametrize("device, words", [
    ("tpu", "--device = 'tpu' is not a device runout runs on"),
    ("cuda:99", "--device"),
])
def test_a_device_this_machine_cannot_serve_is_one_sentence(tmp_path, capsys, argv, device, words):
    argv = [str(a).replace("{tmp}", str(tmp_path)) for a in argv]
    code, err = run([*argv, "--device", device], capsys)
    assert code == 2 and one_sentence(err) and words in err, err
    assert not (tmp_path / "o").exists() and not (tmp_path / "run").exists()
