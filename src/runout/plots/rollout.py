"""Pictures of a learned engine's rollouts: snapshots and the position error over time."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from matplotlib.figure import Figure  # no pyplot: no global figure state, no GUI backend

from runout.trajectory import Trajectory

KINEMATIC_GREY = "0.6"


def draw_points(ax, traj: Trajectory, frame: int, title: str) -> None:
    """Points of one frame, soil coloured by material index, kinematic points grey."""
    ax.clear()
    x = traj.positions[frame]
    colour = np.where(traj.soil, traj.material_id, -1)
    ax.scatter(x[~traj.soil, 0], x[~traj.soil, 1], s=1, c=KINEMATIC_GREY, linewidths=0)
    ax.scatter(x[traj.soil, 0], x[traj.soil, 1], s=1, c=colour[traj.soil], cmap="tab10", vmin=0, vmax=9, linewidths=0)
    (x0, x1), (y0, y1) = traj.bounds
    ax.set_xlim(x0, x1)
    ax.set_ylim(y0, y1)
    ax.set_aspect("equal")
    ax.set_title(title, fontsize=9)
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")


def panel_size(traj: Trajectory, rows: int, cols: int) -> tuple[float, float]:
    (x0, x1), (y0, y1) = traj.bounds
    width = 5.0 * cols
    return width, min(2.2 + rows * width / cols * (y1 - y0) / (x1 - x0), 12.0)


def save_snapshots(traj: Trajectory, path: str | Path, n: int = 4) -> Path:
    """`n` frames evenly spread from the first to the last, side by side."""
    frames = np.linspace(0, traj.n_frames - 1, n).round().astype(int)
    fig = Figure(figsize=panel_size(traj, 1, n))
    axes = fig.subplots(1, n, squeeze=False)
    for ax, f in zip(axes[0], frames):
        draw_points(ax, traj, int(f), f"{traj.name}: t = {f * traj.frame_dt:.2f} s")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    return Path(path)


def save_error_plot(mse: np.ndarray, frame_dt: float, path: str | Path, label: str = "GNS") -> Path:
    """Position MSE (m^2) of a learned engine (its name: label) against the MPM over time."""
    fig = Figure(figsize=(6, 3.5))
    ax = fig.add_subplot()
    ax.plot(np.arange(len(mse)) * frame_dt, mse)
    ax.set_xlabel("time (s)")
    ax.set_ylabel("position MSE (m$^2$)")
    ax.set_title(f"{label} against MPM")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    return Path(path)
