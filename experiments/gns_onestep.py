"""Where in time does a GNS fail? One-step predictions on the MPM's own windows, frame by frame.

A rollout from rest compounds every step's error, so it cannot say which step is wrong. This
feeds the model the *true* window ending at frame t - 1 (frames before 0 are frame 0: the
scene at rest, as training's exact-rest windows and every user's rollout begin) and compares
its normalised acceleration for frame t with the MPM's, over the soil points of the first
--scenes scenes of a split:

    rms      root mean square of the true and the predicted normalised acceleration
    slope    least-squares slope of prediction against truth through 0 (1: right size;
             0.1: a tenth of it)
    corr     correlation of prediction and truth over points and both components
    mse      the model's squared error (the training loss's measure) beside a zero prediction's

A model can be right from frame 5 on and still roll out far too slowly, if it misses the
first accelerations from rest (docs/training.md, round 8). Seconds per model for 16 scenes.

    .venv/bin/python experiments/gns_onestep.py models/pilots/A.pt --data data/ft8 --split valid
    .venv/bin/python experiments/gns_onestep.py A.pt B.pt --frames 1,2,3,5,10,20,40,80 --last-step
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import torch


def onestep_rows(simulator, truths, frames: list[int]) -> list[dict]:
    """One row per target frame: rms of truth and prediction, slope, correlation, mse (module docstring)."""
    from runout.gns.rollout import material_tensor
    from runout.gns.features import Constraints

    history, stride = simulator.schema.history, simulator.frame_stride
    pairs = {t: ([], []) for t in frames}
    for truth in truths:
        pos = truth.positions[::stride].astype(np.float32)  # model steps
        padded = np.concatenate([np.repeat(pos[:1], history - 1, axis=0), pos])  # at rest before step 0
        ptype = torch.from_numpy(truth.particle_type)
        material = material_tensor(simulator, truth).float()
        constraints = Constraints.of(ptype, torch.as_tensor(truth.bounds, dtype=torch.float32))
        soil = constraints.movable.numpy()
        for t in frames:
            if t >= len(pos):
                continue
            window = torch.from_numpy(np.ascontiguousarray(padded[t - 1: t - 1 + history].transpose(1, 0, 2)))
            with torch.no_grad():
                predicted = simulator(window, ptype, material, constraints.bounds).float().numpy()
            last, before = padded[t + history - 2], padded[t + history - 3]
            target = simulator.normalise_acceleration(torch.from_numpy(pos[t] - 2 * last + before)).numpy()
            pairs[t][0].append(predicted[soil])
            pairs[t][1].append(target[soil])
    rows = []
    for t in frames:
        if not pairs[t][0]:
            continue
        p, q = np.concatenate(pairs[t][0]), np.concatenate(pairs[t][1])
        rows.append({
            "frame": t * stride,
            "rms_true": float(np.sqrt((q**2).mean())),
            "rms_pred": float(np.sqrt((p**2).mean())),
            "slope": float((p * q).sum() / max((q * q).sum(), 1e-30)),
            "corr": float(np.corrcoef(p.ravel(), q.ravel())[0, 1]) if p.std() > 0 else 0.0,
            "mse": float(((p - q) ** 2).sum(1).mean()),
            "mse_zero": float((q**2).sum(1).mean()),
        })
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("models", type=Path, nargs="+")
    ap.add_argument("--data", type=Path, default=Path("data/ft8"))
    ap.add_argument("--split", default="valid")
    ap.add_argument("--scenes", type=int, default=16, help="the first SCENES scenes of the split")
    ap.add_argument("--frames", default="1,2,3,5,10,20,40,80",
                    help="target frames (dataset frames; a model of frame stride K takes multiples of K)")
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--last-step", action="store_true",
                    help="also each checkpoint's last-step weights (train_model of --ema runs)")
    args = ap.parse_args()
    torch.set_num_threads(args.threads)

    from runout.dataset import split_trajectories
    from runout.gns.checkpoint import load_last_step, load_simulator

    truths = list(split_trajectories(args.data, args.split, args.scenes))
    models = [(str(path), load_simulator(path)) for path in args.models]
    if args.last_step:
        models += [(f"{path} (last step's weights)", s) for path in args.models if (s := load_last_step(path)) is not None]
    print(f"# one-step predictions on the MPM's windows, {len(truths)} {args.split} scenes of {args.data}, "
          "normalised accelerations of the soil points")
    for name, simulator in models:
        simulator.eval()
        steps = sorted({max(1, int(f) // simulator.frame_stride) for f in args.frames.split(",")})
        print(f"# {name}")
        print("| target frame | rms true | rms predicted | slope | corr | mse | zero-prediction mse |")
        print("|---|---|---|---|---|---|---|")
        for r in onestep_rows(simulator, truths, steps):
            print(f"| {r['frame']} | {r['rms_true']:.2f} | {r['rms_pred']:.2f} | {r['slope']:.2f} | {r['corr']:.2f} "
                  f"| {r['mse']:.2f} | {r['mse_zero']:.2f} |", flush=True)


if __name__ == "__main__":
    main()
