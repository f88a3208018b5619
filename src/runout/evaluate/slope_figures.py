"""Figures of the slope study: material and displacement fields, displacement-error growth."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from matplotlib import colormaps
from matplotlib.cm import ScalarMappable
from matplotlib.colors import Normalize
from matplotlib.figure import Figure  # no pyplot: no global figure state, no GUI backend

from runout.metrics import displacement_error, final_displacement
from runout.plots import draw_displacement, draw_materials
from runout.trajectory import Trajectory

TRACKED_POINTS = 100  # particle error histories drawn (paper: 100 random particles)


def _extent(truth: Trajectory, predicted: Trajectory) -> tuple[tuple[float, float], tuple[float, float]]:
    """x and y limits (m) around the soil of both runs at every frame, with a margin."""
    pts = np.concatenate([truth.positions[:, truth.soil].reshape(-1, 2), predicted.positions[:, truth.soil].reshape(-1, 2)])
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    pad = 0.05 * (hi[0] - lo[0])
    return (lo[0] - pad, hi[0] + pad), (0.0, hi[1] + pad)


def draw_fields(truth: Trajectory, predicted: Trajectory, frames: list[int], folder: Path, label: str) -> None:
    """fields_materials.png and fields_displacement.png: MPM (left) beside the engine named
    `label` (right)."""
    xlim, ylim = _extent(truth, predicted)
    vmax = max(float(final_displacement(truth).max()), float(final_displacement(predicted).max()), 1e-6)
    for kind in ("materials", "displacement"):
        width = 12.0
        height = len(frames) * (width / 2) * (ylim[1] - ylim[0]) / (xlim[1] - xlim[0]) + 1.0 * len(frames)
        fig = Figure(figsize=(width, max(3.0, height)), layout="constrained")
        axes = fig.subplots(len(frames), 2, squeeze=False)
        mappable = None
        for row, frame in enumerate(frames):
            for ax, traj, engine in ((axes[row, 0], truth, "MPM"), (axes[row, 1], predicted, label)):
                title = f"{engine}, frame {frame} (t = {frame * traj.frame_dt:.2f} s)"
                if kind == "materials":
                    draw_materials(ax, traj, frame, title, legend=row == 0 and engine == "MPM")
                else:
                    mappable = draw_displacement(ax, traj, frame, title, vmax=vmax)
                ax.set_xlim(*xlim)
                ax.set_ylim(*ylim)
        if mappable is not None:
            fig.colorbar(mappable, ax=list(axes.ravel()), label="displacement (m)", shrink=0.6)
        _save(fig, folder / f"fields_{kind}.png")


def draw_displacement_error(truth: Trajectory, predicted: Trajectory, path: Path, label: str, seed: int = 0) -> None:
    """Median displacement error over time (black dashed) and 100 random points' error
    histories coloured by their final MPM displacement (m); label: the engine's name."""
    error = displacement_error(predicted, truth)  # [T, S] m
    moved = final_displacement(truth)  # [S] m
    time_s = np.arange(error.shape[0]) * truth.frame_dt
    chosen = np.random.default_rng(seed).choice(error.shape[1], min(TRACKED_POINTS, error.shape[1]), replace=False)
    norm = Normalize(0.0, max(float(moved[chosen].max()), 1e-6))
    cmap = colormaps["viridis"]
    fig = Figure(figsize=(6.4, 4.2), layout="constrained")
    ax = fig.subplots()
    for k in chosen:
        ax.plot(time_s, error[:, k], color=cmap(norm(moved[k])), lw=0.7, alpha=0.8)
    ax.plot(time_s, np.median(error, axis=1), "k--", lw=2.0, label="median over all points")
    ax.set(xlabel="time (s)", ylabel="displacement error (m)", title=f"{label} displacement error against the MPM")
    ax.legend(loc="upper left")
    fig.colorbar(ScalarMappable(norm, cmap), ax=ax, label="final displacement, MPM (m)")
    _save(fig, path)


def _save(fig: Figure, path: Path) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=120)
