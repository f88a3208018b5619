"""Figures of an inverse run: loss history, parameter history, predicted deposit against the target,
the loss along each parameter through the optimum with its interval."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from matplotlib.figure import Figure  # no pyplot: no global figure state, no GUI backend
from matplotlib.ticker import MaxNLocator

from runout.errors import InputError
from runout.inverse.history import History
from runout.inverse.intervals import Intervals
from runout.inverse.optimise import StartResult, read_deposit


def default_iterations(available: list[int]) -> list[int]:
    """The first, second, middle and last iterate."""
    picks = [available[0], available[min(1, len(available) - 1)], available[len(available) // 2], available[-1]]
    return sorted(set(picks))


def check_iterations(text: str | None, max_iterations: int) -> list[int | str] | None:
    """'0,3,last' -> [0, 3, 'last'], checked before the run: whole numbers up to the spec's
    max_iterations, or 'last'; None -> None (the default choice)."""
    if text is None:
        return None
    items = [item.strip() for item in text.split(",")]
    for item in items:
        if item != "last" and not (item.isdigit() and int(item) <= max_iterations):
            raise InputError(
                f"--plot-iterations: '{item}' is neither 'last' nor an iteration number in [0, {max_iterations}] "
                "(the spec's optimiser.max_iterations)."
            )
    return [item if item == "last" else int(item) for item in items]


def pick_iterations(chosen: list[int | str] | None, available: list[int]) -> tuple[list[int], list[int]]:
    """(iterations to draw, requested ones the run did not reach because it stopped early)."""
    if chosen is None:
        return default_iterations(available), []
    numbers = [available[-1] if item == "last" else item for item in chosen]
    return sorted({n for n in numbers if n in available}), sorted({n for n in numbers if n not in available})


def draw_loss(history: History, path: Path) -> None:
    its = history.iterations
    model = [history.model_loss(r) for r in its]
    panels = 2 if model and model[0] is not None else 1
    fig, axes = _figure(1, panels, figsize=(5 * panels, 3.6))
    ax = axes[0, 0]
    ax.semilogy([r.iteration for r in its], [r.loss for r in its], "o-", color="k")
    ax.set(xlabel="iteration", ylabel="data loss (m$^2$)", title="Data loss")
    if panels == 2:
        axes[0, 1].semilogy([r.iteration for r in its], np.maximum(model, 1e-16), "o-", color="tab:red")
        axes[0, 1].set(xlabel="iteration", ylabel="MSE of normalised parameters", title="Model loss")
    _save(fig, path)


KEPT = "kept: the lowest loss (evaluations ran out)"


def draw_parameters(history: History, path: Path) -> None:
    its, kept = history.iterations, history.kept
    n = len(history.free)
    fig, axes = _figure(1, n, figsize=(4 * n, 3.4))
    for k, (p, ax) in enumerate(zip(history.free, axes[0])):
        ax.plot([r.iteration for r in its], [r.values[k] for r in its], "o-", color="tab:blue", label="estimate")
        if kept is not None:  # drawn one step after the last iterate: where the run's answer came from
            ax.plot([its[-1].iteration + 1], [kept.values[k]], "*", ms=12, color="tab:green", label=KEPT)
        ax.axhspan(p.lower, p.upper, color="0.92", zorder=0, label="bounds")
        ax.axhline(p.lower, color="0.5", lw=0.8, ls="--")
        ax.axhline(p.upper, color="0.5", lw=0.8, ls="--")
        if history.true_values is not None:
            ax.axhline(history.true_values[k], color="tab:red", ls=":", label="true")
        ax.set(xlabel="iteration", ylabel=f"{p.name} ({p.unit})", title=p.name)
    axes[0, 0].legend(fontsize=8)
    _save(fig, path)


def draw_deposits(
    history: History,
    target: np.ndarray,  # [N, 2] m, target at the last observed frame
    material_id: np.ndarray,  # [N]
    moving: np.ndarray,  # [N] bool, points that are not kinematic
    iterations: list[int],
    path: Path,
) -> None:
    by_iteration = {r.iteration: r for r in history.iterations}
    panels = [(by_iteration[it], f"iteration {it}") for it in iterations]
    if history.kept is not None:
        panels.append((history.kept, f"evaluation {history.kept.evaluation}, {KEPT}"))
    fig, axes = _figure(len(panels), 1, figsize=(10, 2.6 * len(panels)))
    lo, hi = target[moving].min(axis=0), target[moving].max(axis=0)
    for ax, (record, label) in zip(axes[:, 0], panels):
        predicted = read_deposit(history.out_dir, record.evaluation, len(target))
        ax.scatter(*target[moving].T, s=3, c="0.75", label="target")
        ax.scatter(*predicted[moving].T, s=1, c=material_id[moving], cmap="tab10", vmin=0, vmax=9, label="predicted")
        values = ", ".join(f"{p.name} = {v:.3g} {p.unit}" for p, v in zip(history.free, record.values))
        ax.set_title(f"{label}: {values}", fontsize=9)
        ax.set_aspect("equal")
        pad = 0.05 * (hi - lo).max()
        ax.set_xlim(lo[0] - pad, hi[0] + pad)
        ax.set_ylim(lo[1] - pad, hi[1] + pad)
    axes[0, 0].legend(loc="upper right", fontsize=8, markerscale=4)
    axes[-1, 0].set_xlabel("x (m)")
    _save(fig, path)


def draw_starts(results: list[StartResult], path: Path) -> None:
    """Parameter histories of every start in one figure, to show where the answers gather."""
    free = results[0].history.free
    fig, axes = _figure(1, len(free), figsize=(4 * len(free), 3.4))
    for k, (p, ax) in enumerate(zip(free, axes[0])):
        for n, result in enumerate(results):
            its, kept = result.history.iterations, result.history.kept
            line, = ax.plot([r.iteration for r in its], [r.values[k] for r in its], "o-", ms=3, label=f"start {n}")
            if kept is not None:  # the start's answer, one step after its last iterate
                ax.plot([its[-1].iteration + 1], [kept.values[k]], "*", ms=10, color=line.get_color(),
                        label=f"start {n} kept (evaluations ran out)")
        ax.axhline(p.lower, color="0.5", lw=0.8, ls="--")
        ax.axhline(p.upper, color="0.5", lw=0.8, ls="--")
        true_values = results[0].history.true_values  # the values that made the target, when it records them
        if true_values is not None:
            ax.axhline(true_values[k], color="tab:red", ls=":", label="true")
        ax.set(xlabel="iteration", ylabel=f"{p.name} ({p.unit})", title=p.name)
    axes[0, 0].legend(fontsize=7)
    _save(fig, path)


def draw_profile(profiles, intervals: Intervals, gauss_newton_loss, loss: float, true_values: list[float] | None,
                 path: Path) -> None:
    """Per free parameter, the loss along it through the optimum (forward runs, the others held
    there) above the optimum's, the Gauss-Newton quadratic of the intervals, and the interval.

    profiles: runout.inverse.uncertainty.Profile per parameter; gauss_newton_loss(k, δ [K]) ->
    [K] m², the linearised model's loss with parameter k moved by δ; loss: m² at the optimum."""
    level = f"{100 * intervals.confidence:g} %"
    fig, axes = _figure(1, len(profiles), figsize=(max(4.4 * len(profiles), 7.0), 4.2))
    for k, (p, profile, ax) in enumerate(zip(intervals.free, profiles, axes[0])):
        estimate = intervals.estimate[k]
        fine = np.linspace(profile.values[0], profile.values[-1], 200)
        ax.plot(fine, gauss_newton_loss(k, fine - estimate) - loss, "--", color="tab:red", label="Gauss-Newton quadratic")
        ax.plot(profile.values, profile.losses - loss, "o-", color="k", ms=4, lw=1, label="loss of forward runs")
        if np.isfinite(intervals.lower[k]):
            ax.axvspan(intervals.lower[k], intervals.upper[k], color="tab:blue", alpha=0.15, label=f"{level} interval")
        ax.axvline(estimate, color="tab:blue", lw=1, label="estimate")
        title = p.name if intervals.status[k] == "interior" else f"{p.name}: {intervals.status[k]}"
        if true_values is not None:
            ax.axvline(true_values[k], color="tab:green", ls=":", lw=1.5, label="true")
            title += _beyond(true_values[k], p.unit, profile)
        for bound in (p.lower, p.upper):
            if profile.values[0] <= bound <= profile.values[-1]:
                ax.axvline(bound, color="0.5", lw=0.8, ls="--")
        ax.set_xlim(profile.values[0], profile.values[-1])
        ax.set(xlabel=f"{p.name} ({p.unit})", ylabel="loss - loss at the estimate (m$^2$)", title=title)
        ax.title.set_fontsize(9)
    shown = {}  # one legend for all panels: each label once
    for ax in axes[0]:
        for handle, label in zip(*ax.get_legend_handles_labels()):
            shown.setdefault(label, handle)
    fig.legend(list(shown.values()), list(shown), loc="lower center", ncol=len(shown), fontsize=8)
    _save(fig, path, rect=(0.0, 0.08, 1.0, 1.0))


def _beyond(value: float, unit: str, profile) -> str:
    """Words for a title when the true value lies beyond the profile drawn."""
    if value < profile.values[0]:
        return f" (true {value:.4g} {unit}: left of the plot)"
    if value > profile.values[-1]:
        return f" (true {value:.4g} {unit}: right of the plot)"
    return ""


def _figure(rows: int, cols: int, figsize: tuple[float, float]):
    fig = Figure(figsize=figsize)
    return fig, fig.subplots(rows, cols, squeeze=False)


def _save(fig: Figure, path: Path, rect: tuple[float, float, float, float] | None = None) -> None:
    """rect: the part of the figure the axes fill (room for a figure legend)."""
    for ax in fig.axes:
        if ax.get_xlabel() == "iteration":
            ax.xaxis.set_major_locator(MaxNLocator(integer=True))
    fig.tight_layout(rect=rect)
    fig.savefig(path, dpi=130)
