"""Animations of trajectories, all written by one writer (write_animation): .mp4 through
ffmpeg or .gif through Pillow, chosen by the file name. save_animation stacks trajectories,
save_rollout_animation and save_side_by_side_animation set them beside each other."""

from __future__ import annotations

import shutil
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np
from matplotlib import animation
from matplotlib.figure import Figure  # no pyplot: no global figure state, no GUI backend

from runout.plots.frames import draw_materials, figsize
from runout.plots.rollout import draw_points, panel_size
from runout.trajectory import Trajectory


def write_animation(fig: Figure, draw: Callable[[int], None], frames: Sequence[int], path: Path, fps: int, dpi: int) -> Path:
    """Call draw(frame) for each frame and write the figure's pictures to `path`: MP4 when it
    ends in .mp4 (ffmpeg), else GIF."""
    anim = animation.FuncAnimation(fig, draw, frames=frames)
    writer = animation.FFMpegWriter(fps=fps) if path.suffix == ".mp4" else animation.PillowWriter(fps=fps)
    anim.save(path, writer=writer, dpi=dpi)
    return path


def animation_name(stem: str = "animation") -> str:
    """The file save_rollout_animation writes: .mp4 when ffmpeg is installed, else .gif."""
    return stem + (".mp4" if shutil.which("ffmpeg") else ".gif")


def save_animation(
    trajs: list[Trajectory], path: str | Path, labels: list[str] | None = None, stride: int | None = None,
    fps: int = 15,
) -> Path:
    """A GIF of one or more trajectories stacked vertically (e.g. GNS above MPM), points
    coloured by material."""
    labels = labels or [t.name for t in trajs]
    n_frames = min(t.n_frames for t in trajs)
    stride = stride or max(1, n_frames // 60)
    frames = list(range(0, n_frames, stride))
    if frames[-1] != n_frames - 1:
        frames.append(n_frames - 1)
    fig = Figure(figsize=figsize(trajs[0].bounds, rows=len(trajs)))
    axes = fig.subplots(len(trajs), 1, squeeze=False)

    def draw(f):
        for ax, traj, label in zip(axes[:, 0], trajs, labels):
            ax.clear()
            draw_materials(ax, traj, f, f"{label}: t = {f * traj.frame_dt:.2f} s", legend=False)
        fig.tight_layout()

    return write_animation(fig, draw, frames, Path(path), fps, dpi=80)


def save_rollout_animation(
    predicted: Trajectory, mpm: Trajectory | None, path: str | Path, fps: int = 15, max_frames: int = 80,
    label: str = "GNS",
) -> Path:
    """A learned engine's rollout (its name: label), beside the MPM when given; .mp4 if ffmpeg
    exists, else .gif."""
    trajs = [(predicted, label)] + ([(mpm, "MPM")] if mpm is not None else [])
    frames = _evenly_spread(min(t.n_frames for t, _ in trajs), max_frames)
    fig = Figure(figsize=panel_size(predicted, 1, len(trajs)))
    axes = fig.subplots(1, len(trajs), squeeze=False)

    def draw(f):
        for ax, (traj, label) in zip(axes[0], trajs):
            draw_points(ax, traj, int(f), f"{label}: t = {f * traj.frame_dt:.2f} s")

    path = Path(path).with_name(animation_name(Path(path).stem))
    return write_animation(fig, draw, frames, path, fps, dpi=90 if path.suffix == ".mp4" else 70)


def save_side_by_side_animation(
    panels: list[tuple[Trajectory, str]], path: str | Path, fps: int = 15, max_frames: int = 80
) -> Path:
    """(trajectory, label) panels side by side, left to right on the same axes (e.g. MPM
    beside GNS), points coloured by material; .mp4 if ffmpeg exists, else .gif."""
    frames = _evenly_spread(min(t.n_frames for t, _ in panels), max_frames)
    fig = Figure(figsize=figsize(panels[0][0].bounds, cols=len(panels), width=6.0 * len(panels)))
    axes = fig.subplots(1, len(panels), squeeze=False)

    def draw(f):
        for ax, (traj, label) in zip(axes[0], panels):
            ax.clear()
            draw_materials(ax, traj, int(f), f"{label}: t = {f * traj.frame_dt:.2f} s", legend=False)
        fig.tight_layout()

    path = Path(path).with_name(animation_name(Path(path).stem))
    return write_animation(fig, draw, frames, path, fps, dpi=90 if path.suffix == ".mp4" else 70)


def _evenly_spread(n_frames: int, most: int) -> np.ndarray:
    """At most `most` frame indices spread evenly from the first to the last."""
    return np.unique(np.linspace(0, n_frames - 1, min(n_frames, most)).round().astype(int))
