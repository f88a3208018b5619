"""`runout compare`: the MPM and the shipped model on one tiny scene at the model's
resolution (its training cells, coarser than the scene's 4 m), its metrics, pictures, and the
refusal of bad input."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
import torch

from runout.compare import comparison_metrics
from runout.gns.checkpoint import load_simulator
from runout.learned.training_range import point_spacing
from runout.metrics import deposit_iou, occupied_cells
from runout.scene import Material, save_scene, scene_from_dict
from runout.trajectory import Trajectory, load_trajectory
from test_cli_exits import one_sentence, run

REPO = Path(__file__).resolve().parents[1]
MODEL = REPO / "models" / "slope.pt"  # trained at 8 m cells (4 m point spacing); any coarser than 4 m cells
SPACING = load_simulator(MODEL).point_spacing  # m, the spacing of the model's training data
FRAMES = 12

# a two-layer mound at 4 m cells in the file; compare fills it at the model's cells
MOUND = {
    "name": "mound",
    "domain": {"width": 120.0, "height": 60.0, "cell_size": 4.0},
    "time": {"frames": 40},
    "materials": {"top": {"friction_angle": 20.0, "cohesion": 15.0}, "base": {"friction_angle": 15.0, "cohesion": 20.0}},
    "regions": [
        {"material": "base", "polygon": [[30, 0], [90, 0], [80, 15], [40, 15]]},
        {"material": "top", "polygon": [[40, 15], [80, 15], [70, 30], [50, 30]]},
    ],
}


@pytest.fixture(scope="module")
def compared(tmp_path_factory):
    """(folder, stdout) of `runout compare` on MOUND for FRAMES frames."""
    torch.set_num_threads(1)
    folder = tmp_path_factory.mktemp("compare")
    save_scene(scene_from_dict(MOUND, "mound"), folder / "mound.toml")
    argv = ["compare", folder / "mound.toml", "--model", MODEL, "--out", folder / "out", "--frames", FRAMES,
            "--cache", folder / "cache", "--no-progress"]
    return folder, _stdout(argv)


def _stdout(argv) -> str:
    from typer.testing import CliRunner

    from runout.cli import app

    result = CliRunner().invoke(app, [str(a) for a in argv])
    assert result.exit_code == 0, result.output
    return result.output


def test_compare_writes_metrics_pictures_and_the_engines_trajectory(compared):
    folder, printed = compared
    out = folder / "out"
    for name in ("metrics.json", "final.png", "animation.gif"):
        assert (out / name).stat().st_size > 1000, name
    assert load_trajectory(out / "predicted").n_frames == FRAMES
    assert f"wrote {out / 'metrics.json'}" in printed and "deposit IoU" in printed


def test_compare_metrics_are_present_and_finite(compared):
    m = json.loads((compared[0] / "out" / "metrics.json").read_text())
    for side in ("left", "right", "farthest"):
        assert set(m[f"runout_{side}_m"]) == {"truth", "predicted", "error_m", "ape_percent"}
        assert all(math.isfinite(v) for v in m[f"runout_{side}_m"].values())
    assert 0.0 <= m["deposit_iou"] <= 1.0
    assert math.isfinite(m["position_mse_mean_m2"]) and math.isfinite(m["position_mse_final_m2"])
    wall = m["wall_s"]
    assert m["engine"] == "gns"
    assert wall["mpm"] > 0 and wall["engine"] > 0 and wall["mpm_over_engine"] == pytest.approx(wall["mpm"] / wall["engine"])
    assert m["frames"] == FRAMES and m["centre_m"] == pytest.approx(60.0)


def test_compare_fills_the_scene_at_the_models_spacing_for_both_engines(compared):
    folder, printed = compared
    m = json.loads((folder / "out" / "metrics.json").read_text())
    assert SPACING > 2.0, "the test needs a model trained at cells coarser than the scene's 4 m"
    assert m["cell_size_m"] == 2 * SPACING and m["point_spacing_m"] == SPACING
    assert "filling" in printed and (f"at the model's {SPACING:g} m spacing ({2 * SPACING:g} m cells) instead of the "
                                     "scene's 4 m cells") in printed
    assert point_spacing(load_trajectory(folder / "out" / "predicted")) == pytest.approx(SPACING)
    assert point_spacing(load_trajectory(m["mpm_trajectory"])) == pytest.approx(SPACING)


def test_a_second_compare_reads_the_mpm_from_the_cache(compared):
    folder, _ = compared
    argv = ["compare", folder / "mound.toml", "--model", MODEL, "--out", folder / "again", "--frames", FRAMES,
            "--cache", folder / "cache", "--no-progress"]
    assert "(cached run)" in _stdout(argv)
    assert json.loads((folder / "again" / "metrics.json").read_text())["wall_s"]["mpm_cached"] is True


def strip(x) -> Trajectory:
    """Soil points along y = 1 m at the x positions [T, N] (m), in a 100 x 10 m domain."""
    x = np.asarray(x, dtype=np.float32)
    xy = np.stack([x, np.ones_like(x)], axis=-1)
    n = x.shape[1]
    return Trajectory(xy, np.full(n, 6), np.zeros(n, dtype=np.int64), [Material("soil")], 0.0375, np.array([[0, 100], [0, 10]]))


def test_a_deposit_overlaps_itself_completely():
    traj = strip([[40.0, 50.0, 60.0], [30.0, 50.0, 75.0]])
    assert deposit_iou(traj, traj, 10.0) == 1.0
    m = comparison_metrics(traj, traj, 10.0)
    assert m["deposit_iou"] == 1.0 and m["position_mse_final_m2"] == 0.0
    assert m["runout_left_m"] == {"truth": 20.0, "predicted": 20.0, "error_m": 0.0, "ape_percent": 0.0}


def test_deposit_overlap_counts_cells_of_the_grid():
    truth = strip([[5.0, 15.0, 25.0]])  # cells 0, 1, 2 of 10 m
    predicted = strip([[15.0, 25.0, 35.0]])  # cells 1, 2, 3
    assert len(occupied_cells(truth, 10.0)) == 3
    assert deposit_iou(predicted, truth, 10.0) == pytest.approx(2 / 4)
    assert deposit_iou(strip([[95.0, 96.0, 97.0]]), truth, 10.0) == 0.0


@pytest.mark.parametrize("frames, words", [
    ("1", "--frames = 1 must be at least 2: frame 0 and the first frame the model predicts, 1 frame on."),
    ("2000000", "--frames = 2000000 is outside the allowed range [1, 1e+06]."),
])
def test_a_bad_frame_count_is_one_sentence_and_exit_2(tmp_path, capsys, frames, words):
    save_scene(scene_from_dict(MOUND, "mound"), tmp_path / "mound.toml")
    code, err = run(["compare", tmp_path / "mound.toml", "--model", MODEL, "--out", tmp_path / "out", "--frames", frames], capsys)
    assert code == 2 and one_sentence(err)
    assert words in err
    assert not (tmp_path / "out").exists()
