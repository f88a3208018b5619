"""Data-size study (paper §6): fine-tune subsets of N training simulations from one GNS model
(it trains GNS checkpoints only, through runout.train; a neural MPM's --init is refused), under a fixed step budget and under a fixed epoch budget (either or both), and measure rollout errors on
held-out simulations.

A subset is the first N simulations of DATA/train.npz (with the full set's metadata, so
every subset shares its normalisation). One epoch is one pass over every training window:
the windows runout.train samples from the subset at the model's history and frame stride
(those of a scene at rest included), divided by the batch size and rounded up. The rollout
error of a held-out simulation is its position MSE (m²) averaged over every frame of a
rollout from rest (its frame 0 held).

Writes OUT/sensitivity/: data_N/ (subsets), steps_N/ and epochs_N/ (training runs; a rerun
resumes or reuses them), rollouts.csv, summary.json, rollout_mse.png and loss_history.png.
"""

from __future__ import annotations

import csv
import itertools
import json
import math
import shutil
from pathlib import Path

import numpy as np
import torch
from tqdm.auto import tqdm

from runout.contract import WindowSchema
from runout.dataset import split_trajectories
from runout.defaults import FRAME_DT
from runout.errors import InputError
from runout.evaluate.model_card import model_card
from runout.evaluate.sensitivity_figures import draw_loss_histories, draw_rollout_mse
from runout.evaluate.study_settings import BUDGETS, PAPER_SIZES, SensitivityConfig  # noqa: F401  (re-exported)
from runout.gns.checkpoint import load_simulator
from runout.gns.rollout import rollout_trajectory
from runout.gns.windows import TrainingWindows
from runout.learned.engine import LABELS
from runout.learned.load import engine_name
from runout.metrics import position_mse
from runout.simfiles import iter_simulations, read_metadata, write_simulations
from runout.train import CHECKPOINT, TrainConfig, continued_onset, cpu_has_native_bf16, train


def check_init(init: Path) -> None:
    """InputError unless `init` holds a GNS: the study fine-tunes through runout.train, the GNS's loop."""
    name = engine_name(init)
    if name != "gns":
        raise InputError(f"--init {init}: holds a {LABELS.get(name, name)}, but the data-size study fine-tunes "
                         "GNS checkpoints only; give a GNS checkpoint.")


def run_sensitivity(cfg: SensitivityConfig, out: Path) -> dict:
    """Run the study; returns the summary written to OUT/sensitivity/summary.json."""
    cfg.check()
    check_init(cfg.init)
    folder = Path(out) / "sensitivity"
    held_out = list(split_trajectories(cfg.data, cfg.split, cfg.held_out))
    schema = load_simulator(cfg.init).schema  # every subset is fine-tuned at the model's history and stride
    rows, runs = [], {}
    for size, budget in itertools.product(cfg.sizes, cfg.budgets):
        subset = write_subset(cfg.data, folder / f"data_{size}", size)
        steps = cfg.steps if budget == "steps" else cfg.epochs * steps_per_epoch(subset, cfg.batch_size, schema)
        run_dir = fine_tune(cfg, subset, folder / f"{budget}_{size}", steps)
        runs[(budget, size)] = run_dir
        rows += [{"budget": budget, "size": size, "steps": steps, "held_out": k, "rollout_mse_m2": mse}
                 for k, mse in enumerate(rollout_errors(run_dir / CHECKPOINT, held_out, cfg))]
    write_rows(rows, folder / "rollouts.csv")
    summary = summarise(rows, cfg)
    draw_rollout_mse(summary["results"], folder / "rollout_mse.png")
    draw_loss_histories(runs, folder / "loss_history.png")
    (folder / "summary.json").write_text(json.dumps(summary, indent=1))
    return summary


def write_subset(data: Path, folder: Path, size: int) -> Path:
    """folder/train.npz with the first `size` training simulations, and the full metadata."""
    if (folder / "train.npz").is_file():
        return folder
    sims = list(itertools.islice(iter_simulations(Path(data) / "train.npz"), size))
    if len(sims) < size:
        raise InputError(f"--sizes asks for {size} simulations but {Path(data) / 'train.npz'} holds {len(sims)}.")
    folder.mkdir(parents=True, exist_ok=True)
    shutil.copyfile(Path(data) / "metadata.json", folder / "metadata.json")
    write_simulations(folder / "train.npz", sims)
    return folder


def steps_per_epoch(subset: Path, batch_size: int, schema: WindowSchema) -> int:
    """Steps of one pass over the windows training samples from SUBSET/train.npz at the
    schema's history and frame stride (with TrainConfig's rest windows)."""
    data = TrainingWindows(subset / "train.npz", torch.device("cpu"), schema.history, rest_windows=TrainConfig.rest_windows,
                           frame_dt=float(read_metadata(subset).get("dt", FRAME_DT)))
    return max(1, math.ceil(data.with_stride(schema.frame_stride).n_windows / batch_size))


def fine_tune(cfg: SensitivityConfig, subset: Path, run_dir: Path, steps: int) -> Path:
    """Fine-tune cfg.init on the subset to `steps` steps (resuming a run already there), with
    the settings that trained the shipped model: the recipe (TrainConfig's defaults: noise, exact
    rest, pushforward, weight average), the learning rate going on from the model's step, its
    onset phase continued and its own network inputs; bf16 on a CPU that multiplies it natively."""
    bf16 = torch.device(cfg.device).type == "cpu" and cpu_has_native_bf16()
    train(TrainConfig(
        data=subset, out=run_dir, steps=steps, batch_size=cfg.batch_size, device=cfg.device, init=cfg.init,
        resume=(run_dir / CHECKPOINT).is_file(), valid_every=0, bf16=bf16, progress=cfg.progress,
        log_every=max(1, min(100, steps // 50)), save_every=max(1, min(10_000, steps // 10)), **continued_onset(cfg.init),
    ))
    return run_dir


def rollout_errors(checkpoint: Path, held_out: list, cfg: SensitivityConfig) -> list[float]:
    """Position MSE (m²) averaged over the frames of each held-out rollout."""
    simulator = load_simulator(checkpoint, cfg.device)
    errors = []
    for truth in tqdm(held_out, desc=f"rollouts {checkpoint.parent.name}", disable=not cfg.progress):
        with torch.no_grad():
            predicted = rollout_trajectory(simulator, truth, truth.n_frames, stop_speed=None)
        errors.append(float(position_mse(predicted, truth).mean()))
    return errors


def write_rows(rows: list[dict], path: Path) -> None:
    with path.open("w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=("budget", "size", "steps", "held_out", "rollout_mse_m2"))
        writer.writeheader()
        writer.writerows(rows)


def summarise(rows: list[dict], cfg: SensitivityConfig) -> dict:
    results = []
    for budget, size in itertools.product(cfg.budgets, cfg.sizes):
        mse = np.array([r["rollout_mse_m2"] for r in rows if r["budget"] == budget and r["size"] == size])
        steps = next(r["steps"] for r in rows if r["budget"] == budget and r["size"] == size)
        p25, median, p75 = np.percentile(mse, [25, 50, 75])
        results.append({"budget": budget, "size": size, "steps": steps, "median_mse_m2": float(median),
                        "p25_mse_m2": float(p25), "p75_mse_m2": float(p75), "held_out": len(mse)})
    return {
        "study": "sensitivity",
        "model": model_card(cfg.init).to_dict(),
        "data": str(cfg.data),
        "split": cfg.split,
        "fixed_steps": cfg.steps,
        "fixed_epochs": cfg.epochs,
        "budgets": list(cfg.budgets),
        "results": results,
    }
