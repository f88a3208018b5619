"""Pictures of GNS rollouts: snapshots, position error over time, and an animation of the
GNS beside the MPM (GIF with Pillow, or MP4 when ffmpeg is installed)."""

from __future__ import annotations

import shutil
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib import animation  # noqa: E402

from runout.trajectory import Trajectory  # noqa: E402

KINEMATIC_GREY = "0.6"


def _draw(ax, traj: Trajectory, frame: int, title: str) -> None:
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


def _size(traj: Trajectory, rows: int, cols: int) -> tuple[float, float]:
    (x0, x1), (y0, y1) = traj.bounds
    width = 5.0 * cols
    return width, min(2.2 + rows * width / cols * (y1 - y0) / (x1 - x0), 12.0)


def save_snapshots(traj: Trajectory, path: str | Path, n: int = 4) -> Path:
    """`n` frames evenly spread from the first to the last, side by side."""
    frames = np.linspace(0, traj.n_frames - 1, n).round().astype(int)
    fig, axes = plt.subplots(1, n, figsize=_size(traj, 1, n), squeeze=False)
    for ax, f in zip(axes[0], frames):
        _draw(ax, traj, int(f), f"{traj.name}: t = {f * traj.frame_dt:.2f} s")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return Path(path)


def save_error_plot(mse: np.ndarray, frame_dt: float, path: str | Path) -> Path:
    """Position MSE (m^2) of the GNS against the MPM over time."""
    fig, ax = plt.subplots(figsize=(6, 3.5))
    ax.plot(np.arange(len(mse)) * frame_dt, mse)
    ax.set_xlabel("time (s)")
    ax.set_ylabel("position MSE (m$^2$)")
    ax.set_title("GNS against MPM")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return Path(path)


def animation_name(stem: str = "animation") -> str:
    """The file save_animation writes: .mp4 when ffmpeg is installed, else .gif."""
    return stem + (".mp4" if shutil.which("ffmpeg") else ".gif")


def save_animation(gns: Trajectory, mpm: Trajectory | None, path: str | Path, fps: int = 15, max_frames: int = 80) -> Path:
    """The GNS rollout, beside the MPM when given; .mp4 if ffmpeg exists, else .gif."""
    trajs = [(gns, "GNS")] + ([(mpm, "MPM")] if mpm is not None else [])
    n = min(t.n_frames for t, _ in trajs)
    frames = np.unique(np.linspace(0, n - 1, min(n, max_frames)).round().astype(int))
    fig, axes = plt.subplots(1, len(trajs), figsize=_size(gns, 1, len(trajs)), squeeze=False)

    def draw(f):
        for ax, (traj, label) in zip(axes[0], trajs):
            _draw(ax, traj, int(f), f"{label}: t = {f * traj.frame_dt:.2f} s")

    anim = animation.FuncAnimation(fig, draw, frames=frames)
    path = Path(path).with_name(animation_name(Path(path).stem))
    if path.suffix == ".mp4":
        anim.save(path, writer=animation.FFMpegWriter(fps=fps), dpi=90)
    else:
        anim.save(path, writer=animation.PillowWriter(fps=fps), dpi=70)
    plt.close(fig)
    return path
