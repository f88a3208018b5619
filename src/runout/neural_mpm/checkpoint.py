"""Neural-MPM checkpoints: one file holding the engine (its config and weights), what it was
trained on (data_ranges, runout.learned.training_range) and, for a training run, the state to
resume it (optimizer, step, cpu_seconds, best, train settings; with a weight average, the last
step's weights as train_model, `model` being the average). Written atomically (temporary
file, then os.replace); read as plain data (runout.learned.files.read_plain) and checked
entry by entry before anything is built from it."""

from __future__ import annotations

from dataclasses import fields
from pathlib import Path

import torch

from runout import checks
from runout.errors import InputError
from runout.learned.files import engine_of, read_plain, save_plain
from runout.neural_mpm.config import CONFIG_LIMITS, MAX_LEVELS, MAX_WIDTH, WHOLE, widths_allowed
from runout.neural_mpm.engine import ENGINE_NAME, NeuralMPM, NeuralMPMConfig

FORMAT = "runout-neural-mpm-1"


def checkpoint_dict(engine: NeuralMPM, **training_state) -> dict:
    return {"format": FORMAT, "engine": ENGINE_NAME, "config": engine.config.as_dict(), "model": engine.state_dict(),
            **({"data_ranges": engine.data_ranges} if engine.data_ranges else {}), **training_state}


def save_checkpoint(path: str | Path, engine: NeuralMPM, **training_state) -> Path:
    """Write atomically (runout.learned.files.save_plain)."""
    return save_plain(path, checkpoint_dict(engine, **training_state))


def read_checkpoint(path: str | Path) -> dict:
    """The checkpoint's contents, checked: a neural-MPM file, its config in range, finite weights."""
    return check_checkpoint(read_plain(path), path)


def check_checkpoint(ckpt: object, path: str | Path) -> dict:
    """A file's contents as read (runout.learned.files.read_plain), checked as read_checkpoint does."""
    found = engine_of(ckpt)
    if found != ENGINE_NAME:
        raise InputError(f"{path}: holds {'a ' + found if found else 'no'} engine's model where a {ENGINE_NAME} "
                         "checkpoint was expected.")
    for key in ("config", "model"):
        if not isinstance(ckpt.get(key), dict):
            raise InputError(f"{path}: the checkpoint's '{key}' must be a table of values.")
    _check_config(ckpt["config"], path)
    for key in ("model", "train_model"):
        weights = ckpt.get(key, {})
        if not isinstance(weights, dict):
            raise InputError(f"{path}: the checkpoint's '{key}' must be a table of values.")
        for name, tensor in weights.items():
            if not isinstance(tensor, torch.Tensor) or not bool(torch.isfinite(tensor).all()):
                raise InputError(f"{path}: the {'model' if key == 'model' else 'last step'} weight '{name}' is not a "
                                 "finite tensor.")
    if "train_model" in ckpt and {k: tuple(v.shape) for k, v in ckpt["train_model"].items()} != \
            {k: tuple(v.shape) for k, v in ckpt["model"].items()}:
        raise InputError(f"{path}: the last step's weights (train_model) do not match the model's names and shapes.")
    ranges = ckpt.get("data_ranges")
    if ranges is not None and not isinstance(ranges, dict):
        raise InputError(f"{path}: the checkpoint's 'data_ranges' must be a table of values.")
    return ckpt


def _check_config(config: dict, path) -> None:
    known = {f.name for f in fields(NeuralMPMConfig)}
    unknown = sorted(set(config) - known)
    if unknown:
        raise InputError(f"{path}: unknown key '{unknown[0]}' in the checkpoint's config; known keys are "
                         f"{', '.join(sorted(known))}.")
    for key, (lo, hi) in CONFIG_LIMITS.items():
        if key in config:
            checks.number(config[key], f"config.{key}", path, lo, hi, whole=key in WHOLE)
    widths = config.get("widths", NeuralMPMConfig.widths)
    if not widths_allowed(widths):
        raise InputError(f"{path}: config.widths = {widths!r} must be 1 to {MAX_LEVELS} whole numbers of channels in "
                         f"[1, {MAX_WIDTH}].")


def engine_from_checkpoint(ckpt: dict, source) -> NeuralMPM:
    engine = NeuralMPM(NeuralMPMConfig.from_dict(ckpt["config"]))
    try:
        engine.load_state_dict(ckpt["model"])
    except (RuntimeError, TypeError, KeyError):
        raise InputError(f"{source}: the model weights do not match the engine's config.") from None
    engine.data_ranges = ckpt.get("data_ranges")
    return engine


def load_engine(path: str | Path, device: str | torch.device = "cpu") -> NeuralMPM:
    """The engine stored in a checkpoint, on `device`, in eval mode."""
    return engine_from_checkpoint(read_checkpoint(path), path).to(device).eval()



def ship(run_file: str | Path, shipped: str | Path, resume: str | Path, ranges: dict | None = None) -> None:
    """From a training run's checkpoint, the shipped file (the engine, its config and what it
    was trained on: no optimizer state) and the resume file (everything, for the next chunk).
    ranges: data_ranges to record where the run's file has none (runs older than the record)."""
    ckpt = read_checkpoint(run_file)
    if ranges is not None and not ckpt.get("data_ranges"):
        ckpt["data_ranges"] = ranges
    engine = engine_from_checkpoint(ckpt, run_file)
    trained = {k: ckpt[k] for k in ("step", "cpu_seconds", "best", "train") if k in ckpt}
    save_checkpoint(shipped, engine, **trained)
    save_checkpoint(resume, engine, **{**trained, **{k: ckpt[k] for k in ("optimizer", "train_model") if k in ckpt}})
