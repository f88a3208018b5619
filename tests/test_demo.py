"""`runout demo` wiring (reduced by --quick) and the GPU session driver (scripts/gpu_session.py),
both on CPU with tiny models."""

import importlib.util
import json
import shutil
import sys
from pathlib import Path

import pytest
import torch
from typer.testing import CliRunner

from runout.cli import app
from runout.errors import InputError
from runout.gns.checkpoint import read_checkpoint
from runout.gns.schema import NetworkConfig
from runout.train import TrainConfig, continued_onset, train
from test_gns_synthetic import write_dataset

torch.set_num_threads(1)  # tiny graphs: extra threads only add OpenMP synchronisation cost

REPO = Path(__file__).resolve().parents[1]
TINY = ["--latent", "16", "--message-passing", "2", "--device", "cpu"]


def load_session_module():
    spec = importlib.util.spec_from_file_location("gpu_session", REPO / "scripts" / "gpu_session.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # dataclasses look their module up there
    spec.loader.exec_module(module)
    return module


session = load_session_module()


def tiny_model(folder: Path, width: int, radius: float) -> Path:
    """A checkpoint trained for 2 steps on falling blocks, with the given material width and radius (m)."""
    data = write_dataset(folder / "data", width=width)
    meta = json.loads((data / "metadata.json").read_text())
    meta["default_connectivity_radius"] = radius
    (data / "metadata.json").write_text(json.dumps(meta))
    network = NetworkConfig(latent=16, hidden=16, hidden_layers=2, message_passing_steps=2)
    train(TrainConfig(data=data, out=folder / "run", steps=2, network=network, valid_every=0, log_every=1, checkpoint_layers=False,
                      exact_rest=True))
    return folder / "run" / "checkpoint.pt"


def session_dataset(folder: Path, stage: str, count: int = 10, seed: int = 0, frames: int = 20, cell: float = 4.0) -> Path:
    """A finished dataset as `runout generate` leaves it (falling blocks stand in for the MPM)."""
    width = 1 if stage == "base" else 2
    data = write_dataset(folder, frames=frames, width=width)
    shutil.copyfile(data / "valid.npz", data / "test.npz")
    meta = json.loads((data / "metadata.json").read_text())
    meta.update(stage=stage, count=count, seed=seed, frames=frames, cell_size=cell,
                material_features=["tan_phi", "c_over_100kPa"][:width])
    (data / "metadata.json").write_text(json.dumps(meta))
    return data


def session_args(tmp_path: Path, stage: str, data: Path, minutes: str = "0.15", reserve: str = "3") -> list[str]:
    return ["--stage", stage, "--minutes", minutes, "--reserve", reserve, "--count", "10", "--frames", "20",
            "--data", str(data), "--run", str(tmp_path / f"run_{stage}"), "--models", str(tmp_path / "models"),
            "--out", str(tmp_path / f"out_{stage}"), *TINY]


# ----------------------------------------------------------------------------- demo


def test_quick_demo_leads_with_the_mpm_and_prints_its_pictures_last(tmp_path):
    model = tiny_model(tmp_path / "model", width=2, radius=11.5)  # 10 m cells: ~1,000 slope points
    out = tmp_path / "demo"
    result = CliRunner().invoke(app, ["demo", "--out", str(out), "--model", str(model), "--quick"])
    assert result.exit_code == 0, result.output
    lines = result.output.splitlines()
    steps = [line for line in lines if line[:2] in ("1.", "2.", "3.", "4.")]
    assert [s[:2] for s in steps] == ["1.", "2.", "3.", "4."]  # the MPM's two answers first, then the learned engine's
    assert steps[0].startswith("1. MPM forward runout") and "at its 4 m cells" in steps[0]  # the scene's own cells
    assert steps[1].startswith("2. MPM (reverse-mode AD) back-calculation") and "at 10 m cells" in steps[1]
    assert steps[2].startswith("3. GNS forward runout") and "at its 10 m cells" in steps[2]  # the model's spacing
    assert steps[3].startswith("4. GNS back-calculation") and "from 2 starts" in steps[3]
    errors = [lines[lines.index(step) + 1] for step in steps]  # each step's error line follows it
    assert all(error.startswith("   ") and " %" in error for error in errors), errors
    assert "(6750 points)" in errors[0]
    assert "outside the model's training ranges" in errors[3]  # the dam's phi = 0 shell, which no training scene had
    assert "outside" not in errors[1]  # the MPM has no training ranges

    metrics = json.loads((out / "3_slope_learned" / "metrics.json").read_text())  # the GNS beside the MPM of the same points
    left = metrics["runout_left_m"]
    assert left["truth"] > 0 and f"outermost points {left['predicted']:.1f} m left" in result.output
    starts = json.loads((out / "4_dam_learned" / "inverse" / "starts.json").read_text())["starts"]
    assert len(starts) == 2 and starts[0]["initial"] != starts[1]["initial"]  # two L-BFGS-B starts, the lower loss kept
    best = min(range(2), key=lambda k: starts[k]["loss"])
    pictures = lines[lines.index(next(line for line in lines if line.startswith("demo done"))) + 1:]
    expected = ["1_slope_mpm/slope.png", "2_dam_mpm/inverse/parameters.png", "2_dam_mpm/inverse/deposit.png",
                "3_slope_learned/final.png", "3_slope_learned/animation.gif",
                f"4_dam_learned/inverse/start_0{best}/parameters.png", f"4_dam_learned/inverse/start_0{best}/deposit.png",
                "4_dam_learned/inverse/starts.png"]
    assert [p.strip() for p in pictures] == [str(out / name) for name in expected]  # the output ends with the pictures
    for name in expected:
        assert (out / name).stat().st_size > 0, name
    # the slope at its own 4 m cells, at 8 m (step 1's resolution check) and at the model's 10 m; the
    # dam at its own 10 m cells, which are also the model's (steps 2 and 4 share the target)
    runs = {p: p.stat().st_mtime_ns for p in (out / "mpm").glob("*/trajectory.npz")}
    assert len(runs) == 4
    again = CliRunner().invoke(app, ["demo", "--out", str(out), "--model", str(model), "--quick"])
    assert again.exit_code == 0, again.output
    assert "--force removes" not in again.output  # the demo replaces its own back-calculations quietly
    assert {p: p.stat().st_mtime_ns for p in (out / "mpm").glob("*/trajectory.npz")} == runs  # reused, not rerun


def test_the_demo_reads_its_model_from_runout_models(tmp_path, monkeypatch):
    models = tmp_path / "models"
    models.mkdir()
    shutil.copyfile(tiny_model(tmp_path / "model", width=2, radius=11.5), models / "neural-mpm.pt")
    monkeypatch.setenv("RUNOUT_MODELS", str(models))
    result = CliRunner().invoke(app, ["demo", "--out", str(tmp_path / "demo"), "--quick"])
    assert result.exit_code == 0, result.output
    assert f"GNS in {models / 'neural-mpm.pt'}" in result.output  # the file names its engine


def test_runout_models_without_the_model_is_one_sentence(tmp_path, monkeypatch):
    monkeypatch.setenv("RUNOUT_MODELS", str(tmp_path))
    result = CliRunner().invoke(app, ["demo", "--out", str(tmp_path / "demo"), "--quick"])
    assert isinstance(result.exception, InputError)
    assert str(result.exception) == (f"RUNOUT_MODELS={tmp_path}: neural-mpm.pt is not in that folder; set RUNOUT_MODELS to a "
                                     "folder that holds neural-mpm.pt, unset it to use the installed model, or pass --model FILE.")
    assert not (tmp_path / "demo").exists()


def test_demo_refuses_a_model_without_cohesion_input(tmp_path):
    model = tiny_model(tmp_path / "model", width=1, radius=11.5)
    result = CliRunner().invoke(app, ["demo", "--out", str(tmp_path / "demo"), "--model", str(model), "--quick"])
    assert isinstance(result.exception, InputError)
    assert "cohesion input" in str(result.exception)


# ----------------------------------------------------------------------------- GPU session driver


def test_a_base_session_then_a_finetune_session_continue_each_other(tmp_path):
    base_data = session_dataset(tmp_path / "base_data", "base")
    assert session.main(session_args(tmp_path, "base", base_data)) == 0
    out = tmp_path / "out_base"
    assert sorted(p.name for p in out.iterdir()) == ["base.pt", "eval.png", "log.jsonl", "session.json"]
    summary = json.loads((out / "session.json").read_text())
    assert summary["init"] is None and summary["training"]["steps"] >= session.MEASURE_STEPS
    assert summary["training"]["first_steps_per_s"] > 0 and "position_mse_mean_m2" in summary["evaluation"]
    base = read_checkpoint(out / "base.pt")
    assert "optimizer" not in base and base["step"] == summary["training"]["steps"]
    assert base["train"]["onset_schedule"] == TrainConfig.onset_schedule and base["train"]["noise"] == TrainConfig.noise

    (tmp_path / "models").mkdir()
    shutil.copyfile(out / "base.pt", tmp_path / "models" / "base.pt")
    ft_data = session_dataset(tmp_path / "ft_data", "finetune")
    assert session.main(session_args(tmp_path, "finetune", ft_data)) == 0
    tuned = read_checkpoint(tmp_path / "out_finetune" / "slope.pt")
    ft_summary = json.loads((tmp_path / "out_finetune" / "session.json").read_text())
    assert ft_summary["init"] == str(tmp_path / "models" / "base.pt")
    assert tuned["schema"]["material_features"] == ["tan_phi", "c_over_100kPa"]  # widened
    assert tuned["step"] == base["step"] + ft_summary["training"]["steps"]  # cumulative: the lr schedule continues
    assert [s["stage"] for s in tuned["sessions"]] == ["base", "finetune"]


def test_a_committed_model_of_another_radius_is_passed_over(tmp_path):
    models = tmp_path / "models"
    models.mkdir()
    shutil.copyfile(tiny_model(tmp_path / "smoke", width=2, radius=11.5), models / "slope.pt")
    shutil.copyfile(tiny_model(tmp_path / "base", width=1, radius=4.6), models / "base.pt")
    args = session.parse_args(["--stage", "finetune", "--out", str(tmp_path / "out"), "--models", str(models)])
    meta = {"default_connectivity_radius": 4.6, "material_features": ["tan_phi", "c_over_100kPa"]}
    start, skipped = session.starting_checkpoint(args, meta)
    assert start == models / "base.pt"
    assert len(skipped) == 1 and "connectivity radius 11.5 m" in skipped[0]


def test_a_committed_model_trained_before_the_recipe_is_passed_over(tmp_path):
    """The committed solver-3 models (no --exact-rest in their settings) are never a start."""
    models = tmp_path / "models"
    models.mkdir()
    old = read_checkpoint(tiny_model(tmp_path / "old", width=2, radius=4.6))
    old["train"] = {k: v for k, v in old["train"].items() if k != "exact_rest"}
    torch.save(old, models / "slope.pt")
    args = session.parse_args(["--stage", "finetune", "--out", str(tmp_path / "out"), "--models", str(models)])
    meta = {"default_connectivity_radius": 4.6, "material_features": ["tan_phi", "c_over_100kPa"]}
    start, skipped = session.starting_checkpoint(args, meta)
    assert start is None and len(skipped) == 1 and "trained before the recipe" in skipped[0]


def test_a_session_from_a_trained_run_goes_on_in_its_onset_phase(tmp_path):
    """A GPU session started from the campaign's run keeps the onset phase that run had
    reached, instead of replaying the schedule's first phase (40 % of windows from the start)."""
    ckpt = read_checkpoint(tiny_model(tmp_path / "run", width=2, radius=4.6))
    ckpt["train"]["onset_schedule"] = ((0, 0.4, 4), (12000, 0.5, 2), (22231, 0.1, 4), (104237, 0.3, 4))
    for step, phase in ((5000, (0.4, 4)), (30000, (0.1, 4)), (110000, (0.3, 4))):
        ckpt["step"] = step
        torch.save(ckpt, tmp_path / "start.pt")
        assert continued_onset(tmp_path / "start.pt") == {"onset_schedule": ((0, *phase),)}
    assert continued_onset(None) == {}


def test_a_session_whose_deadline_passes_during_generation_says_so(tmp_path):
    args = session_args(tmp_path, "finetune", tmp_path / "new_data", minutes="0.01", reserve="0.599")
    assert session.main(args) == 0
    summary = json.loads((tmp_path / "out_finetune" / "session.json").read_text())
    assert "not complete" in summary["stopped"]
    assert not (tmp_path / "out_finetune" / "slope.pt").exists()


def test_a_reserve_longer_than_the_budget_is_refused(tmp_path, capsys):
    assert session.main(["--stage", "base", "--out", str(tmp_path), "--minutes", "0.5", "--reserve", "30"]) == 2
    assert "--reserve 30 s must lie in [0, 30) s" in capsys.readouterr().err
