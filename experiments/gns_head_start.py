"""How much of a model's rollout error is its start? Held-out scenes scored as the pilots are,
but with the first S frames given by the MPM.

For each S in --heads, every scene's prediction is the MPM's frames 0..S followed by the model's
rollout from the MPM's window ending at frame S (the public GNS's start from simulated frames),
scored over all frames against the MPM with runout.evaluate.heldout.score (position error,
fronts, extent runout). S = 0 is the start from rest that users get. If a head start of a few
frames brings the position error near the target, the start is what the model misses; if not,
the flow after it is wrong too.

    OMP_NUM_THREADS=1 .venv/bin/python experiments/gns_head_start.py MODEL --heads 0,5,20 --valid 16

Frames before S count in the score (they are the MPM's, error 0), as they would for a model
that got them right.
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("model", type=Path)
    ap.add_argument("--data", type=Path, default=Path("data/ft8"))
    ap.add_argument("--heads", default="0,5,20", help="S: frames the MPM gives before the model takes over")
    ap.add_argument("--valid", type=int, default=16, help="scenes of the valid split")
    ap.add_argument("--last-step", action="store_true", help="the last-step weights instead of the average")
    ap.add_argument("--threads", type=int, default=1)
    args = ap.parse_args()
    torch.set_num_threads(args.threads)

    from runout.dataset import split_trajectories
    from runout.errors import InputError
    from runout.evaluate.heldout import score, standing_still
    from runout.gns.checkpoint import load_last_step, load_simulator
    from runout.gns.rollout import rollout_trajectory

    try:
        simulator = (load_last_step if args.last_step else load_simulator)(args.model)
        truths = list(split_trajectories(args.data, "valid", args.valid))
    except InputError as e:
        print(e, file=sys.stderr)
        raise SystemExit(2)
    stride, history = simulator.frame_stride, simulator.schema.history
    heads = [int(s) for s in args.heads.split(",")]
    for head in heads:
        if head and (head < (history - 1) * stride or head % stride):
            print(f"--heads: {head} must be 0 or a multiple of the frame stride {stride}, at least "
                  f"{(history - 1) * stride} (the model's window)", file=sys.stderr)
            raise SystemExit(2)
    spacing = simulator.point_spacing
    print(f"# {args.model}{' (last step)' if args.last_step else ''}: {len(truths)} valid scenes of {args.data}")
    print("| MPM frames given | position error (m) | front error | extent runout error | mean displacement (m) |")
    print("|---|---|---|---|---|")
    still = score([standing_still(t) for t in truths], truths, spacing)
    for head in heads:
        predicted = []
        for truth in truths:
            if head == 0:
                predicted.append(rollout_trajectory(simulator, truth, truth.n_frames, stop_speed=None))
                continue
            first = head - (history - 1) * stride  # the window's first frame
            later = replace(truth, positions=truth.positions[first:])
            rolled = rollout_trajectory(simulator, later, truth.n_frames - first, stop_speed=None, from_rest=False)
            frames = np.concatenate([truth.positions[:first:stride], rolled.positions])  # rolled: frames first, first + K, ...
            predicted.append(replace(rolled, positions=frames))
        s = score(predicted, truths, spacing)
        print(f"| {head} | {s['position_error_m']:.2f} | {100 * s['front_error']:.1f} % | {100 * s['runout_error']:.1f} % "
              f"| {s['displacement_m']:.1f} (MPM {s['displacement_mpm_m']:.1f}) |", flush=True)
    print(f"| standing still | {still['position_error_m']:.2f} | {100 * still['front_error']:.1f} % "
          f"| {100 * still['runout_error']:.1f} % | 0 |")


if __name__ == "__main__":
    main()
