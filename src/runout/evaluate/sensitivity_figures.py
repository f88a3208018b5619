"""Figures of the data-size study: rollout MSE per subset size, training-loss histories."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure  # no pyplot: no global figure state, no GUI backend

from runout.train import LOG

TITLES = {"steps": "fixed step budget", "epochs": "fixed epoch budget"}


def draw_rollout_mse(results: list[dict], path: Path) -> None:
    """Bars of the median rollout MSE per subset size, error bars from the 25th to 75th percentile."""
    budgets = [b for b in TITLES if any(r["budget"] == b for r in results)]
    fig = Figure(figsize=(5 * len(budgets), 3.8), layout="constrained")
    axes = np.atleast_1d(fig.subplots(1, len(budgets), sharey=True))
    for ax, budget in zip(axes, budgets):
        group = [r for r in results if r["budget"] == budget]
        median = np.array([r["median_mse_m2"] for r in group])
        low = median - np.array([r["p25_mse_m2"] for r in group])
        high = np.array([r["p75_mse_m2"] for r in group]) - median
        ax.bar(range(len(group)), median, yerr=[low, high], capsize=4, color="tab:blue", alpha=0.8)
        ax.set_xticks(range(len(group)), [f"{r['size']}\n({r['steps']:,} steps)" for r in group], fontsize=7)
        ax.set(xlabel="training simulations N", ylabel="rollout MSE (m$^2$)", title=TITLES[budget], yscale="log")
    fig.savefig(path, dpi=120)


def draw_loss_histories(runs: dict[tuple[str, int], Path], path: Path) -> None:
    """Training loss against step for every run, one panel per budget."""
    budgets = [b for b in TITLES if any(kind == b for kind, _ in runs)]
    fig = Figure(figsize=(5 * len(budgets), 3.8), layout="constrained")
    axes = np.atleast_1d(fig.subplots(1, len(budgets)))
    for ax, budget in zip(axes, budgets):
        for (kind, size), run_dir in sorted(runs.items()):
            if kind == budget:
                steps, losses = _loss_log(run_dir / LOG)
                ax.plot(steps, losses, label=f"N = {size}")
        ax.set(xlabel="step", ylabel="training loss", title=TITLES[budget], yscale="log")
        ax.legend(fontsize=7)
    fig.savefig(path, dpi=120)


def _loss_log(path: Path) -> tuple[list[int], list[float]]:
    records = [json.loads(line) for line in path.read_text().splitlines() if line.strip()] if path.is_file() else []
    records = [r for r in records if "loss" in r]
    return [r["step"] for r in records], [r["loss"] for r in records]
