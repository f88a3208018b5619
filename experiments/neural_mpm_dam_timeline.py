"""When does a learned engine's dam fall behind the MPM's? Mean displacement and the right front,
frame by frame.

A dam back-calculated through a learned engine answers a weaker soil when the engine's dam moves
too little at the true strengths. This reads one MPM run of a scene (a folder with
trajectory.npz and metadata.json, e.g. the MPM cache's run of `examples/dam.toml`) and the
engines' rollouts of the same scene from rest (`runout rollout --model FILE MPM_FOLDER --out
DIR --stop-speed 0`), checks that they hold the same points, and draws the soil's mean
displacement (m) and its right front (largest soil x, m) against frame, the MPM beside each
rollout, so a slow start and a short outflow look different. It prints both at a few frames and
the front's travel short of the MPM's (share of the MPM's travel). Nothing is run.

    PYTHONPATH=src .venv/bin/python experiments/neural_mpm_dam_timeline.py /root/.cache/runout/mpm/c0c9d87076730775c601 \
        runs/dam-truth-p28 runs/dam-truth-c130000 --out docs/figures/nmpm_dam_timeline.png
"""

from __future__ import annotations

import argparse
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from runout.trajectory import load_trajectory  # noqa: E402


def timeline(folder: Path) -> tuple[np.ndarray, np.ndarray]:
    """Mean soil displacement from frame 0 (m) and largest soil x (m), per frame."""
    traj = load_trajectory(folder)
    x = traj.positions[:, traj.soil].astype(float)
    displacement = np.linalg.norm(x - x[0], axis=2).mean(axis=1)
    return displacement, x[:, :, 0].max(axis=1)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("mpm", type=Path, help="the MPM's run of the scene (folder with trajectory.npz)")
    p.add_argument("rollouts", nargs="+", type=Path, help="learned engines' rollouts of the same scene from rest")
    p.add_argument("--frames", default="40,80,160,240,320,399", help="frames to print (comma-separated)")
    p.add_argument("--out", type=Path, required=True, help="PNG to write")
    args = p.parse_args()
    frames = [int(f) for f in args.frames.split(",")]
    mpm_disp, mpm_front = timeline(args.mpm)
    travel = mpm_front[-1] - mpm_front[0]
    print("frame           " + " ".join(f"{f:>7d}" for f in frames))
    print(f"{'MPM':<16}" + " ".join(f"{mpm_disp[f]:7.2f}" for f in frames) + f"   front {mpm_front[-1]:.1f} m")
    fig, (ax_d, ax_f) = plt.subplots(1, 2, figsize=(11, 4.2))
    ax_d.plot(mpm_disp, "k-", lw=2, label="MPM")
    ax_f.plot(mpm_front, "k-", lw=2, label="MPM")
    for k, folder in enumerate(args.rollouts):
        disp, front = timeline(folder)
        if len(disp) != len(mpm_disp):
            raise SystemExit(f"{folder}: {len(disp)} frames, the MPM's run {len(mpm_disp)}; roll out with --stop-speed 0.")
        short = 100 * (mpm_front[-1] - front[-1]) / travel
        print(f"{folder.name:<16}" + " ".join(f"{disp[f]:7.2f}" for f in frames)
              + f"   front {front[-1]:.1f} m ({short:.0f} % of the MPM's {travel:.1f} m of travel short)")
        ax_d.plot(disp, color=f"C{k}", label=folder.name)
        ax_f.plot(front, color=f"C{k}", label=folder.name)
    ax_d.set_ylabel("mean displacement of the soil (m)")
    ax_f.set_ylabel("right front, largest soil x (m)")
    for ax in (ax_d, ax_f):
        ax.set_xlabel("frame")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    fig.suptitle(f"{args.mpm.name}: learned engines from rest against the MPM")
    fig.tight_layout()
    args.out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(args.out, dpi=110)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
