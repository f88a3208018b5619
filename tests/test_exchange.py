"""Our files load in the public GNS code (geoelements/gns): its loader reads the material
entry with np.full(n_particles, entry, dtype=float), so one feature must be stored as (N,);
two features are (N, 2), the layout of its multi-material branch. Our reader takes every
layout: (N,), (N, 1), (N, 2) and scalars."""

from __future__ import annotations

import numpy as np
import pytest

from runout.scene import Material
from runout.simfiles import read_simulations, write_simulations
from runout.trajectory import Trajectory, save_trajectory


def reference_load(path):
    """What the public loader does: np.load with pickles, then (positions, type, material) per
    simulation from either layout, the material broadcast with np.full to one value per particle."""
    with np.load(path, allow_pickle=True) as data:
        items = list(data["gns_data"]) if "gns_data" in data.files else [item for _, item in data.items()]
    out = []
    for positions, ptype, material in items:
        n = positions.shape[1]
        out.append((np.transpose(positions, (1, 0, 2)), np.full(n, ptype, dtype=int), np.full(n, material, dtype=float)))
    return out


def _sims(width):
    rng = np.random.default_rng(5)
    sims = []
    for n in (4, 7):
        positions = rng.normal(size=(8, n, 2)).astype(np.float32)
        ptype = np.full(n, 6, dtype=np.int64)
        material = rng.uniform(0.1, 0.9, (n, width)).astype(np.float32)
        sims.append((positions, ptype, material))
    return sims


@pytest.mark.parametrize("layout", ["dict", "gns_data"])
def test_friction_only_datasets_load_in_the_reference_code(tmp_path, layout):
    sims = _sims(1)
    write_simulations(tmp_path / "train.npz", sims, layout=layout)
    for (positions, _, material), (ref_positions, ref_type, ref_material) in zip(sims, reference_load(tmp_path / "train.npz"), strict=True):
        np.testing.assert_array_equal(ref_positions, np.transpose(positions, (1, 0, 2)))
        np.testing.assert_allclose(ref_material, material[:, 0])
        assert ref_type.tolist() == [6] * len(ref_type)


def test_a_friction_only_trajectory_loads_in_the_reference_code(tmp_path):
    traj = Trajectory(
        positions=np.zeros((8, 3, 2), dtype=np.float32), particle_type=np.array([3, 6, 6]),
        material_id=np.array([0, 0, 1]), materials=[Material("a", friction_angle=20.0), Material("b", friction_angle=35.0)],
        frame_dt=0.0375, bounds=np.array([[0.0, 10.0], [0.0, 10.0]]),
    )
    save_trajectory(traj, tmp_path, feature_width=1)
    (_, _, material), = reference_load(tmp_path / "trajectory.npz")
    np.testing.assert_allclose(material, np.tan(np.radians([20.0, 20.0, 35.0])), rtol=1e-6)


def test_two_features_are_written_as_n_by_2(tmp_path):
    write_simulations(tmp_path / "train.npz", _sims(2))
    with np.load(tmp_path / "train.npz", allow_pickle=True) as data:
        assert data["simulation_1"][2].shape == (7, 2)


@pytest.mark.parametrize("material, expected", [
    (np.full(4, 0.5), [[0.5]] * 4),
    (np.full((4, 1), 0.5), [[0.5]] * 4),
    (np.tile([0.5, 0.2], (4, 1)), [[0.5, 0.2]] * 4),
    (0.5, [[0.5]] * 4),
])
def test_our_reader_takes_every_material_layout(tmp_path, material, expected):
    item = np.empty(3, dtype=object)
    item[0], item[1], item[2] = np.zeros((8, 4, 2)), 6, material
    np.savez(tmp_path / "x.npz", simulation_0=item)
    (_, ptype, read), = read_simulations(tmp_path / "x.npz")
    np.testing.assert_allclose(read, np.array(expected, dtype=np.float32))
    assert ptype.tolist() == [6] * 4


def test_three_features_are_refused(tmp_path):
    from runout.errors import InputError

    item = np.empty(3, dtype=object)
    item[0], item[1], item[2] = np.zeros((8, 4, 2)), 6, np.zeros((4, 3))
    np.savez(tmp_path / "x.npz", simulation_0=item)
    with pytest.raises(InputError, match=r"material has shape \(4, 3\); expected a scalar, \(4,\), \(4, 1\) or \(4, 2\)"):
        read_simulations(tmp_path / "x.npz")
