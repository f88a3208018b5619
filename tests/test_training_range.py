"""A model records what it was trained on (phi, c, domain, point spacing, materials per
scene), and rollout and invert warn, naming the value and the range, when used outside it."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import torch

from runout.gns.checkpoint import load_simulator, read_checkpoint
from runout.gns.engine import GnsEngine
from runout.learned.scenes import scene_at_rest
from runout.learned.training_range import bound_warnings, measure, range_warnings
from runout.mpm.cache import MpmCache, scene_key
from runout.scene import save_scene, scene_from_dict
from test_cli_exits import TINY, run
from test_gns_synthetic import write_dataset

REPO = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    """A 2-step model trained on falling blocks with tan(phi) in [0.2, 0.8] and c / 100 kPa in [0.1, 0.6]."""
    torch.set_num_threads(1)
    folder = tmp_path_factory.mktemp("ranges")
    data = write_dataset(folder / "data", frames=12, n_train=3, width=2)
    from runout.cli import main

    main(["train", "--data", str(data), "--out", str(folder / "run"), "--steps", "2", *TINY])
    return data, folder / "run" / "checkpoint.pt"


def scene(phi=30.0, c=20.0, width=60.0, cell=4.0):
    return scene_from_dict({
        "domain": {"width": width, "height": 30.0, "cell_size": cell},
        "materials": {"sand": {"friction_angle": phi, "cohesion": c}},
        "regions": [{"material": "sand", "polygon": [[20, 0], [36, 0], [36, 10], [20, 10]]}],
    })


def test_training_records_the_ranges_of_its_data(trained):
    data, ckpt = trained
    from runout.simfiles import read_simulations

    ranges = read_checkpoint(ckpt)["data_ranges"]
    tan_phi = np.concatenate([m[t != 3, 0] for _, t, m in read_simulations(data / "train.npz")])
    c = np.concatenate([m[t != 3, 1] for _, t, m in read_simulations(data / "train.npz")]) * 100
    assert ranges["friction_angle_deg"] == pytest.approx(np.degrees(np.arctan([tan_phi.min(), tan_phi.max()])), rel=1e-5)
    assert ranges["cohesion_kpa"] == pytest.approx([c.min(), c.max()], rel=1e-5)
    assert ranges["domain_m"] == [60.0, 30.0] and ranges["point_spacing_m"] == pytest.approx(4.6 / 2.3)
    assert ranges["materials_per_scene"] == [1, 1]


def test_the_recorded_spacing_is_the_datasets_not_the_models_radius():
    soil = [np.array([[0.5, 0.2]])], [np.array([6])]
    meta = {"bounds": [[0, 60], [0, 30]], "default_connectivity_radius": 4.6}
    assert measure(*soil, meta, radius=12.0, source="test")["point_spacing_m"] == pytest.approx(2.0)
    assert measure(*soil, {**meta, "cell_size": 8.0}, radius=12.0, source="test")["point_spacing_m"] == 4.0


def test_a_scene_inside_the_ranges_gets_no_warning(trained):
    simulator = GnsEngine(load_simulator(trained[1]))
    lo, hi = simulator.data_ranges["friction_angle_deg"]
    c_lo, c_hi = simulator.data_ranges["cohesion_kpa"]
    assert range_warnings(simulator, scene_at_rest(scene(phi=(lo + hi) / 2, c=(c_lo + c_hi) / 2))) == []


def test_each_value_outside_is_named_with_its_range(trained):
    simulator = GnsEngine(load_simulator(trained[1]))
    lo, hi = simulator.data_ranges["friction_angle_deg"]
    warnings = range_warnings(simulator, scene_at_rest(scene(phi=55.0, c=90.0, width=120.0, cell=8.0)))
    assert any(f"phi = 55 degrees of material sand is outside the model's training range {lo:.4g}-{hi:.4g} degrees" in w for w in warnings)
    assert any("c = 90 kPa" in w and "kPa" in w for w in warnings)
    assert any("120 x 30 m, is larger than the model's training domain 60 x 30 m" in w for w in warnings)
    assert any("point spacing of the scene, 4 m, differs from the model's training spacing 2 m" in w for w in warnings)
    assert all("\n" not in w and w.endswith(".") for w in warnings)


def test_bounds_reaching_outside_are_named(trained):
    simulator = GnsEngine(load_simulator(trained[1]))
    hi = simulator.data_ranges["friction_angle_deg"][1]
    assert bound_warnings(simulator, "phi[sand]", "degrees", 15.0, 20.0) == []
    (warning,) = bound_warnings(simulator, "phi[sand]", "degrees", 15.0, 59.0)
    assert "[15, 59] degrees of phi[sand]" in warning and f"{hi:.4g} degrees" in warning


def test_rollout_prints_the_warning(trained, tmp_path, capsys):
    save_scene(scene(phi=58.0, c=20.0, cell=4.6), tmp_path / "steep.toml")
    code, err = run(["rollout", "--model", trained[1], tmp_path / "steep.toml", "--out", tmp_path / "o",
                     "--frames", "8", "--no-animation"], capsys)
    assert code == 0 and "warning: phi = 58 degrees of material sand is outside the model's training range" in err


def test_a_model_without_ranges_says_so():
    simulator = GnsEngine(load_simulator(REPO / "models" / "slope.pt"))
    simulator.data_ranges = None
    assert range_warnings(simulator, scene_at_rest(scene())) == [
        "the model records no training ranges, so its use outside them cannot be checked."
    ]


def test_the_mpm_cache_keys_on_the_solver_version(tmp_path):
    s = scene()
    assert scene_key(s, "2") != scene_key(s, "3")
    assert scene_key(s) == scene_key(replace(s))
    assert MpmCache(tmp_path).path(s).name == scene_key(s)
