"""`runout average`: the model weights of several checkpoints of one GNS training run averaged
into one file (stochastic weight averaging over points of one run's path, which steadies a run
whose rollouts swing from one validation to the next; whether it helps is judged by rollouts
from rest, `runout evaluate heldout`).

Each input's `model` entry (the weight average when the run had --ema) is read, the weights
are averaged parameter by parameter with equal weights, and OUT is written as a weights-only
checkpoint (no optimiser, not resumable) with the last input's normalisation, schema and
settings and the step of the last input. The inputs must come from one run: the same network,
schema, normalisation statistics and connectivity radius, else InputError.
"""

from __future__ import annotations

from pathlib import Path

import torch

from runout.errors import InputError
from runout.gns.checkpoint import read_checkpoint, save_checkpoint, simulator_from_checkpoint
from runout.reading import file_to_read

SAME = ("schema", "stats", "radius", "network")  # entries every input must share


def check_inputs(out: Path, inputs: list[Path]) -> None:
    """InputError unless every input is a file, there are at least 2 and OUT is none of them
    nor a folder. Reads nothing."""
    for path in inputs:
        file_to_read(path, "checkpoint")
    if len(inputs) < 2:
        raise InputError(f"{len(inputs)} checkpoint given; averaging needs at least 2 of one run.")
    if Path(out).is_dir():
        raise InputError(f"--out {out} is a folder; name the checkpoint file to write, such as {Path(out) / 'mean.pt'}.")
    if any(Path(out).resolve() == Path(p).resolve() for p in inputs):
        raise InputError(f"--out {out} is one of the inputs; name a new file for the average.")


def average_checkpoints(out: Path, inputs: list[Path]) -> Path:
    """Write the mean of the inputs' weights to OUT (module docstring) and return its path."""
    check_inputs(out, inputs)
    ckpts = [read_checkpoint(p) for p in inputs]
    first = ckpts[0]
    for path, ckpt in zip(inputs[1:], ckpts[1:]):
        for key in SAME:
            if not _equal(ckpt.get(key), first.get(key)):
                raise InputError(f"{path}: its '{key}' differs from that of {inputs[0]}; only checkpoints of one run can be averaged.")
    names = first["model"].keys()
    mean = {n: sum(c["model"][n].double() for c in ckpts).div(len(ckpts)).to(first["model"][n].dtype) for n in names}
    last = ckpts[-1]
    simulator = simulator_from_checkpoint({**last, "model": mean}, out)
    extra = {k: last[k] for k in ("step", "train") if k in last}
    return save_checkpoint(out, simulator, averaged_from=[str(p) for p in inputs], **extra)


def _equal(a, b) -> bool:
    """Nested dicts/lists of tensors and plain values compared by value."""
    if isinstance(a, dict) and isinstance(b, dict):
        return a.keys() == b.keys() and all(_equal(a[k], b[k]) for k in a)
    if isinstance(a, (list, tuple)) and isinstance(b, (list, tuple)):
        return len(a) == len(b) and all(_equal(x, y) for x, y in zip(a, b))
    if isinstance(a, torch.Tensor) and isinstance(b, torch.Tensor):
        return a.shape == b.shape and bool(torch.equal(a, b))
    return a == b
