"""Pictures of random scene families (paper Table A.1), to look at before generating."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from matplotlib import colormaps
from matplotlib.figure import Figure  # no pyplot: no global figure state, no GUI backend
from matplotlib.patches import Polygon

from runout.scene import Scene


def draw_grid(scenes: list[tuple[Scene, str]], path: str | Path, columns: int = 4) -> Path:
    """Draw scenes, each with its family's name, in a grid (fixed regions grey, each soil
    material its own colour, block velocities as arrows) and save the picture to `path`."""
    rows = -(-len(scenes) // columns)
    fig = Figure(figsize=(4.2 * columns, 2.6 * rows))
    axes = fig.subplots(rows, columns, squeeze=False)
    colours = colormaps["tab10"].colors
    for ax, (scene, family) in zip(axes.ravel(), scenes):
        d = scene.domain
        names = scene.material_names
        for r in scene.regions:
            colour = "0.6" if r.fixed else colours[names.index(r.material) % 10]
            ax.add_patch(Polygon(r.polygon, closed=True, facecolor=colour, edgecolor="k", linewidth=0.5))
            if r.velocity != (0.0, 0.0):
                cx, cy = np.mean(r.polygon, axis=0)
                ax.annotate("", (cx + 2 * r.velocity[0], cy + 2 * r.velocity[1]), (cx, cy),
                            arrowprops={"arrowstyle": "->", "color": "k"})
        soils = [m for m in scene.materials.values() if m.model != "elastic"]
        label = ", ".join(f"{m.friction_angle:.0f}°/{m.cohesion:.0f}" for m in soils)
        ax.set_title(f"{scene.name} ({family}): φ/c {label}", fontsize=7)
        ax.set_xlim(0, d.width)
        ax.set_ylim(0, d.height)
        ax.set_aspect("equal")
        ax.tick_params(labelsize=6)
    for ax in axes.ravel()[len(scenes):]:
        ax.axis("off")
    fig.tight_layout()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    return path
