"""ParaView files of a trajectory: one VTK XML UnstructuredGrid (.vtu, ASCII) per frame and
a .pvd collection that puts them on a time axis.

    write_vtk(trajectory, "out/run/vtk")   # frame_00000.vtu ... and trajectory.pvd

Each point is a VTK_VERTEX cell at (x, y, 0) m with the point data material_id,
particle_type (3 kinematic, 6 soil), phi (degrees), c (kPa), displacement from frame 0 (m)
and velocity (m/s, the backward difference (x_t - x_{t-1}) / frame_dt; zero at frame 0).
The format is written by this module alone (plain XML text), so no VTK library is needed;
ASCII keeps the files readable and exact to 7 significant digits (float32).
"""

from __future__ import annotations

from pathlib import Path
from xml.sax.saxutils import quoteattr

import numpy as np

from runout.trajectory import Trajectory

VTK_VERTEX = 1
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


def _data_array(name: str | None, values: np.ndarray) -> str:
    kind = {"i": "Int32", "u": "Int32", "f": "Float32"}[values.dtype.kind]
    parts = values.reshape(len(values), -1)
    fmt = "%d" if kind == "Int32" else "%.7g"
    text = " ".join(fmt % v for v in parts.ravel().tolist())
    label = "" if name is None else f" Name={quoteattr(name)}"
    return (f'<DataArray type="{kind}"{label} NumberOfComponents="{parts.shape[1]}" format="ascii">'
            f"{text}</DataArray>")


def vtu_text(traj: Trajectory, frame: int) -> str:
    """The .vtu document of one frame."""
    n = traj.n_points
    points = _xyz(traj.positions[frame])
    point_data = "\n".join(_data_array(name, v) for name, v in frame_fields(traj, frame).items())
    cells = "\n".join([
        _data_array("connectivity", np.arange(n, dtype=np.int32)),
        _data_array("offsets", np.arange(1, n + 1, dtype=np.int32)),
        _data_array("types", np.full(n, VTK_VERTEX, dtype=np.int32)),
    ])
    return (
        '<?xml version="1.0"?>\n'
        '<VTKFile type="UnstructuredGrid" version="0.1" byte_order="LittleEndian">\n'
        f'<UnstructuredGrid>\n<Piece NumberOfPoints="{n}" NumberOfCells="{n}">\n'
        f"<Points>\n{_data_array(None, points)}\n</Points>\n"
        f"<Cells>\n{cells}\n</Cells>\n"
        f'<PointData Scalars="material_id" Vectors="velocity">\n{point_data}\n</PointData>\n'
        "</Piece>\n</UnstructuredGrid>\n</VTKFile>\n"
    )


def write_vtk(traj: Trajectory, folder: str | Path, every: int = 1) -> Path:
    """Write every `every`-th frame (and the last) as .vtu and the .pvd series; returns the .pvd."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    frames = sorted(set(range(0, traj.n_frames, every)) | {traj.n_frames - 1})
    entries = []
    for f in frames:
        name = f"frame_{f:05d}.vtu"
        (folder / name).write_text(vtu_text(traj, f))
        entries.append(f'<DataSet timestep="{f * traj.frame_dt:.6g}" group="" part="0" file={quoteattr(name)}/>')
    pvd = (
        '<?xml version="1.0"?>\n<VTKFile type="Collection" version="0.1" byte_order="LittleEndian">\n'
        "<Collection>\n" + "\n".join(entries) + "\n</Collection>\n</VTKFile>\n"
    )
    path = folder / PVD_NAME
    path.write_text(pvd)
    return path
