"""Choose among a run's checkpoints by rollouts from rest on scenes that are not the judged ones.

A GNS rolled out from rest swings from checkpoint to checkpoint (docs/training.md, round 6),
so the last checkpoint is not always the best. This script rolls each given checkpoint (the
snapshots `runout train --keep-every N` keeps, or any checkpoint files) out from rest over all
frames of a range of the validation scenes, scores it against the MPM and against standing
still (runout.evaluate.heldout, the measures of experiments/train_pilots.py), and names the one with
the lowest mean position error. The judged scenes (the first 16, experiments/train_pilots.py
--valid 16) are left out by default: selecting on them would make their score optimistic.

    python experiments/select_checkpoint.py --data data/ft8 --scenes 16:26 \\
        --checkpoints runs/recipe10/NAME/snapshots/*.pt runs/recipe10/NAME/checkpoint.pt --threads 1

--last-step also rolls out each checkpoint's last-step weights (train_model of an --ema run).
Units: m; front errors as a share of the MPM's front travel.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path


def parse_range(text: str) -> tuple[int, int]:
    first, _, end = text.partition(":")
    return int(first), int(end)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", type=Path, required=True)
    ap.add_argument("--checkpoints", type=Path, nargs="+", required=True)
    ap.add_argument("--scenes", type=parse_range, default=(16, 26),
                    help="validation scenes FIRST:END rolled out (default 16:26, the ones train_pilots does not judge)")
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--last-step", action="store_true", help="also the last-step weights of --ema checkpoints")
    ap.add_argument("--json", type=Path, default=None, help="write the rows here")
    args = ap.parse_args()

    import torch

    from runout.dataset import split_trajectories
    from runout.evaluate.heldout import rollout_all, score, standing_still
    from runout.gns.checkpoint import load_last_step, load_simulator, read_checkpoint
    from runout.gns.engine import GnsEngine

    torch.set_num_threads(args.threads)
    first, end = args.scenes
    truths = list(split_trajectories(args.data, "valid", end))[first:end]
    if not truths:
        raise SystemExit(f"--scenes {first}:{end}: the validation split has no scenes there")
    rows = []
    for path in args.checkpoints:
        step = int(read_checkpoint(path)["step"])
        models = [("average" if load_last_step(path) is not None else "model", load_simulator(path))]
        if args.last_step and (last := load_last_step(path)) is not None:
            models.append(("last step", last))
        for kind, simulator in models:
            if not rows:
                rows.append({"checkpoint": "standing still", "step": 0, "weights": "",
                             **score([standing_still(t) for t in truths], truths, simulator.point_spacing)})
            t0 = time.perf_counter()
            predicted = rollout_all(GnsEngine(simulator), truths)
            rows.append({"checkpoint": str(path), "step": step, "weights": kind,
                         **score(predicted, truths, simulator.point_spacing), "rollout_s": time.perf_counter() - t0})
            r = rows[-1]
            print(f"{path} step {step} {kind}: position {r['position_error_m']:.2f} m, front {100 * r['front_error']:.1f} %, "
                  f"displacement {r['displacement_m']:.1f} m (MPM {r['displacement_mpm_m']:.1f}), {r['rollout_s']:.0f} s", flush=True)
    print(f"\nvalidation scenes {first}-{end - 1}\n")
    print("| checkpoint | step | weights | position error (m) | front error / travel | extent runout error | mean displacement (MPM) m |")
    print("|---|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['checkpoint']} | {r['step']} | {r['weights']} | {r['position_error_m']:.2f} | {100 * r['front_error']:.1f} % | "
              f"{100 * r['runout_error']:.1f} % | {r['displacement_m']:.1f} ({r['displacement_mpm_m']:.1f}) |")
    best = min(rows[1:], key=lambda r: r["position_error_m"])
    print(f"\nlowest position error: {best['checkpoint']} ({best['weights']}, step {best['step']}): {best['position_error_m']:.2f} m")
    if args.json:
        args.json.write_text(json.dumps([{k: v for k, v in r.items() if k != "per_scene"} for r in rows], indent=1))


if __name__ == "__main__":
    main()
