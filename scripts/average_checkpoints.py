"""Average the model weights of several checkpoints of one training run into one file.

    python scripts/average_checkpoints.py OUT.pt runs/ft8-snap/step-80000.pt runs/ft8-snap/step-85000.pt ...

Each input's `model` entry (the weight average when the run had --ema) is read, the weights
are averaged parameter by parameter with equal weights, and OUT is written as a weights-only
checkpoint (no optimiser, not resumable) with the last input's normalisation, schema and
settings and the step of the last input. The inputs must come from one run: the same network,
schema, normalisation statistics and connectivity radius, else the script refuses with one
sentence and exit code 2. Averaging points of one run's path several thousand steps apart
(stochastic weight averaging) steadies a run whose rollouts swing from one validation to the
next; whether it helps is judged by rollouts from rest (scripts/evaluate_model.py), as ever.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import torch

from runout.errors import InputError
from runout.gns.checkpoint import read_checkpoint, save_checkpoint, simulator_from_checkpoint

SAME = ("schema", "stats", "radius", "network")  # entries every input must share


def average_checkpoints(out: Path, inputs: list[Path]) -> Path:
    if len(inputs) < 2:
        raise InputError(f"average_checkpoints: {len(inputs)} input checkpoint given; averaging needs at least 2.")
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


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("out", type=Path, help="the averaged checkpoint to write")
    parser.add_argument("inputs", type=Path, nargs="+", help="checkpoints of one run")
    args = parser.parse_args(argv)
    try:
        path = average_checkpoints(args.out, args.inputs)
    except InputError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(f"{path}: the mean of {len(args.inputs)} checkpoints' weights")
    return 0


if __name__ == "__main__":
    sys.exit(main())
