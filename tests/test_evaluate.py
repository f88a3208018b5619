import csv
import json
import re
import shutil
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
import torch
from matplotlib.figure import Figure
from matplotlib.text import Text
from typer.testing import CliRunner

import runout.mpm.cache as mpm_cache
from runout.cli import app
from runout.errors import InputError
from runout.evaluate import ColumnCase, MpmCache, column_file, column_scene, scene_key
from runout.evaluate.columns import CSV_COLUMNS
from runout.evaluate.diagnostics import sigma_distance
from runout.evaluate.inverse_study import spec_text
from runout.evaluate.scenes import EXAMPLES, example_scene
from runout.gns.checkpoint import read_checkpoint, save_checkpoint
from runout.gns.schema import FeatureSchema, NetworkConfig
from runout.gns.simulator import GraphNetworkSimulator, Normalisation
from runout.inverse import load_inverse_spec
from runout.metrics import (
    absolute_percentage_error, coefficient_of_variation, displacement_error, normalised_runout, r_squared,
    runout_front, side_runouts,
)
from runout.scene import Material
from runout.trajectory import Trajectory
from test_gns_synthetic import write_dataset

torch.set_num_threads(1)  # tiny graphs: extra threads only add OpenMP synchronisation cost

STATS = Normalisation((0.0, -0.01), (0.02, 0.03), (0.0, -1e-3), (2e-3, 3e-3), 2.5e-3)  # m/frame, m/frame^2
COARSE = ["--frames", "12", "--no-progress"]
COLUMN_GRID = ["--aspects", "1,2", "--phis", "22.5", "--cohesions", "25", "--scale", "0.2"]


def tiny_model(path, materials=("tan_phi", "c_over_100kPa")):
    torch.manual_seed(0)
    simulator = GraphNetworkSimulator(FeatureSchema(material_features=materials), STATS, 4.6, NetworkConfig(16, 16, 2, 2))
    return save_checkpoint(path, simulator)


def invoke(args):
    return CliRunner().invoke(app, [str(a) for a in args])


def tiny_neural_mpm(path):
    from runout.neural_mpm.checkpoint import save_checkpoint
    from runout.neural_mpm.engine import NeuralMPM, NeuralMPMConfig

    torch.manual_seed(0)
    engine = NeuralMPM(NeuralMPMConfig(cell_size=8.0, point_spacing=4.0, history=2, frames_per_call=4, widths=(8, 16),
                                       velocity_scale=0.1))
    for p in engine.parameters():
        p.data.normal_(0.0, 0.1)
    return save_checkpoint(path, engine)


@dataclass
class Studies:
    root: Path  # model.pt, cache/
    out: Path  # the studies' results
    lines: dict[str, str]  # each study command's output
    texts: dict[str, list[str]]  # the texts of every figure saved, by "<folder>/<file>"


def run_studies(root: Path, model: Path, inverse: tuple[str, ...] = ()) -> Studies:
    """The columns, slope, diagnostics and inverse studies of `model` run (coarse) into root/out."""
    common = ["--model", model, "--out", root / "out", "--cache", root / "cache", *COARSE]
    lines, texts, save = {}, {}, Figure.savefig

    def recording(fig, path, *args, **kwargs):
        texts[f"{Path(path).parent.name}/{Path(path).name}"] = [t.get_text() for t in fig.findobj(Text)]
        return save(fig, path, *args, **kwargs)

    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(Figure, "savefig", recording)
        for args in (["columns", *COLUMN_GRID], ["slope", "--scale", "0.2"],
                     ["diagnostics", "--aspect", "1", "--phi", "22.5", "--c", "25", "--scale", "0.2"],
                     ["inverse", "--scale", "0.4", "--max-iterations", "1", *inverse]):
            result = invoke(["evaluate", *args, *common])
            assert result.exit_code == 0, result.output
            lines[args[0]] = result.output
    return Studies(root, root / "out", lines, texts)


@pytest.fixture(scope="module")
def studies(tmp_path_factory):
    """A tiny GNS, and the columns, slope, diagnostics and inverse studies run on it (coarse)."""
    root = tmp_path_factory.mktemp("evaluate")
    return run_studies(root, tiny_model(root / "model.pt"))


@pytest.fixture(scope="module")
def neural_mpm_studies(tmp_path_factory):
    """A tiny neural MPM, and the same studies run on it (the inverse without its yardstick)."""
    root = tmp_path_factory.mktemp("evaluate_neural_mpm")
    return run_studies(root, tiny_neural_mpm(root / "model.pt"), ("--no-yardstick",))


def line(positions) -> Trajectory:
    """Soil points along x with the given positions [T, N] (m), y = 1 m."""
    positions = np.asarray(positions, dtype=np.float32)
    xy = np.stack([positions, np.ones_like(positions)], axis=-1)
    n = positions.shape[1]
    return Trajectory(xy, np.full(n, 6), np.zeros(n, dtype=np.int64), [Material("soil")], 0.0375, np.array([[0, 100], [0, 10]]))


# ----------------------------------------------------------------------------- metrics


def test_normalised_runout_is_the_relative_growth_of_the_front():
    assert normalised_runout(150.0, 300.0) == pytest.approx(1.0)
    assert normalised_runout(100.0, 186.3) == pytest.approx(0.863)


def test_absolute_percentage_error_cv_and_r2_on_known_numbers():
    np.testing.assert_allclose(absolute_percentage_error([110.0, 90.0, 0.863], [100.0, 100.0, 0.848]), [10.0, 10.0, 1.7688679], rtol=1e-6)
    assert np.isnan(absolute_percentage_error(1.0, 0.0))
    assert coefficient_of_variation([1.0, 3.0]) == pytest.approx(0.5)  # population std 1 over mean 2
    assert r_squared([1.0, 2.0, 4.0], [1.0, 2.0, 3.0]) == pytest.approx(0.5)  # 1 - 1 / 2
    assert r_squared([2.0, 2.0, 2.0], [1.0, 2.0, 3.0]) == pytest.approx(0.0)
    assert r_squared([3.0, 2.0, 1.0], [1.0, 2.0, 3.0]) == pytest.approx(-3.0)  # not a fitted line's R²


def test_fronts_side_runouts_and_displacement_errors():
    truth = line([[40.0, 50.0, 60.0], [30.0, 50.0, 75.0]])
    predicted = line([[40.0, 50.0, 60.0], [32.0, 50.0, 72.0]])
    assert runout_front(truth, 0) == 60.0 and runout_front(truth) == 75.0
    assert side_runouts(truth, 50.0) == (20.0, 25.0)
    np.testing.assert_allclose(displacement_error(predicted, truth), [[0, 0, 0], [2, 0, 3]])


def test_sigma_distance_places_points_on_the_ellipses():
    v = np.array([[1.0, -2.0], [3.0, -2.0], [1.0, 2.0]])
    np.testing.assert_allclose(sigma_distance(v, np.array([1.0, -2.0]), np.array([2.0, 4.0])), [0.0, 1.0, 1.0])


# ----------------------------------------------------------------------------- MPM cache


def test_missing_scenes_run_in_one_batch_and_are_keyed_by_their_toml(tmp_path, monkeypatch):
    calls = []
    real = mpm_cache.simulate
    monkeypatch.setattr(mpm_cache, "simulate", lambda scenes, **kw: calls.append(len(scenes)) or real(scenes, **kw))
    column = example_scene(EXAMPLES, column_file(1.0))
    a = column_scene(column, ColumnCase(1.0, 22.5, 25.0), 8, 0.1)
    b = column_scene(column, ColumnCase(1.0, 22.5, 40.0), 8, 0.1)
    cache = MpmCache(tmp_path)
    paths = cache.ensure([a, b, a], progress=False)
    assert calls == [2] and cache.simulated == 2
    assert paths[0] == paths[2] != paths[1] and scene_key(a) != scene_key(b)
    assert (paths[0] / "scene.toml").is_file() and cache.load(a).n_frames == 8


def test_a_second_columns_run_reads_the_mpm_from_the_cache(studies, tmp_path, monkeypatch):
    def no_mpm(*args, **kwargs):
        raise AssertionError("the MPM ran although every scene is cached")

    monkeypatch.setattr(mpm_cache, "simulate", no_mpm)
    one_case = ["--aspects", "2", "--phis", "22.5", "--cohesions", "25", "--scale", "0.2"]
    result = invoke(["evaluate", "columns", *one_case, *COARSE, "--model", studies.root / "model.pt", "--out", tmp_path,
                     "--cache", studies.root / "cache"])
    assert result.exit_code == 0, result.output
    assert (tmp_path / "columns" / "cases.csv").read_text().count("\n") == 2


# ----------------------------------------------------------------------------- studies


def test_a_study_runs_the_mpm_and_the_gns_at_the_models_spacing(tmp_path):
    from runout.evaluate import StudyContext, run_columns
    from runout.evaluate.columns import ColumnGrid
    from runout.gns.checkpoint import load_simulator
    from runout.learned.training_range import point_spacing
    from runout.scene import load_scene
    from runout.trajectory import load_trajectory

    simulator = load_simulator(tiny_model(tmp_path / "model.pt"))
    simulator.data_ranges = {"point_spacing_m": 5.0}  # trained at 10 m cells; the example columns have 4 m
    save_checkpoint(tmp_path / "coarse.pt", simulator)
    lines = []
    run = StudyContext(MpmCache(tmp_path / "cache"), progress=False, log=lines.append)
    summary = run_columns(tmp_path / "coarse.pt", tmp_path / "out", ColumnGrid((1.0,), (22.5,), (25.0,), 8, 0.2), run)
    assert lines == ["filling column_a1.toml at the model's 5 m spacing (10 m cells) instead of the scene's 4 m cells"]
    mpm_dir = tmp_path / "cache" / summary["percentile_cases"]["50"]["mpm_key"]
    assert load_scene(mpm_dir / "scene.toml").domain.cell_size == 10.0
    predicted = load_trajectory(tmp_path / "out" / "columns" / "predicted" / "column_a1_phi22.5_c25")
    assert point_spacing(load_trajectory(mpm_dir)) == point_spacing(predicted) == pytest.approx(5.0)
    assert summary["percentile_cases"]["50"]["L0_m"] == pytest.approx(30.0)  # a 150 m column at scale 0.2


def test_columns_writes_every_case_with_its_runouts_and_errors(studies):
    folder = studies.out / "columns"
    with (folder / "cases.csv").open() as f:
        rows = list(csv.DictReader(f))
    assert tuple(rows[0]) == CSV_COLUMNS and len(rows) == 2
    assert {"Lf_predicted_m", "runout_norm_predicted", "predicted_wall_s"} <= set(rows[0])  # the engine's, whichever ran
    assert not any("gns" in column for column in rows[0])
    for row in rows:
        l0, lf, n = float(row["L0_m"]), float(row["Lf_mpm_m"]), float(row["runout_norm_mpm"])
        assert n == pytest.approx((lf - l0) / l0)
        expected = abs(float(row["runout_norm_predicted"]) - n) / n * 100
        assert float(row["ape_percent"]) == pytest.approx(expected)
    assert {float(r["L0_m"]) for r in rows} == {30.0, 20.0}  # columns 150 and 100 m wide, scale 0.2
    summary = json.loads((folder / "summary.json").read_text())
    assert [b["aspect"] for b in summary["by_aspect"]] == [1.0, 2.0] and summary["model"]["steps"] is None
    for b in summary["by_friction_angle"]:  # signed: predicted minus MPM over MPM, per aspect and friction angle
        group = [r for r in rows if float(r["aspect"]) == b["aspect"] and float(r["phi_deg"]) == b["phi_deg"]]
        expected = np.mean([(float(r["runout_norm_predicted"]) / float(r["runout_norm_mpm"]) - 1) * 100 for r in group])
        assert b["cases"] == len(group) and b["mean_signed_error_percent"] == pytest.approx(expected)
        assert abs(b["mean_signed_error_percent"]) <= b["mean_ape_percent"] + 1e-9
    assert sum(b["cases"] for b in summary["by_friction_angle"]) == len(rows)
    assert summary["predicted_wall_s_total"] > 0 and sorted(p.name for p in (folder / "predicted").iterdir()) == [r["case"] for r in rows]
    for name in ("runout_1to1.png", "error_heatmaps.png", "evolution_p25.png", "evolution_p50.png", "evolution_p75.png"):
        assert (folder / name).stat().st_size > 1000


def test_slope_reports_both_sides_wall_times_and_figures(studies):
    folder = studies.out / "slope"
    s = json.loads((folder / "summary.json").read_text())
    assert s["centre_m"] == pytest.approx(100.0) and s["frames"] == 12
    assert s["runout_left_m"]["mpm"] > 0 and s["runout_right_m"]["predicted"] > 0
    assert s["wall_time_s"]["mpm"] > 0 and s["wall_time_s"]["predicted"] > 0
    assert (folder / "predicted" / "trajectory.npz").is_file() and not (folder / "gns").exists()
    for name in ("fields_materials.png", "fields_displacement.png", "displacement_error.png"):
        assert (folder / name).stat().st_size > 1000


def test_diagnostics_use_the_models_training_velocities(studies):
    s = json.loads((studies.out / "diagnostics" / "summary.json").read_text())
    np.testing.assert_allclose(s["training_velocity_m_s"]["std"], np.array(STATS.vel_std) / 0.0375)
    assert [f["frame"] for f in s["frames"]] == [11]
    assert (studies.out / "diagnostics" / "velocity_diagnostics.png").is_file()


def test_inverse_records_truth_bounds_model_loss_and_figures(studies):
    folder = studies.out / "inverse"
    s = json.loads((folder / "summary.json").read_text())
    assert [(p["true"], p["lower"], p["upper"]) for p in s["parameters"]] == [(40.0, 10.0, 100.0), (100.0, 99.0, 101.0), (41.0, 5.0, 50.0)]
    assert all(p["lower"] <= p["inferred"] <= p["upper"] for p in s["parameters"])
    assert s["history"][0]["model_loss"] == pytest.approx(np.mean([(80 - 40) ** 2 / 90**2, 0.0, (30 - 41) ** 2 / 45**2]))
    for name in ("target.png", "run/loss.png", "run/parameters.png", "run/deposit.png", "run_mpm_ad/parameters.png"):
        assert (folder / name).is_file()


def test_inverse_solves_the_same_problem_through_the_mpm_as_its_yardstick(studies):
    s = json.loads((studies.out / "inverse" / "summary.json").read_text())
    y = s["yardstick"]
    assert s["engine"] == "gns" and y["engine"] == "mpm-ad"
    assert [p["name"] for p in y["parameters"]] == [p["name"] for p in s["parameters"]]
    assert [p["initial"] for p in y["parameters"]] == [80.0, 100.0, 30.0]  # the same start as the GNS
    assert all(p["lower"] <= p["inferred"] <= p["upper"] for p in y["parameters"])
    for engine in (s, y):  # the cost of an iteration: every evaluation's forward and backward time over the iterations
        assert engine["seconds"] > 0
        assert engine["seconds_per_iteration"] == pytest.approx(engine["seconds"] / max(engine["iterations"], 1))
    history = json.loads((studies.out / "inverse" / "run_mpm_ad" / "history.json").read_text())
    assert history["run"]["engine"] == "mpm-ad" and history["run"]["model"] == ""


def test_inverse_records_each_engines_data_loss_at_the_true_values(studies):
    """The target is the MPM's run of the same scene at the same spacing, so the MPM-AD's loss at the
    truth is rounding alone: measured 1.8e-11 m² (the target's float32 records against the float64
    MPM-AD run), against 4.9e-5 m² at its answer after one iteration."""
    s = json.loads((studies.out / "inverse" / "summary.json").read_text())
    y = s["yardstick"]
    for engine in (s, y):
        assert np.isfinite(engine["data_loss_at_true_m2"]) and engine["data_loss_at_true_m2"] >= 0
    assert y["data_loss_at_true_m2"] < 1e-8 < y["final_data_loss_m2"]
    for label, engine in (("GNS", s), ("MPM-AD", y)):
        assert (f"{label} at the true values: data loss {engine['data_loss_at_true_m2']:.4g} m² "
                f"(its answer: {engine['final_data_loss_m2']:.4g} m²)") in studies.lines["inverse"]


def test_inverse_spec_keeps_the_papers_bounds_and_points_at_the_mpm_target(tmp_path):
    import tomllib

    example = tomllib.loads((EXAMPLES / "dam_inverse.toml").read_text())
    shutil.copyfile(EXAMPLES / "dam.toml", tmp_path / "scene.toml")
    (tmp_path / "spec.toml").write_text(spec_text(example, tmp_path / "target", 3))
    spec = load_inverse_spec(tmp_path / "spec.toml")
    bounds = {p.name: (p.lower, p.upper) for p in spec.free}
    assert bounds == {"c[m1_downstream_lower]": (10.0, 100.0), "c[m2_core]": (99.0, 101.0), "phi[m3_downstream_upper]": (5.0, 50.0)}
    assert spec.target.trajectory == tmp_path / "target" and spec.optimiser.max_iterations == 3


def test_sensitivity_fine_tunes_each_subset_under_both_budgets(tmp_path):
    data = write_dataset(tmp_path / "data", frames=10, n_train=2, width=1)
    shutil.copyfile(data / "valid.npz", data / "test.npz")
    model = tiny_model(tmp_path / "base.pt", ("tan_phi",))
    args = ["evaluate", "sensitivity", "--data", data, "--init", model, "--out", tmp_path / "out", "--sizes", "1,2",
            "--steps", "2", "--epochs", "1", "--held-out", "1", "--no-progress"]
    result = invoke(args)
    assert result.exit_code == 0, result.output
    s = json.loads((tmp_path / "out" / "sensitivity" / "summary.json").read_text())
    steps = {(r["budget"], r["size"]): r["steps"] for r in s["results"]}
    assert steps == {("steps", 1): 2, ("steps", 2): 2, ("epochs", 1): 5, ("epochs", 2): 9}  # 9 windows per simulation (5 from rest), batch 2
    assert all(r["p25_mse_m2"] <= r["median_mse_m2"] <= r["p75_mse_m2"] for r in s["results"])
    assert (tmp_path / "out" / "sensitivity" / "rollout_mse.png").is_file()
    # each subset is fine-tuned with the recipe that trained the shipped model, not TrainConfig's bare defaults
    settings = read_checkpoint(tmp_path / "out" / "sensitivity" / "steps_1" / "checkpoint.pt")["train"]
    assert (settings["noise"], settings["exact_rest"], settings["pushforward"], settings["ema"]) == (0.01, True, 2, 0.999)


def test_sensitivity_can_run_the_step_budget_alone(tmp_path, capfd):
    data = write_dataset(tmp_path / "data", frames=10, n_train=2, width=1)
    model = tiny_model(tmp_path / "base.pt", ("tan_phi",))
    args = ["evaluate", "sensitivity", "--data", data, "--init", model, "--out", tmp_path / "out", "--sizes", "1,2",
            "--steps", "2", "--budgets", "steps", "--split", "valid", "--held-out", "1", "--no-progress"]
    result = invoke(args)
    assert result.exit_code == 0, result.output
    folder = tmp_path / "out" / "sensitivity"
    s = json.loads((folder / "summary.json").read_text())
    assert [(r["budget"], r["size"], r["steps"]) for r in s["results"]] == [("steps", 1, 2), ("steps", 2, 2)]
    assert "GNS training" not in result.output + capfd.readouterr().err  # --no-progress reaches the fine-tunes' bars too
    assert not any(folder.glob("epochs_*")) and (folder / "loss_history.png").is_file()
    doc = tmp_path / "r.md"
    assert invoke(["evaluate", "report", "--out", tmp_path / "out", "--doc", doc]).exit_code == 0
    assert "fixed budget 2 steps (the other budget not run)" in doc.read_text()
    assert "stays level from about 250 on" in doc.read_text()  # the paper's finding beside ours
    bad = invoke(args[:-1] + ["--budgets", "hours", "--no-progress"])
    assert str(bad.exception) == "--budgets 'hours' must name steps, epochs or both, e.g. steps,epochs."


def column_and_slope_summaries(engine: str) -> tuple[dict, dict]:
    """A columns and a slope summary at the paper's geometry, with keys as the code writes them
    now (engine "predicted") or as it wrote them before they named no engine ("gns")."""
    case = {"aspect": 1.0, "phi_deg": 0.0, "cohesion_kpa": 10.0, "runout_norm_mpm": 3.5, f"runout_norm_{engine}": 3.0,
            "ape_percent": 14.29}
    columns = {"cases": 1, "grid": {"aspects": [1.0], "phis_deg": [0.0], "cohesions_kpa": [10.0], "frames": 600, "scale": 1.0},
               "mean_ape_percent": 5.0, "median_ape_percent": 5.0, f"{engine}_wall_s_total": 1.0, "percentile_cases": {"50": case},
               "by_aspect": [{"aspect": 1.0, "cases": 1, "mean_ape_percent": 5.0, "cv_ape": 0.1, "r2": 0.9}]}
    side = {"mpm": 300.0, engine: 297.0, "ape_percent": 1.0}
    slope = {"points": 10, "frames": 480, "scale": 1.0, "centre_m": 500.0, "runout_left_m": side, "runout_right_m": side,
             "median_displacement_error_final_m": 1.0, "max_displacement_error_final_m": 2.0,
             "wall_time_s": {"mpm": 1.0, "mpm_device": "cpu", "mpm_host": "h", "mpm_batch_size": 1, engine: 2.0,
                             f"{engine}_device": "cuda", f"{engine}_host": "g"}}
    return columns, slope


def test_report_tables_the_signed_error_by_friction_angle_where_the_summary_has_it():
    from runout.evaluate.report import SECTIONS

    columns, _ = column_and_slope_summaries("predicted")
    assert not any("by friction angle" in line for line in SECTIONS["columns"](columns, "neural MPM"))  # older summaries
    columns["by_friction_angle"] = [{"aspect": 1.0, "phi_deg": 0.0, "cases": 1, "mean_signed_error_percent": -14.29,
                                     "mean_ape_percent": 14.29}]
    lines = SECTIONS["columns"](columns, "neural MPM")
    assert any("signed error of L^n by friction angle" in line for line in lines)
    assert "| aspect a | φ = 0° |" in lines and "| 1 | -14.29 |" in lines


@pytest.mark.parametrize("keys", ["predicted", "gns"])
@pytest.mark.parametrize("label", ["GNS", "neural MPM"])
def test_report_sets_the_papers_figures_beside_ours_at_the_papers_geometry(keys, label):
    from runout.evaluate.report import SECTIONS

    columns, slope = column_and_slope_summaries(keys)
    lines = SECTIONS["columns"](columns, label)
    assert "| 1 | 1 | 5 | 3.55 | 0.1 | 0.9 | 0.994 |" in lines  # §5.1.1: a = 1
    assert f"| percentile | a | φ (°) | c (kPa) | L^n MPM | L^n {label} | error (%) |" in lines
    assert "| 50 | 1 | 0 | 10 | 3.5 | 3 | 14.29 |" in lines
    assert any(f"{label} wall time for all cases 1.0 s." in line for line in lines)
    lines = SECTIONS["slope"](slope, label)
    assert "| left | 300 | 297 | 1 | 1.57 |" in lines and "| right | 300 | 297 | 1 | 0.96 |" in lines  # §5.1.2
    assert f"| side | MPM (m) | {label} (m) | error (%) | paper (%) |" in lines
    assert lines[-1].endswith(f"{label} 2 s (cuda on g).")


def inverse_summary(at_truth: float | None, yardstick_at_truth: float | None) -> dict:
    """An inverse summary with the learned engine's answer at 30 m² and the MPM-AD's at 1e-4 m²;
    None leaves an engine's loss at the true values out, as summaries written before it do."""
    parameter = {"name": "c[m1_downstream_lower]", "unit": "kPa", "lower": 10.0, "upper": 100.0, "initial": 80.0,
                 "true": 40.0, "inferred": 10.0}
    engine = {"parameters": [parameter], "final_data_loss_m2": 30.0, "iterations": 3, "evaluations": 5, "message": "done",
              "seconds": 6.0, "seconds_per_iteration": 2.0, "history": []}
    yardstick = engine | {"final_data_loss_m2": 1e-4, "engine": "mpm-ad"}
    if at_truth is not None:
        engine["data_loss_at_true_m2"] = at_truth
    if yardstick_at_truth is not None:
        yardstick["data_loss_at_true_m2"] = yardstick_at_truth
    return engine | {"scale": 1.0, "frames": 400, "yardstick": yardstick}


@pytest.mark.parametrize("at_truth, meaning", [
    (150.0, "the GNS's response at the true strengths is further from the target than at its answer: "
            "the error is the model's, not the optimiser's."),
    (31.0, "the GNS's loss is about the same at the true strengths as at its answer: where the answer misses them, "
           "the loss surface is flat between the two."),
    (2.0, "the GNS's loss is lower at the true strengths than at its answer: the optimiser stopped short of them."),
])
def test_report_says_what_the_loss_at_the_true_values_means(at_truth, meaning):
    from runout.evaluate.report import SECTIONS

    lines = SECTIONS["inverse"](inverse_summary(at_truth, 2e-11), "GNS")
    table_end = lines.index("| c[m1_downstream_lower] | kPa | [10, 100] | 80 | 40 | 10 | 46.17 | 10 |")
    assert lines[table_end + 2] == (f"Data loss at the true values: GNS {at_truth:g} m² (30 m² at its answer), "
                                    f"MPM-AD 2e-11 m² (0.0001 m² at its answer); {meaning}")


def test_report_of_an_inverse_summary_without_the_loss_at_the_true_values_says_nothing_of_it():
    from runout.evaluate.report import SECTIONS

    lines = SECTIONS["inverse"](inverse_summary(None, None), "GNS")
    assert "| c[m1_downstream_lower] | kPa | [10, 100] | 80 | 40 | 10 | 46.17 | 10 |" in lines
    assert not any("true values" in line for line in lines)


def test_report_reads_the_summaries_of_the_code_before_its_keys_named_no_engine(tmp_path):
    """docs/results.md was written from such summaries (runs/final*): they must still be reported."""
    card = {"path": "models/slope.pt", "sha256": "7092af7fec97", "steps": 157561, "base_steps": 20000,
            "training_data": "data/ft8", "initialised_from": "models/base-best20000.pt",
            "material_features": ["tan_phi", "c_over_100kPa"], "parameters": 215762, "network": {}}  # no engine, no stride
    columns, slope = column_and_slope_summaries("gns")
    for study, summary in (("columns", columns), ("slope", slope)):
        (tmp_path / "out" / study).mkdir(parents=True)
        (tmp_path / "out" / study / "summary.json").write_text(json.dumps({"study": study, "model": card, **summary}))
    doc = tmp_path / "r.md"
    result = invoke(["evaluate", "report", "--out", tmp_path / "out", "--doc", doc])
    assert result.exit_code == 0, result.output
    text = doc.read_text()
    assert text.count("(GNS, sha256 7092af7fec97…, 215,762 parameters") == 2
    assert "GNS wall time for all cases 1.0 s." in text and "| L^n MPM | L^n GNS |" in text
    assert "| 50 | 1 | 0 | 10 | 3.5 | 3 | 14.29 |" in text and "| left | 300 | 297 | 1 | 1.57 |" in text
    assert "GNS 2 s (cuda on g)." in text



def results_folder(out: Path, engine: str, path: str, summaries: dict[str, dict]) -> Path:
    """A results folder of `engine`'s model at `path`: each study's summary.json and two figures
    whose bytes name the folder."""
    card = {"path": path, "sha256": "0123456789ab", "steps": 1000, "base_steps": 0, "training_data": "data/x",
            "initialised_from": None, "material_features": ["tan_phi"], "parameters": 10, "network": {}, "engine": engine}
    for study, summary in summaries.items():
        (out / study).mkdir(parents=True)
        (out / study / "summary.json").write_text(json.dumps({"study": study, "model": card, **summary}))
    (out / "columns" / "runout_1to1.png").write_bytes(out.name.encode())
    (out / "inverse" / "run").mkdir()
    (out / "inverse" / "run" / "loss.png").write_bytes(out.name.encode())
    return out


def two_engines_results(root: Path) -> tuple[Path, Path]:
    """A GNS's results (summaries as written before the keys named no engine) and a neural MPM's,
    with different numbers; the neural MPM's inverse frees one parameter more."""
    gns_columns, gns_slope = column_and_slope_summaries("gns")
    gns = results_folder(root / "gns", "gns", "models/slope.pt",
                         {"columns": gns_columns, "slope": gns_slope, "inverse": inverse_summary(150.0, None)})
    columns, slope = column_and_slope_summaries("predicted")
    columns["by_aspect"][0] |= {"mean_ape_percent": 8.5, "r2": 0.8}
    slope["runout_left_m"] = slope["runout_left_m"] | {"ape_percent": 2.5}
    slope["wall_time_s"]["predicted"] = 0.25
    inverse = inverse_summary(None, None)
    phi = {"name": "phi[m3_downstream_upper]", "unit": "°", "lower": 5.0, "upper": 50.0, "initial": 30.0, "true": 38.0,
           "inferred": 39.0}
    inverse["parameters"] = [inverse["parameters"][0] | {"inferred": 35.0}, phi]
    inverse["yardstick"]["parameters"] = inverse["parameters"]
    inverse["seconds_per_iteration"] = 0.5
    nmpm = results_folder(root / "nmpm", "neural-mpm", "models/neural-mpm.pt",
                          {"columns": columns, "slope": slope, "inverse": inverse})
    return gns, nmpm


def test_report_of_two_engines_sets_them_side_by_side_beside_the_paper(tmp_path):
    from runout.evaluate import write_report

    gns, nmpm = two_engines_results(tmp_path)
    doc = tmp_path / "docs" / "results.md"
    text = write_report([gns, nmpm], doc).read_text()
    assert f"Generated by `runout evaluate report --out {gns} --out {nmpm}` on " in text
    table = text[text.index("## Side by side"):text.index("## Column collapse")].splitlines()
    assert table[2] == "| measure | paper (GNS) | GNS (`models/slope.pt`) | neural MPM (`models/neural-mpm.pt`) |"
    for row in ("| column collapse a = 0.5: mean error (%) | 7.26 | – | – |",
                "| column collapse a = 1: mean error (%) | 3.55 | 5 | 8.5 |",
                "| column collapse a = 2: R² | 0.957 | – | – |",
                "| column collapse a = 1: R² | 0.994 | 0.9 | 0.8 |",
                "| four-layer slope left runout error (%) | 1.57 | 1 | 2.5 |",
                "| four-layer slope right runout error (%) | 0.96 | 1 | 1 |",
                "| four-layer slope rollout wall time, learned engine (s) | – | 2 | 0.25 |",
                "| four-layer slope rollout wall time, MPM (s) | – | 1 | 1 |",
                "| dam c[m1_downstream_lower] (kPa, true 40) | 46.17 | 10 | 35 |",
                "| dam phi[m3_downstream_upper] (°, true 38) | 40.24 | – | 39 |",
                "| dam data loss at the true values (m²) | – | 150 | – |",
                "| dam seconds per L-BFGS-B iteration (paper: on a GPU) | 62 | 2 | 0.5 |"):
        assert row in table, row
    assert "Each engine's model and its training come in its sections below" in text
    for label in ("GNS", "neural MPM"):
        for title in ("Column collapse (paper §5.1.1)", "Four-layer slope (paper §5.1.2)", "Dam inversion (paper §5.2)"):
            assert text.count(f"\n## {title}: {label}\n") == 1
        assert f"## Velocity-space error diagnostics (paper §5.1.1): {label}\n\nNot run" in text
    assert text.index("## Dam inversion (paper §5.2): GNS") < text.index("## Column collapse (paper §5.1.1): neural MPM")
    assert "| side | MPM (m) | neural MPM (m) | error (%) | paper (%) |" in text and "| left | 300 | 297 | 2.5 | 1.57 |" in text
    figures = doc.parent / "results_figures"
    for k, folder in ((1, gns), (2, nmpm)):
        for name in ("columns_runout_1to1.png", "inverse_run_loss.png"):
            assert (figures / f"{k}_{name}").read_bytes() == folder.name.encode()
            assert f"](results_figures/{k}_{name})" in text
    assert not (figures / "columns_runout_1to1.png").exists()
    result = invoke(["evaluate", "report", "--out", gns, "--out", nmpm, "--doc", tmp_path / "cli.md"])
    assert result.exit_code == 0, result.output
    assert (tmp_path / "cli.md").read_text() == text.replace("results_figures/", "cli_figures/")


def test_side_by_side_shows_the_papers_values_only_where_every_engine_ran_the_papers_geometry(tmp_path):
    from runout.evaluate import write_report

    gns, nmpm = two_engines_results(tmp_path)
    summary = json.loads((nmpm / "columns" / "summary.json").read_text())
    summary["grid"]["scale"] = 0.2
    (nmpm / "columns" / "summary.json").write_text(json.dumps(summary))
    text = write_report([gns, nmpm], tmp_path / "r.md").read_text()
    assert "| column collapse a = 1: mean error (%) | – | 5 | 8.5 |" in text
    assert "| four-layer slope left runout error (%) | 1.57 | 1 | 2.5 |" in text


def test_report_of_one_folder_is_the_page_it_always_was(tmp_path):
    from runout.evaluate import write_report

    gns, _ = two_engines_results(tmp_path)
    text = write_report(gns, tmp_path / "one.md").read_text()
    assert write_report([gns], tmp_path / "list.md").read_text() == text.replace("one_figures/", "list_figures/")
    assert "Side by side" not in text and "| measure |" not in text
    assert "\n## Column collapse (paper §5.1.1)\n" in text and ": GNS\n" not in text
    assert "](one_figures/columns_runout_1to1.png)" in text and (tmp_path / "one_figures" / "inverse_run_loss.png").is_file()
    (tmp_path / "empty").mkdir()
    with pytest.raises(InputError, match=f"^{re.escape(str(tmp_path / 'empty'))}: holds no study results"):
        write_report([gns, tmp_path / "empty"], tmp_path / "r.md")

FIGURES_NAMING_THE_ENGINE = ("columns/runout_1to1.png", "columns/evolution_p75.png", "slope/fields_materials.png",
                             "slope/fields_displacement.png", "slope/displacement_error.png",
                             "diagnostics/velocity_diagnostics.png")


def assert_named(studies: Studies, label: str, other: str) -> None:
    """Every figure that shows the learned engine, and the slope's and the inverse's lines, name it,
    never the other engine."""
    for name in FIGURES_NAMING_THE_ENGINE:
        texts = studies.texts[name]
        assert any(label in text for text in texts), name
        assert not any(other in text for text in texts), name
    assert re.search(rf"wall time MPM \S+ s, {label} \S+ s", studies.lines["slope"])
    assert f"seconds per L-BFGS-B iteration: {label} " in studies.lines["inverse"]
    assert not any(other in text for text in studies.lines.values())


def test_every_label_names_the_gns_that_ran(studies):
    assert_named(studies, "GNS", "neural MPM")
    assert json.loads((studies.out / "inverse" / "summary.json").read_text())["engine"] == "gns"


def test_every_label_names_the_neural_mpm_that_ran(neural_mpm_studies, tmp_path):
    studies = neural_mpm_studies
    assert_named(studies, "neural MPM", "GNS")
    for study in ("columns", "slope", "diagnostics"):
        assert (studies.out / study / "predicted").is_dir() and not (studies.out / study / "gns").exists()
    for study in ("columns", "slope", "diagnostics", "inverse"):
        text = (studies.out / study / "summary.json").read_text()
        assert '"engine": "neural-mpm"' in text and "gns" not in text
    doc = tmp_path / "r.md"
    assert invoke(["evaluate", "report", "--out", studies.out, "--doc", doc]).exit_code == 0
    text = doc.read_text()
    assert text.count("(neural MPM, sha256") == 4
    assert "neural MPM wall time for all cases" in text and "| L^n MPM | L^n neural MPM | error (%) |" in text
    assert "| side | MPM (m) | neural MPM (m) | error (%) | paper (%) |" in text
    assert "Velocity errors of the neural MPM against the MPM:" in text
    assert "| inferred (neural MPM) | paper (GNS) |" in text and "Per iteration (neural MPM):" in text
    assert "Cost on this machine: neural MPM " in text
    assert text.count("GNS") == text.count("paper (GNS)") + text.count("The paper's GNS")  # the paper's figures alone


def test_report_names_the_model_and_links_existing_figures(studies, tmp_path):
    doc = tmp_path / "docs" / "results.md"
    result = invoke(["evaluate", "report", "--out", studies.out, "--doc", doc])
    assert result.exit_code == 0, result.output
    text = doc.read_text()
    assert "untrained (saved without a training run)" in text and "shrunk: not the paper's geometry" in text
    assert "| aspect a | cases | mean error (%) | paper (%) | CV | R² | paper R² |" in text
    assert "Not run (`runout evaluate sensitivity`)." in text
    assert "| 0.96 |" not in text and "| 3.55 |" not in text  # shrunk scenes are not the paper's: no paper figure beside them
    assert "| inferred (GNS) | paper (GNS) | inferred (MPM-AD) |" in text and "s per L-BFGS-B iteration" in text
    assert "Data loss at the true values: GNS " in text and " m² at its answer), MPM-AD " in text
    links = [part.split(")")[0] for part in text.split("](")[1:]]
    assert links and all((doc.parent / link).is_file() for link in links)


# ----------------------------------------------------------------------------- bad input


@pytest.mark.parametrize("args, message", [
    (["columns", "--aspects", "3"], "aspect ratio 3 has no example column; choose from 0.5, 1, 2."),
    (["columns", "--phis", "ten"], "--phis 'ten' must be numbers separated by commas, e.g. 0.5,1,2."),
    (["columns", "--scale", "0"], "--scale = 0 is outside the allowed range (0, 1]."),
    (["columns", "--phis", "75"], "<scene>: materials.soil.friction_angle = 75 is outside the allowed range [0, 60] degrees."),
    (["slope", "--frames", "1"], "--frames = 1 must be at least 2: frame 0 and the first frame the model predicts, 1 frame on."),
])
def test_bad_study_input_is_one_sentence(tmp_path, args, message):
    model = tiny_model(tmp_path / "m.pt")
    result = invoke(["evaluate", *args, "--model", model, "--out", tmp_path / "o", "--cache", tmp_path / "c", "--no-progress"])
    assert isinstance(result.exception, InputError)
    assert str(result.exception) == message


def test_the_data_size_study_refuses_a_neural_mpm_in_one_sentence(tmp_path, capsys):
    from test_cli_exits import one_sentence, run

    model = tiny_neural_mpm(tmp_path / "nmpm.pt")
    code, err = run(["evaluate", "sensitivity", "--data", tmp_path, "--init", model, "--out", tmp_path / "out"], capsys)
    assert code == 2 and one_sentence(err)
    assert err.strip().splitlines()[-1] == (f"error: --init {model}: holds a neural MPM, but the data-size study "
                                            "fine-tunes GNS checkpoints only; give a GNS checkpoint.")
    assert not (tmp_path / "out").exists()


def test_bad_sizes_and_an_empty_report_are_input_errors(tmp_path):
    result = invoke(["evaluate", "sensitivity", "--data", tmp_path, "--init", tmp_path / "m.pt", "--out", tmp_path, "--sizes", "0,10"])
    assert str(result.exception) == "--sizes '0,10' must be positive whole numbers, e.g. 10,50,100."
    result = invoke(["evaluate", "report", "--out", tmp_path, "--doc", tmp_path / "r.md"])
    assert isinstance(result.exception, InputError) and "holds no study results" in str(result.exception)
