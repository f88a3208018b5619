"""ParaView export: the .vtu frames (binary, zlib-compressed, written by meshio) read back with
meshio hold the positions, material ids, phi, c, displacements and velocities of the
trajectory to float32, the .pvd series lists every frame with its time in seconds, and the
files take a fraction of the ~100 bytes per point and frame of the former ASCII writer."""

from __future__ import annotations

import xml.etree.ElementTree as ET

import meshio
import numpy as np
import pytest

import runout.mpm
from runout.scene import Material
from runout.trajectory import Trajectory
from runout.vtk import PVD_NAME, write_vtk
from test_cli_exits import DAM, MODEL, run, static_run

MATERIALS = [Material("sand", friction_angle=31.0, cohesion=0.0), Material("clay", friction_angle=12.5, cohesion=35.0)]


def small_trajectory(frames=5, points=6):
    rng = np.random.default_rng(0)
    positions = (10 + rng.uniform(0, 20, (1, points, 2)) + np.cumsum(rng.normal(0, 0.3, (frames, points, 2)), 0))
    return Trajectory(
        positions=positions.astype(np.float32), particle_type=np.array([3, 6, 6, 6, 6, 6]),
        material_id=np.array([0, 0, 1, 1, 0, 1]), materials=MATERIALS, frame_dt=0.0375,
        bounds=np.array([[0.0, 60.0], [0.0, 40.0]]), name="small",
    )


def slumping_block(frames=4):
    """3,000 points on a 0.5 m grid that slump: upper points travel further, with a little noise."""
    gx, gy = np.meshgrid(np.arange(100) * 0.5 + 5.25, np.arange(30) * 0.5 + 0.25)
    x0 = np.column_stack([gx.ravel(), gy.ravel()])
    s = 1 - np.exp(-np.arange(frames)[:, None, None] * 0.0375 / 4.0)
    flow = np.stack([x0[:, 1] * 0.8, -x0[:, 1] * 0.35], 1)
    noise = np.cumsum(np.random.default_rng(1).normal(0, 1e-3, (frames, len(x0), 2)), 0)
    return Trajectory(
        positions=(x0 + s * flow + noise).astype(np.float32), particle_type=np.where(gy.ravel() < 0.5, 3, 6),
        material_id=(x0[:, 1] > 8).astype(np.int64), materials=MATERIALS, frame_dt=0.0375,
        bounds=np.array([[0.0, 100.0], [0.0, 20.0]]), name="block",
    )


def pvd_entries(pvd):
    return ET.parse(pvd).getroot().findall("Collection/DataSet")


def test_every_frame_reads_back_with_its_fields(tmp_path):
    traj = small_trajectory()
    datasets = pvd_entries(write_vtk(traj, tmp_path / "vtk"))
    assert len(datasets) == traj.n_frames
    for f, entry in enumerate(datasets):
        assert float(entry.get("timestep")) == pytest.approx(f * traj.frame_dt)  # seconds
        mesh = meshio.read(tmp_path / "vtk" / entry.get("file"))
        np.testing.assert_array_equal(mesh.points[:, :2], traj.positions[f])
        assert (mesh.points[:, 2] == 0).all()
        assert [c.type for c in mesh.cells] == ["vertex"] and (mesh.cells[0].data[:, 0] == np.arange(6)).all()
        data = mesh.point_data
        assert data["material_id"].tolist() == traj.material_id.tolist()
        assert data["particle_type"].tolist() == traj.particle_type.tolist()
        assert data["phi"].tolist() == [31.0, 31.0, 12.5, 12.5, 31.0, 12.5]
        assert data["c"].tolist() == [0.0, 0.0, 35.0, 35.0, 0.0, 35.0]
        displacement = traj.positions[f].astype(np.float64) - traj.positions[0]
        np.testing.assert_array_equal(data["displacement"][:, :2], displacement.astype(np.float32))
        velocity = (traj.positions[f].astype(np.float64) - traj.positions[max(f - 1, 0)]) / traj.frame_dt
        np.testing.assert_array_equal(data["velocity"][:, :2], velocity.astype(np.float32))
        assert (data["displacement"][:, 2] == 0).all() and (data["velocity"][:, 2] == 0).all()


def test_frames_are_binary_and_compressed(tmp_path):
    write_vtk(small_trajectory(frames=1), tmp_path)
    root = ET.parse(tmp_path / "frame_00000.vtu").getroot()
    assert root.get("compressor") == "vtkZLibDataCompressor"
    assert {a.get("format") for a in root.iter("DataArray")} == {"binary"}


def test_files_take_under_a_third_of_the_former_ascii_size(tmp_path):
    traj = slumping_block()
    write_vtk(traj, tmp_path)
    size = sum(p.stat().st_size for p in tmp_path.glob("*.vtu"))
    assert size / (traj.n_points * traj.n_frames) < 33  # bytes per point and frame; ASCII took ~100


def test_a_stride_keeps_the_last_frame(tmp_path):
    pvd = write_vtk(small_trajectory(frames=7), tmp_path, every=3)
    entries = pvd_entries(pvd)
    assert [d.get("file") for d in entries] == ["frame_00000.vtu", "frame_00003.vtu", "frame_00006.vtu"]
    assert [float(d.get("timestep")) for d in entries] == pytest.approx([0.0, 0.1125, 0.225])
    assert sorted(p.name for p in tmp_path.glob("*.vtu")) == [d.get("file") for d in entries]


def test_a_shorter_export_over_a_longer_one_leaves_no_frame_of_the_old_run(tmp_path):
    write_vtk(small_trajectory(frames=7), tmp_path)
    (tmp_path / "notes.txt").write_text("mine")
    pvd = write_vtk(small_trajectory(frames=3), tmp_path)
    assert sorted(p.name for p in tmp_path.glob("*.vtu")) == [d.get("file") for d in pvd_entries(pvd)] == [
        "frame_00000.vtu", "frame_00001.vtu", "frame_00002.vtu"]
    assert (tmp_path / "notes.txt").read_text() == "mine"


def test_runout_mpm_and_rollout_write_vtk_on_request(tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(runout.mpm, "simulate", lambda scenes, **k: static_run(scenes, frames=7))
    assert run(["mpm", DAM, "--out", tmp_path / "mpm", "--vtk", "--no-animate"], capsys)[0] == 0
    assert (tmp_path / "mpm" / "vtk" / PVD_NAME).is_file() and len(list((tmp_path / "mpm" / "vtk").glob("*.vtu"))) == 7
    argv = ["rollout", "--model", MODEL, DAM, "--out", tmp_path / "gns", "--frames", "8", "--no-animation", "--vtk"]
    assert run(argv, capsys)[0] == 0
    mesh = meshio.read(tmp_path / "gns" / "vtk" / "frame_00007.vtu")
    assert {"material_id", "phi", "c", "displacement", "velocity"} <= mesh.point_data.keys() and len(mesh.points) > 100
