"""Pictures of scenes and trajectory frames: material colours, displacement fields. Lengths in metres."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from matplotlib.figure import Figure  # no pyplot: no global figure state, no GUI backend
from matplotlib.patches import Polygon as PolygonPatch

from runout.scene import Scene
from runout.trajectory import Trajectory

GROUND_COLOUR = "#9a9a9a"
_PALETTE = ["#4c9be8", "#e8554c", "#f2b134", "#8e6cd1", "#3fb67a", "#e58ac9", "#6d4c3d", "#2bb5c4"]


def material_colour(k: int) -> str:
    return _PALETTE[k % len(_PALETTE)]


def _material_label(m) -> str:
    if m.model == "elastic":
        return f"{m.name} (elastic)"
    return f"{m.name}: φ={m.friction_angle:.1f}°, c={m.cohesion:.0f} kPa"


def _frame_axes(ax, bounds, title: str | None) -> None:
    ax.set_xlim(bounds[0][0], bounds[0][1])
    ax.set_ylim(bounds[1][0], bounds[1][1])
    ax.set_aspect("equal")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    if title:
        ax.set_title(title, fontsize=10)


def _marker_size(ax, traj: Trajectory) -> float:
    """Marker area (pt^2) so that points at the seeding spacing roughly touch, from the axes'
    width once the domain's limits and equal aspect apply: after ax.clear() the axes' active
    box is a stale square, which drew every animation frame after the first with points too
    small to see."""
    _frame_axes(ax, traj.bounds, None)
    ax.apply_aspect()
    fig = ax.figure
    width_in = fig.get_size_inches()[0] * ax.get_position().width
    width_m = traj.bounds[0][1] - traj.bounds[0][0]
    spacing = _spacing(traj)
    return max(0.5, (spacing / width_m * width_in * 72) ** 2)


def _spacing(traj: Trajectory) -> float:
    x = np.unique(np.round(traj.positions[0, :, 0], 3))
    d = np.diff(x)
    return float(np.median(d[d > 1e-6])) if len(d) else 1.0


def draw_materials(ax, traj: Trajectory, frame: int, title: str | None = None, legend: bool = True) -> None:
    """Points of one frame coloured by material; kinematic (fixed) points grey."""
    pos = traj.positions[frame]
    size = _marker_size(ax, traj)
    soil = traj.soil
    ax.scatter(pos[~soil, 0], pos[~soil, 1], s=size, c=GROUND_COLOUR, marker="s", linewidths=0)
    for k, m in enumerate(traj.materials):
        sel = soil & (traj.material_id == k)
        if sel.any():
            ax.scatter(pos[sel, 0], pos[sel, 1], s=size, c=material_colour(k), marker="s",
                       linewidths=0, label=_material_label(m))
    _frame_axes(ax, traj.bounds, title)
    if legend and soil.any():
        (x0, x1), (y0, y1) = traj.bounds
        # a flat domain (a dam, a runout plain) has no free corner: the legend goes beside it
        place = {"loc": "upper left", "bbox_to_anchor": (1.01, 1.0)} if (y1 - y0) < 0.3 * (x1 - x0) else {"loc": "best"}
        ax.legend(**place, fontsize=7, markerscale=max(1.0, 6 / np.sqrt(size)), framealpha=0.8)


def draw_displacement(ax, traj: Trajectory, frame: int, title: str | None = None, vmax: float | None = None):
    """Points of one frame coloured by displacement magnitude from frame 0 (m)."""
    pos = traj.positions[frame]
    disp = np.linalg.norm(pos - traj.positions[0], axis=1)
    sc = ax.scatter(pos[:, 0], pos[:, 1], s=_marker_size(ax, traj), c=disp, cmap="viridis",
                    vmin=0, vmax=vmax if vmax is not None else max(float(disp.max()), 1e-6),
                    marker="s", linewidths=0)
    _frame_axes(ax, traj.bounds, title)
    return sc


def figsize(bounds, rows: int = 1, cols: int = 1, width: float = 10.0) -> tuple[float, float]:
    w = bounds[0][1] - bounds[0][0]
    h = bounds[1][1] - bounds[1][0]
    return width, max(2.5, rows * width / cols * h / w + 0.9 * rows)


def save_frame(traj: Trajectory, frame: int, path: str | Path, title: str | None = None) -> Path:
    path = Path(path)
    fig = Figure(figsize=figsize(traj.bounds))
    ax = fig.add_subplot()
    t = frame * traj.frame_dt
    draw_materials(ax, traj, frame, title or f"{traj.name}: frame {frame} (t = {t:.2f} s)")
    fig.tight_layout()
    fig.savefig(path, dpi=130)
    return path


def save_comparison(
    truth: Trajectory, predicted: Trajectory, path: str | Path, frames: tuple[int, int], titles: tuple[str, str],
    height: float = 5.0,
) -> Path:
    """The truth (MPM) above the prediction (GNS) at the given frames, coloured by material."""
    fig = Figure(figsize=(10, height))
    axes = fig.subplots(2, 1)
    draw_materials(axes[0], truth, frames[0], title=titles[0])
    draw_materials(axes[1], predicted, frames[1], title=titles[1], legend=False)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    return Path(path)


def save_side_by_side(panels: list[tuple[Trajectory, str]], path: str | Path, frame: int = -1) -> Path:
    """(trajectory, label) panels at one frame (-1: each one's last), left to right on the
    same axes (e.g. MPM beside GNS), points coloured by material, the legend on the first."""
    fig = Figure(figsize=figsize(panels[0][0].bounds, cols=len(panels), width=6.0 * len(panels)))
    axes = fig.subplots(1, len(panels), squeeze=False)
    for k, (ax, (traj, label)) in enumerate(zip(axes[0], panels)):
        f = frame % traj.n_frames
        draw_materials(ax, traj, f, f"{label}: frame {f} (t = {f * traj.frame_dt:.2f} s)", legend=k == 0)
    fig.tight_layout()
    fig.savefig(path, dpi=130)
    return Path(path)


def draw_scene(scene: Scene, path: str | Path) -> Path:
    """The scene's regions as filled polygons (no simulation)."""
    path = Path(path)
    bounds = [[0, scene.domain.width], [0, scene.domain.height]]
    fig = Figure(figsize=figsize(bounds))
    ax = fig.add_subplot()
    names = scene.material_names
    seen = set()
    for r in scene.regions:
        k = names.index(r.material)
        colour = GROUND_COLOUR if r.fixed else material_colour(k)
        label = None if r.material in seen else _material_label(scene.materials[r.material])
        seen.add(r.material)
        ax.add_patch(PolygonPatch(np.asarray(r.polygon), closed=True, fc=colour, ec="k", lw=0.6, label=label))
        if any(r.velocity):
            c = np.asarray(r.polygon).mean(axis=0)
            ax.annotate("", xy=c + np.asarray(r.velocity), xytext=c, arrowprops={"arrowstyle": "->"})
    _frame_axes(ax, bounds, f"{scene.name}: {scene.domain.width:g} x {scene.domain.height:g} m, "
                            f"cells {scene.domain.cell_size:g} m")
    ax.legend(loc="upper right", fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=130)
    return path
