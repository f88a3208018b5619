"""Pictures of a hazard study: exceedance curves over the slope's drawing, and each front's
runout histogram with its P5 / P50 / P95."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from matplotlib.figure import Figure  # no pyplot: no global figure state, no GUI backend
from matplotlib.patches import Polygon as PolygonPatch

from runout.hazard.deposit import FRONTS
from runout.plots.frames import GROUND_COLOUR, material_colour
from runout.scene import Scene


def save_exceedance(scene: Scene, x: np.ndarray, probability: np.ndarray, thresholds, path: Path) -> Path:
    """The scene's regions (metres, left axis) under P(thickness > h) along x (right axis)."""
    fig = Figure(figsize=(10, max(2.5, 10 * scene.domain.height / scene.domain.width + 1.2)))
    ax = fig.add_subplot()
    names = scene.material_names
    for r in scene.regions:
        colour = GROUND_COLOUR if r.fixed else material_colour(names.index(r.material))
        ax.add_patch(PolygonPatch(np.asarray(r.polygon), closed=True, fc=colour, ec="k", lw=0.5, alpha=0.35))
    ax.set(xlim=(0, scene.domain.width), ylim=(0, scene.domain.height), xlabel="x (m)", ylabel="y (m)")
    curves = ax.twinx()
    for h, p in zip(thresholds, probability):
        curves.step(x, p, where="mid", lw=1.4, label=f"P(thickness > {h:g} m)")
    curves.set(ylim=(0, 1.05), ylabel="probability of exceedance")
    curves.legend(loc="upper right", fontsize=8)
    ax.set_title(f"{scene.name}: deposit thickness exceedance over the initial slope")
    fig.tight_layout()
    fig.savefig(path, dpi=130)
    return path


def save_runouts(runouts: np.ndarray, summaries: dict, path: Path) -> Path:
    """A histogram of each front's runout (m) with its P5, P50 and P95 marked."""
    fig = Figure(figsize=(5 * len(FRONTS), 3.6))
    for k, front in enumerate(FRONTS):
        ax = fig.add_subplot(1, len(FRONTS), k + 1)
        ax.hist(runouts[:, k], bins=min(30, max(5, len(runouts) // 5)), color="0.6", ec="k", lw=0.4)
        s = summaries[front]
        for key, style in (("p5_m", ":"), ("p50_m", "-"), ("p95_m", "--")):
            ax.axvline(s[key], color="C3", ls=style, label=f"{key[:-2].upper()} {s[key]:.1f} m")
        ax.set(xlabel=f"{front} front runout (m)", ylabel="realisations")
        ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=130)
    return path
