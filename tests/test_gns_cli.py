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
    assert {"position_mse_final_m2", "normalised_runout_predicted", "runout_error"} <= metrics.keys()
    assert metrics["engine"] == "GNS"
    assert (out / "position_mse.png").is_file() and (out / "animation.gif").is_file()


def test_a_missing_model_is_an_input_error(tmp_path):
    result = CliRunner().invoke(app, ["rollout", "--model", str(tmp_path / "none.pt"), str(tmp_path / "traj"), "--out", str(tmp_path / "o")])
    assert isinstance(result.exception, InputError)
    assert "none.pt: no such checkpoint file." in str(result.exception)


# ----------------------------------------------------------------------------- the model's point spacing


def spaced_model(path, radius=12.0, spacing=4.0):
    """An untrained checkpoint whose data_ranges record `spacing` (m) and whose radius is another (m)."""
    from runout.gns.checkpoint import save_checkpoint
    from runout.gns.schema import FeatureSchema, NetworkConfig
    from runout.gns.simulator import GraphNetworkSimulator, Normalisation

    torch.manual_seed(0)
    stats = Normalisation((0.0, 0.0), (0.02, 0.02), (0.0, 0.0), (2e-3, 2e-3), 2.5e-3)
    schema = FeatureSchema(material_features=("tan_phi", "c_over_100kPa"))
    simulator = GraphNetworkSimulator(schema, stats, radius, NetworkConfig(8, 8, 1, 1))
    simulator.data_ranges = None if spacing is None else {"point_spacing_m": spacing, "source": "a test"}
    return save_checkpoint(path, simulator)


def test_a_scene_is_filled_at_the_spacing_the_checkpoint_records_not_at_its_radius(tmp_path):
    from runout.gns.checkpoint import load_simulator
    from runout.learned.scenes import at_model_spacing
    from runout.scene import EXAMPLES, load_scene

    simulator = load_simulator(spaced_model(tmp_path / "m.pt"))
    assert simulator.point_spacing == 4.0 and simulator.radius == 12.0
    lines = []
    scene = at_model_spacing(load_scene(EXAMPLES / "column_a1.toml"), simulator, "column_a1.toml", lines.append)
    assert scene.domain.cell_size == 8.0
    assert lines == ["filling column_a1.toml at the model's 4 m spacing (8 m cells) instead of the scene's 4 m cells"]
    old = load_simulator(spaced_model(tmp_path / "old.pt", radius=11.5, spacing=None))  # no data_ranges: radius / 2.3
    assert old.point_spacing == pytest.approx(5.0) and at_model_spacing(scene, old).domain.cell_size == 10.0


def test_rollout_of_a_scene_file_fills_it_at_the_models_spacing(tmp_path):
    from runout.learned.training_range import point_spacing
    from runout.scene import EXAMPLES, fill_points, load_scene

    model = spaced_model(tmp_path / "m.pt")
    out = tmp_path / "rollout"
    result = CliRunner().invoke(app, ["rollout", "--model", str(model), str(EXAMPLES / "column_a1.toml"), "--out", str(out),
                                      "--frames", "7", "--no-animation"])
    assert result.exit_code == 0, result.output
    assert "at the model's 4 m spacing (8 m cells) instead of the scene's 4 m cells" in result.output
    traj = load_trajectory(out)
    assert point_spacing(traj) == pytest.approx(4.0)
    assert traj.n_points == len(fill_points(load_scene(EXAMPLES / "column_a1.toml").with_point_spacing(4.0)))


def test_a_recorded_spacing_outside_its_range_is_one_sentence(tmp_path):
    from runout.gns.checkpoint import load_simulator

    path = spaced_model(tmp_path / "m.pt", spacing=-1.0)
    with pytest.raises(InputError, match=r"data_ranges.point_spacing_m = -1 is outside the allowed range \(0, 1000\] m."):
        load_simulator(path)
