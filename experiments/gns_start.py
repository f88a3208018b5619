"""Does a GNS start, and does it keep going? A one-minute look at the two ways a model fails.

For a few validation scenes, the mean displacement (m) of the soil after F frames: the MPM's,
the model's rolled out from rest (as every user's scene starts), and the model's rolled out
from simulated frames S, S + K, ... (the public GNS's start, the flow already under way)
against the MPM's displacement over the same frames. A model that does not start shows ~0 from
rest; one that has not learned the flow shows a wrong displacement from simulated frames.

    .venv/bin/python experiments/gns_start.py --model runs/recipe5/x-noise0.03-exact-pf2/checkpoint.pt
    .venv/bin/python experiments/gns_start.py --model M --data data/ft8 --scenes 4,13 --frames 100 --starts 5,20

This is a look, not a verdict: pilots are judged by experiments/train_pilots.py (16 scenes from rest,
all frames, against the MPM and standing still).
"""

from __future__ import annotations

import argparse
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch


def mean_displacement(traj, first: int, last: int) -> float:
    """Mean distance (m) the soil points of `traj` moved from frame `first` to frame `last`."""
    moved = traj.positions[last, traj.soil].astype(float) - traj.positions[first, traj.soil]
    return float(np.linalg.norm(moved, axis=-1).mean())


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--model", type=Path, required=True)
    ap.add_argument("--data", type=Path, default=Path("data/ft8"))
    ap.add_argument("--scenes", default="4,13", help="indices into the valid split")
    ap.add_argument("--frames", type=int, default=100, help="F: frames after the start of the simulation")
    ap.add_argument("--starts", default="5,20", help="S: simulated frames the second kind of rollout starts from")
    ap.add_argument("--threads", type=int, default=1)
    args = ap.parse_args()
    torch.set_num_threads(args.threads)

    from runout.dataset import split_trajectories
    from runout.gns.checkpoint import load_simulator
    from runout.gns.rollout import rollout_trajectory

    simulator = load_simulator(args.model)
    stride = simulator.frame_stride
    wanted = [int(k) for k in args.scenes.split(",")]
    truths = list(split_trajectories(args.data, "valid", max(wanted) + 1))
    last = args.frames
    print(f"# {args.model}: mean soil displacement (m) over frames 0-{last} and from frame S to {last}")
    for k in wanted:
        truth = truths[k]
        if truth.n_frames <= last:
            raise SystemExit(f"{args.data}: valid scene {k} has {truth.n_frames} frames; --frames must be below that")
        row = [f"valid_{k}: MPM {mean_displacement(truth, 0, last):.2f}"]
        rest = rollout_trajectory(simulator, truth, last + 1, stop_speed=None)
        row.append(f"GNS from rest {mean_displacement(rest, 0, -1):.2f}")
        for start in (int(s) for s in args.starts.split(",")):
            span = (last - start) // stride * stride  # whole model steps
            later = replace(truth, positions=truth.positions[start:])
            rolled = rollout_trajectory(simulator, later, span + 1, stop_speed=None, from_rest=False)
            row.append(f"from frame {start}: MPM {mean_displacement(truth, start, start + span):.2f}, "
                       f"GNS {mean_displacement(rolled, 0, -1):.2f}")
        print(" | ".join(row), flush=True)


if __name__ == "__main__":
    main()
