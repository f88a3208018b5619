"""ParaView export: the .vtu frames and .pvd series, read back with xml.etree, hold exactly
the positions, material ids, phi, c, displacements and velocities of the trajectory."""

from __future__ import annotations

import xml.etree.ElementTree as ET

import numpy as np
import pytest

import runout.mpm
from runout.scene import Material
from runout.trajectory import Trajectory
from runout.vtk import PVD_NAME, VTK_VERTEX, write_vtk
from test_cli_exits import DAM, MODEL, run, static_run


def small_trajectory(frames=5, points=6):
    rng = np.random.default_rng(0)
    positions = (10 + rng.uniform(0, 20, (1, points, 2)) + np.cumsum(rng.normal(0, 0.3, (frames, points, 2)), 0))
    materials = [Material("sand", friction_angle=31.0, cohesion=0.0), Material("clay", friction_angle=12.5, cohesion=35.0)]
    return Trajectory(
        positions=positions.astype(np.float32), particle_type=np.array([3, 6, 6, 6, 6, 6]),
        material_id=np.array([0, 0, 1, 1, 0, 1]), materials=materials, frame_dt=0.0375,
        bounds=np.array([[0.0, 60.0], [0.0, 40.0]]), name="small",
    )


def read_vtu(path):
    """{array name: values [N, components]} and the points [N, 3] of a .vtu file."""
    piece = ET.parse(path).getroot().find("UnstructuredGrid/Piece")
    n = int(piece.get("NumberOfPoints"))

    def values(array):
        data = np.array(array.text.split(), dtype=float)
        return data.reshape(n, int(array.get("NumberOfComponents")))

    arrays = {a.get("Name"): values(a) for a in piece.find("PointData")}
    cells = {a.get("Name"): values(a)[:, 0] for a in piece.find("Cells")}
    return values(piece.find("Points/DataArray")), arrays, cells, int(piece.get("NumberOfCells"))


def test_every_frame_reads_back_with_its_fields(tmp_path):
    traj = small_trajectory()
    pvd = write_vtk(traj, tmp_path / "vtk")
    datasets = ET.parse(pvd).getroot().findall("Collection/DataSet")
    assert len(datasets) == traj.n_frames
    for f, entry in enumerate(datasets):
        assert float(entry.get("timestep")) == pytest.approx(f * traj.frame_dt)
        points, arrays, cells, n_cells = read_vtu(tmp_path / "vtk" / entry.get("file"))
        np.testing.assert_allclose(points[:, :2], traj.positions[f], rtol=1e-6)
        assert (points[:, 2] == 0).all() and n_cells == traj.n_points
        assert (cells["types"] == VTK_VERTEX).all() and (cells["connectivity"] == np.arange(6)).all()
        assert arrays["material_id"][:, 0].tolist() == traj.material_id.tolist()
        assert arrays["particle_type"][:, 0].tolist() == traj.particle_type.tolist()
        assert arrays["phi"][:, 0].tolist() == [31.0, 31.0, 12.5, 12.5, 31.0, 12.5]
        assert arrays["c"][:, 0].tolist() == [0.0, 0.0, 35.0, 35.0, 0.0, 35.0]
        np.testing.assert_allclose(arrays["displacement"][:, :2], traj.positions[f] - traj.positions[0], atol=1e-5)
        velocity = (traj.positions[f] - traj.positions[max(f - 1, 0)]) / traj.frame_dt
        np.testing.assert_allclose(arrays["velocity"][:, :2], velocity, rtol=1e-5, atol=1e-4)
        assert (arrays["velocity"][:, 2] == 0).all()


def test_a_stride_keeps_the_last_frame(tmp_path):
    pvd = write_vtk(small_trajectory(frames=7), tmp_path, every=3)
    files = [d.get("file") for d in ET.parse(pvd).getroot().findall("Collection/DataSet")]
    assert files == ["frame_00000.vtu", "frame_00003.vtu", "frame_00006.vtu"]


def test_runout_mpm_and_rollout_write_vtk_on_request(tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(runout.mpm, "simulate", lambda scenes, **k: static_run(scenes, frames=7))
    assert run(["mpm", DAM, "--out", tmp_path / "mpm", "--vtk", "--no-animate"], capsys)[0] == 0
    assert (tmp_path / "mpm" / "vtk" / PVD_NAME).is_file() and len(list((tmp_path / "mpm" / "vtk").glob("*.vtu"))) == 7
    argv = ["rollout", "--model", MODEL, DAM, "--out", tmp_path / "gns", "--frames", "8", "--no-animation", "--vtk"]
    assert run(argv, capsys)[0] == 0
    points, arrays, _, _ = read_vtu(tmp_path / "gns" / "vtk" / "frame_00007.vtu")
    assert {"material_id", "phi", "c", "displacement", "velocity"} <= arrays.keys() and len(points) > 100
