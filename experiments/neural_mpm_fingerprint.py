"""Does a change leave neural-MPM training unchanged, bit for bit? Prints with full precision:

1. every loss logged while a copy of a run folder (one made by the code before the change, such
   as runs/nmpm-p3-k3) resumes for N more steps with its stored settings (`steps` moved on to
   its step + N; no validation, a log line per step), and a checksum of its final weights;
2. the same of a new tiny engine trained 2 N steps on the run's data.

Both go through runout.neural_mpm.training.train(settings, config, resume), which the code
before and after issue 53 share. Run it under each and diff the outputs:

    PYTHONPATH=src .venv/bin/python experiments/neural_mpm_fingerprint.py --run runs/nmpm-p3-k3 --work /tmp/nfp > after.txt
"""

from __future__ import annotations

import argparse
import hashlib
import json
import shutil
from dataclasses import fields
from pathlib import Path

import torch

from runout.neural_mpm.engine import NeuralMPMConfig
from runout.neural_mpm.training import CHECKPOINT, LOG, TrainSettings, train

QUIET = dict(valid_every=0, log_every=1, progress=False, max_hours=None, max_cpu_hours=None, threads=1)
TINY = NeuralMPMConfig(cell_size=8.0, point_spacing=4.0, history=2, frames_per_call=4, widths=(8, 16))


def fingerprint(engine, out: Path, since: int) -> list[str]:
    rows = [json.loads(line) for line in (out / LOG).read_text().splitlines()]
    losses = [(r["step"], r["loss"], r["lr"]) for r in rows if r["event"] == "loss" and r["step"] > since]
    digest = hashlib.sha256(b"".join(t.detach().cpu().numpy().tobytes() for t in engine.state_dict().values()))
    return [f"{out.name} step {step} loss {loss!r} lr {lr!r}" for step, loss, lr in losses] + [
        f"{out.name} weights sha256 {digest.hexdigest()}"]


def resumed_run(run: Path, work: Path, more: int, data: str | None) -> list[str]:
    out = work / run.name
    shutil.rmtree(out, ignore_errors=True)
    out.mkdir(parents=True)
    shutil.copyfile(run / CHECKPOINT, out / CHECKPOINT)
    state = torch.load(out / CHECKPOINT, weights_only=True, map_location="cpu")
    known = {f.name for f in fields(TrainSettings)}
    stored = {k: v for k, v in state["train"].items() if k in known}
    stored.update(QUIET, out=str(out), steps=state["step"] + more, **({"data": data} if data else {}))
    return fingerprint(train(TrainSettings(**stored), resume=True), out, state["step"])


def tiny_run(data: str, work: Path, steps: int) -> list[str]:
    out = work / "tiny"
    shutil.rmtree(out, ignore_errors=True)
    settings = TrainSettings(data=data, out=str(out), batch_size=2, steps=steps, save_every=steps, **QUIET)
    return fingerprint(train(settings, TINY), out, 0)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--run", type=Path, required=True, help="a neural-MPM run folder (its checkpoint.pt is copied)")
    ap.add_argument("--data", help="the dataset(s) of the run, if not where its settings say")
    ap.add_argument("--steps", type=int, default=20, help="N: steps resumed (the tiny run takes 2 N)")
    ap.add_argument("--work", type=Path, required=True, help="a scratch folder")
    args = ap.parse_args()
    torch.set_num_threads(1)
    lines = resumed_run(args.run, args.work, args.steps, args.data)
    state = torch.load(args.run / CHECKPOINT, weights_only=True, map_location="cpu")
    lines += tiny_run(args.data or state["train"]["data"], args.work, 2 * args.steps)
    print("\n".join(lines))


if __name__ == "__main__":
    main()
