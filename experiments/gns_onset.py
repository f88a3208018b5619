"""Does a GNS tell scenes apart? A few-minute look at the onset of motion across many scenes.

Every model of the recipe pilots so far moved about the same in every scene, whatever its
strengths and shape. This rolls each model out from rest (as every user's scene starts) on the
first --valid validation scenes for --frames frames and prints, at a few frames, the mean soil
displacement (m) of the model beside the MPM's, the correlation across scenes, and the spread: the slope of the least-squares line of the
model's displacements against the MPM's (1: the right differences between scenes; near 0: one
motion for all, whatever its mean).

    .venv/bin/python experiments/gns_onset.py runs/recipe8/x-noise0.01-exact-pf2-onset0.25/checkpoint.pt
    .venv/bin/python experiments/gns_onset.py A.pt B.pt --data data/ft8 --valid 16 --at 20,60,120

A look, not a verdict: pilots are judged by experiments/train_pilots.py (16 scenes from rest, all
frames, against the MPM and standing still). About 2-3 minutes per model on one core for 16
scenes of 120 frames at 8 m cells.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import torch


def displacement(positions: np.ndarray, frame: int, soil: np.ndarray) -> float:
    """Mean distance (m) the soil points moved from frame 0 to `frame`."""
    moved = positions[frame, soil].astype(float) - positions[0, soil]
    return float(np.linalg.norm(moved, axis=-1).mean())


def spread(model: np.ndarray, truth: np.ndarray) -> tuple[float, float]:
    """(correlation, least-squares slope) of the model's displacements against the MPM's."""
    if truth.std() == 0:
        return float("nan"), float("nan")
    corr = float(np.corrcoef(model, truth)[0, 1]) if model.std() > 0 else 0.0
    slope = float(np.cov(model, truth, bias=True)[0, 1] / truth.var())
    return corr, slope


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("models", type=Path, nargs="+")
    ap.add_argument("--data", type=Path, default=Path("data/ft8"))
    ap.add_argument("--valid", type=int, default=16, help="validation scenes (the first ones)")
    ap.add_argument("--at", default="20,60,120", help="frames at which displacements are compared (multiples of the stride)")
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--last-step", action="store_true",
                    help="also roll out each checkpoint's last-step weights (train_model) beside its weight average (--ema runs)")
    args = ap.parse_args()
    torch.set_num_threads(args.threads)

    from runout.dataset import split_trajectories
    from runout.gns.checkpoint import load_last_step, load_simulator
    from runout.gns.rollout import rollout_trajectory

    at = sorted(int(f) for f in args.at.split(","))
    truths = list(split_trajectories(args.data, "valid", args.valid))
    if any(t.n_frames <= at[-1] for t in truths):
        raise SystemExit(f"{args.data}: a valid scene has {min(t.n_frames for t in truths)} frames; --at must stay below that")
    mpm = np.array([[displacement(t.positions, f, t.soil) for f in at] for t in truths])
    print(f"# {len(truths)} valid scenes of {args.data}, from rest; mean soil displacement (m) at frames {at}")
    print("MPM " + " | ".join(f"frame {f}: {np.round(mpm[:, j], 2).tolist()}" for j, f in enumerate(at)))
    models = [(str(path), load_simulator(path)) for path in args.models]
    if args.last_step:
        last = [(f"{path} (last step's weights)", load_last_step(path)) for path in args.models]
        models += [(name, simulator) for name, simulator in last if simulator is not None]
    for name, simulator in models:
        gns = np.array([[displacement(r.positions, f // simulator.frame_stride, t.soil) for f in at]
                        for t in truths
                        for r in [rollout_trajectory(simulator, t, at[-1] + 1, stop_speed=None)]])
        print(f"# {name}")
        for j, f in enumerate(at):
            corr, slope = spread(gns[:, j], mpm[:, j])
            print(f"  frame {f}: mean {gns[:, j].mean():.2f} m (MPM {mpm[:, j].mean():.2f}), correlation {corr:.2f}, "
                  f"spread {slope:.2f}; per scene {np.round(gns[:, j], 2).tolist()}", flush=True)


if __name__ == "__main__":
    main()
