"""Figures of the column-collapse study: 1:1 runout plots, error heat maps, time evolution."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from matplotlib.figure import Figure  # no pyplot: no global figure state, no GUI backend

from runout.plots import draw_materials
from runout.trajectory import Trajectory

EVOLUTION_COLUMNS = 4  # snapshots per engine in a time-evolution figure


def _aspects(rows) -> list[float]:
    return sorted({r.aspect for r in rows})


def _material_labels(rows) -> list[tuple[float, float]]:
    """(phi, c) combinations in a fixed order: the colour label of each point."""
    return sorted({(r.phi_deg, r.cohesion_kpa) for r in rows})


def draw_runout_comparison(rows, stats: list[dict], path: Path, label: str) -> None:
    """L^n of the engine named `label` against the MPM, one panel per aspect ratio, with the 1:1 line."""
    aspects, labels = _aspects(rows), _material_labels(rows)
    colours = [_colour(k, len(labels)) for k in range(len(labels))]
    r2 = {s["aspect"]: s["r2"] for s in stats}
    fig = Figure(figsize=(4.2 * len(aspects) + 2.2, 4.2), layout="constrained")
    axes = fig.subplots(1, len(aspects), squeeze=False)[0]
    for ax, aspect in zip(axes, aspects):
        group = [r for r in rows if r.aspect == aspect]
        for r in group:
            k = labels.index((r.phi_deg, r.cohesion_kpa))
            ax.scatter(r.runout_norm_mpm, r.runout_norm_predicted, color=colours[k], s=28, edgecolors="k", linewidths=0.4)
        values = [v for r in group for v in (r.runout_norm_mpm, r.runout_norm_predicted) if np.isfinite(v)]
        lo, hi = min(values + [0.0]), max(values + [1e-3])
        ax.plot([lo, hi], [lo, hi], "k--", lw=0.8)
        ax.set(xlabel="$L^n$ MPM", ylabel=f"$L^n$ {label}", title=f"a = {aspect:g}, $R^2$ = {r2[aspect]:.3f}", aspect="equal")
    handles = [axes[0].scatter([], [], color=colours[k], s=28, edgecolors="k", linewidths=0.4,
                               label=f"{k}: φ={p:g}°, c={c:g} kPa") for k, (p, c) in enumerate(labels)]
    fig.legend(handles=handles, loc="outside right center", fontsize=6, title="material", title_fontsize=7)
    _save(fig, path)


def draw_error_heatmaps(rows, stats: list[dict], path: Path) -> None:
    """Absolute percentage error per (phi, c), one heat map per aspect ratio."""
    aspects = _aspects(rows)
    phis = sorted({r.phi_deg for r in rows})
    cohesions = sorted({r.cohesion_kpa for r in rows})
    by_aspect = {s["aspect"]: s for s in stats}
    top = max([r.ape_percent for r in rows if np.isfinite(r.ape_percent)] + [1e-6])
    fig = Figure(figsize=(4.2 * len(aspects) + 1.0, 3.8), layout="constrained")
    axes = fig.subplots(1, len(aspects), squeeze=False)[0]
    image = None
    for ax, aspect in zip(axes, aspects):
        grid = np.full((len(phis), len(cohesions)), np.nan)
        for r in rows:
            if r.aspect == aspect:
                grid[phis.index(r.phi_deg), cohesions.index(r.cohesion_kpa)] = r.ape_percent
        image = ax.imshow(grid, origin="lower", cmap="Reds", vmin=0, vmax=top, aspect="auto")
        for (i, j), v in np.ndenumerate(grid):
            ax.text(j, i, f"{v:.1f}", ha="center", va="center", fontsize=7)
        s = by_aspect[aspect]
        ax.set(xticks=range(len(cohesions)), xticklabels=[f"{c:g}" for c in cohesions], xlabel="c (kPa)",
               yticks=range(len(phis)), yticklabels=[f"{p:g}" for p in phis], ylabel="φ (°)",
               title=f"a = {aspect:g}: mean {s['mean_ape_percent']:.2f} %, CV {s['cv_ape']:.2f}")
    fig.colorbar(image, ax=list(axes), label="runout error (%)")
    _save(fig, path)


def draw_evolution(truth: Trajectory, predicted: Trajectory, row, percentile: int, path: Path, label: str) -> None:
    """MPM (top) and the engine named `label` (bottom) at evenly spaced frames of one case."""
    last = min(truth.n_frames, predicted.n_frames) - 1
    frames = sorted({round(k * last / (EVOLUTION_COLUMNS - 1)) for k in range(EVOLUTION_COLUMNS)})
    x_hi = max(row.Lf_mpm_m, row.Lf_predicted_m, row.L0_m) * 1.1
    y_hi = float(truth.positions[0, truth.soil, 1].max()) * 1.1
    fig = Figure(figsize=(3.6 * len(frames), 2 * max(2.0, 3.6 * y_hi / x_hi) + 0.8), layout="constrained")
    axes = fig.subplots(2, len(frames), squeeze=False, sharex=True, sharey=True)
    for col, frame in enumerate(frames):
        for ax, traj, engine in ((axes[0, col], truth, "MPM"), (axes[1, col], predicted, label)):
            draw_materials(ax, traj, frame, f"{engine}, t = {frame * traj.frame_dt:.2f} s (frame {frame})", legend=False)
            ax.set_xlim(0, x_hi)
            ax.set_ylim(0, y_hi)
            ax.label_outer()
    fig.suptitle(f"{percentile}th error percentile: a = {row.aspect:g}, φ = {row.phi_deg:g}°, c = {row.cohesion_kpa:g} kPa; "
                 f"$L^n$ {label} {row.runout_norm_predicted:.3f} vs MPM {row.runout_norm_mpm:.3f} ({row.ape_percent:.2f} %)", fontsize=10)
    _save(fig, path)


def _colour(k: int, n: int):
    from matplotlib import colormaps

    return colormaps["turbo"](k / max(n - 1, 1))


def _save(fig: Figure, path: Path) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=120)
