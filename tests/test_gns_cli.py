import json

import numpy as np
import pytest
import torch
from typer.testing import CliRunner

from runout.cli import app
from runout.errors import InputError
from runout.scene import save_scene, scene_from_dict
from runout.trajectory import load_trajectory, save_trajectory, trajectory_from_features
from test_gns_synthetic import BOUNDS, FRAME_DT, falling_block, write_dataset

torch.set_num_threads(1)  # tiny graphs: extra threads only add OpenMP synchronisation cost

TINY = ["--latent", "16", "--hidden", "16", "--message-passing-steps", "2", "--valid-every", "0", "--log-every", "1"]


@pytest.fixture(scope="module")
def model(tmp_path_factory):
    """A checkpoint trained for 3 steps through `runout train`."""
    folder = tmp_path_factory.mktemp("gns_cli")
    data = write_dataset(folder / "data")
    result = CliRunner().invoke(app, ["train", "--data", str(data), "--out", str(folder / "run"), "--steps", "3", *TINY])
    assert result.exit_code == 0, result.output
    return folder / "run" / "checkpoint.pt"


def test_rollout_of_a_scene_at_rest_writes_a_trajectory_and_pictures(tmp_path, model):
    scene = scene_from_dict({
        "domain": {"width": 60, "height": 30},
        "materials": {"sand": {"friction_angle": 30}},
        "regions": [{"material": "sand", "polygon": [[20, 0], [36, 0], [36, 10], [20, 10]]}],
    })
    save_scene(scene, tmp_path / "scene.toml")
    out = tmp_path / "rollout"
    result = CliRunner().invoke(app, ["rollout", "--model", str(model), str(tmp_path / "scene.toml"), "--out", str(out), "--frames", "12", "--stop-speed", "0", "--no-animation"])
    assert result.exit_code == 0, result.output
    traj = load_trajectory(out)
    assert traj.positions.shape[0] == 12 and np.isfinite(traj.positions).all()
    assert (out / "snapshots.png").is_file()
    assert json.loads((out / "metrics.json").read_text())["frames"] == 12


def test_rollout_against_a_ground_truth_reports_position_error_and_runout(tmp_path, model):
    truth = trajectory_from_features(*falling_block(14, 0.5), FRAME_DT, BOUNDS)
    save_trajectory(truth, tmp_path / "mpm", feature_width=1)
    out = tmp_path / "rollout"
    result = CliRunner().invoke(app, ["rollout", "--model", str(model), str(tmp_path / "mpm"), "--out", str(out)])
    assert result.exit_code == 0, result.output
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["frames_compared"] == 14
    assert {"position_mse_final_m2", "normalised_runout_gns", "runout_error"} <= metrics.keys()
    assert (out / "position_mse.png").is_file() and (out / "animation.gif").is_file()


def test_a_missing_model_is_an_input_error(tmp_path):
    result = CliRunner().invoke(app, ["rollout", "--model", str(tmp_path / "none.pt"), str(tmp_path), "--out", str(tmp_path / "o")])
    assert isinstance(result.exception, InputError)
    assert "none.pt: no such checkpoint file." in str(result.exception)
