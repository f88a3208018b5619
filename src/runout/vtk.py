"""ParaView files of a trajectory: one VTK XML UnstructuredGrid (.vtu) per frame and a .pvd
collection that puts them on a time axis.

    write_vtk(trajectory, "out/run/vtk")   # frame_00000.vtu ... and trajectory.pvd

Each point is a VTK_VERTEX cell at (x, y, 0) m with the point data material_id,
particle_type (3 kinematic, 6 soil), phi (degrees), c (kPa), displacement from frame 0 (m)
and velocity (m/s, the backward difference (x_t - x_{t-1}) / frame_dt; zero at frame 0).
meshio writes the .vtu files, binary (float32, int32) and zlib-compressed; the .pvd is a few
lines of XML that meshio does not write, so it is written here.
"""

from __future__ import annotations

from pathlib import Path
from xml.sax.saxutils import quoteattr

import meshio
import numpy as np

from runout.trajectory import Trajectory

PVD_NAME = "trajectory.pvd"


def frame_fields(traj: Trajectory, frame: int) -> dict[str, np.ndarray]:
    """The point data of one frame, by VTK array name."""
    x = traj.positions[frame].astype(np.float64)
    previous = traj.positions[max(frame - 1, 0)].astype(np.float64)
    phi = np.array([m.friction_angle for m in traj.materials])
    c = np.array([m.cohesion for m in traj.materials])
    return {
        "material_id": traj.material_id.astype(np.int32),
        "particle_type": traj.particle_type.astype(np.int32),
        "phi": phi[traj.material_id].astype(np.float32),
        "c": c[traj.material_id].astype(np.float32),
        "displacement": _xyz(x - traj.positions[0]),
        "velocity": _xyz((x - previous) / traj.frame_dt),
    }


def _xyz(xy: np.ndarray) -> np.ndarray:
    return np.column_stack([xy, np.zeros(len(xy))]).astype(np.float32)


def frame_mesh(traj: Trajectory, frame: int) -> meshio.Mesh:
    """One frame as a meshio mesh: a vertex cell per point, with its point data."""
    vertices = np.arange(traj.n_points, dtype=np.int32)[:, None]
    return meshio.Mesh(_xyz(traj.positions[frame]), [("vertex", vertices)],
                       point_data=frame_fields(traj, frame))


def write_vtk(traj: Trajectory, folder: str | Path, every: int = 1) -> Path:
    """Write every `every`-th frame (and the last) as .vtu and the .pvd series; returns the .pvd.
    Frame files of an earlier export in the folder that this one does not rewrite are removed,
    so the folder never mixes two runs; other files in it are left alone."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    frames = sorted(set(range(0, traj.n_frames, every)) | {traj.n_frames - 1})
    entries = []
    for f in frames:
        name = f"frame_{f:05d}.vtu"
        meshio.vtu.write(folder / name, frame_mesh(traj, f), binary=True, compression="zlib")
        entries.append(f'<DataSet timestep="{f * traj.frame_dt:.6g}" group="" part="0" file={quoteattr(name)}/>')
    pvd = (
        '<?xml version="1.0"?>\n<VTKFile type="Collection" version="0.1" byte_order="LittleEndian">\n'
        "<Collection>\n" + "\n".join(entries) + "\n</Collection>\n</VTKFile>\n"
    )
    path = folder / PVD_NAME
    path.write_text(pvd)
    written = {f"frame_{f:05d}.vtu" for f in frames}
    for stale in folder.glob("frame_[0-9][0-9][0-9][0-9][0-9].vtu"):  # a previous, longer or denser export's frames
        if stale.name not in written:
            stale.unlink()
    return path
