"""The velocity-space / physical-space diagnostics figure (3 rows x one column per frame)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from matplotlib.figure import Figure  # no pyplot: no global figure state, no GUI backend
from matplotlib.patches import Ellipse

from runout.metrics import velocities
from runout.trajectory import Trajectory


def draw_diagnostics(truth: Trajectory, predicted: Trajectory, frames: list[int], mean: np.ndarray, std: np.ndarray,
                     case, path: Path, label: str) -> None:
    """Top: the engine's velocities (m/s) coloured by velocity error with the training mean and
    its 1 and 2 sigma ellipses; middle: its positions coloured by velocity error; bottom: its
    positions coloured by its speed. label: the engine's name (GNS, neural MPM)."""
    soil = truth.soil
    fig = Figure(figsize=(4.6 * len(frames), 10.5), layout="constrained")
    axes = fig.subplots(3, len(frames), squeeze=False)
    for col, frame in enumerate(frames):
        v_pred, v_true = velocities(predicted, frame)[soil], velocities(truth, frame)[soil]
        error = np.linalg.norm(v_pred - v_true, axis=1)
        xy = predicted.positions[frame, soil]
        t = f"t = {frame} ({frame * truth.frame_dt:.2f} s)"
        _velocity_space(axes[0, col], v_pred, error, mean, std, f"{label} velocity space\n{t}")
        _positions(axes[1, col], xy, error, "|v$_{pred}$ − v$_{true}$| (m/s)", f"{label} velocity error\n{t}", "magma")
        _positions(axes[2, col], xy, np.linalg.norm(v_pred, axis=1), "|v$_{pred}$| (m/s)", f"{label} speed\n{t}", "viridis")
    fig.suptitle(f"{label} against the MPM\ncolumn a = {case.aspect:g}, φ = {case.phi:g}°, c = {case.cohesion:g} kPa")
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)


def _velocity_space(ax, v: np.ndarray, error: np.ndarray, mean: np.ndarray, std: np.ndarray, title: str) -> None:
    sc = ax.scatter(v[:, 0], v[:, 1], c=error, s=4, cmap="magma")
    ax.figure.colorbar(sc, ax=ax, label="|v$_{pred}$ − v$_{true}$| (m/s)")
    ax.plot(*mean, "o", color="red", ms=5, label="training mean")
    for k, style in ((1, "-"), (2, "--")):
        ax.add_patch(Ellipse(mean, 2 * k * std[0], 2 * k * std[1], fill=False, ec="red", ls=style, lw=1.2,
                             label=f"{k}σ"))
    ax.set(xlabel="v$_x$ (m/s)", ylabel="v$_y$ (m/s)", title=title)
    ax.legend(fontsize=7, loc="lower left")


def _positions(ax, xy: np.ndarray, value: np.ndarray, label: str, title: str, cmap: str) -> None:
    sc = ax.scatter(xy[:, 0], xy[:, 1], c=value, s=3, cmap=cmap, marker="s", linewidths=0)
    ax.figure.colorbar(sc, ax=ax, label=label)
    ax.set(xlabel="x (m)", ylabel="y (m)", title=title, aspect="equal")
