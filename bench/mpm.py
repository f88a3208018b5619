"""MPM throughput: particle-substeps per second and seconds per run.

A column collapse of about 6,000 points (150 x 160 m column, 4 m cells, 2 x 2 points per
cell) run alone and in batches of 8 and 64 scenes (friction angle varied across the batch).
Frames can be cut for a quick figure: throughput is per substep, and the printed "s per
500-frame run" extrapolates from it (relaxation substeps included in the count).

    python bench/mpm.py                       # CPU, batches 1, 8, 64, 30 frames
    python bench/mpm.py --device cuda --frames 500
    python bench/mpm.py --batches 1,8 --backends torch,warp   # the Warp kernels beside the torch solver
    python bench/mpm.py --batches 1 --frames 500 --backends torch --compile

The Warp kernels (runout.mpm.kernels, what every command runs) are float64 only; their compile (or
cache load) is done before the timed run, as torch.compile's is. Warp runs each CPU launch on one
thread; a batch's scenes run in up to --threads groups side by side (kernels.WarpSubstep), so a
batch of one scene uses one core whatever --threads says. --float32 and --compile apply to the torch solver (the tests' oracle).

Reference: the paper's MPM data took ~50 minutes per run on a 56-core node.
"""

from __future__ import annotations

import argparse
import os
import platform
import time

import torch

from runout.mpm import simulate
from runout.scene import scene_from_dict

REFERENCE_S_PER_RUN = 50 * 60  # paper: ~50 min per simulation on 56 cores


def column_scene(phi: float, frames: int):
    return scene_from_dict(
        {
            "name": f"column_phi{phi:g}",
            "domain": {"width": 600.0, "height": 200.0},
            "time": {"frames": frames},
            "materials": {"soil": {"friction_angle": phi, "cohesion": 10.0}},
            "regions": [{"material": "soil", "polygon": [[0, 0], [150, 0], [150, 160], [0, 160]]}],
        }
    )


def measure(batch: int, frames: int, device: str, dtype, compile: bool, backend: str = "warp") -> dict:
    scenes = [column_scene(20.0 + 20.0 * k / max(batch - 1, 1), frames) for k in range(batch)]
    if compile or backend == "warp":  # compile once (dynamic shapes) or load the kernels outside the timed run
        simulate(scenes[:1], device=device, progress=False, dtype=dtype, compile=compile, frames=2, backend=backend)
    if device == "cuda":
        torch.cuda.synchronize()
    start = time.perf_counter()
    trajs = simulate(scenes, device=device, progress=False, dtype=dtype, compile=compile, backend=backend)
    if device == "cuda":
        torch.cuda.synchronize()
    wall = time.perf_counter() - start
    info = trajs[0].info
    points = sum(t.n_points for t in trajs)
    substeps = info["relaxation_substeps"] + info["substeps_per_frame"] * (frames - 1)
    rate = points * substeps / wall
    full = info["relaxation_substeps"] + info["substeps_per_frame"] * 499
    return {
        "backend": backend, "batch": batch, "points_per_scene": trajs[0].n_points, "substeps": substeps, "wall_s": wall,
        "rate": rate, "s_per_500_frame_run": full * trajs[0].n_points / rate,
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--frames", type=int, default=30)
    ap.add_argument("--batches", default="1,8,64")
    ap.add_argument("--threads", type=int, default=None, help="torch CPU threads (default: torch's choice)")
    ap.add_argument("--float32", action="store_true")
    ap.add_argument("--compile", action="store_true")
    ap.add_argument("--backends", default="warp", help="comma-separated: warp (kernels.py), torch (solver.py)")
    args = ap.parse_args()
    if args.threads:
        torch.set_num_threads(args.threads)
    dtype = torch.float32 if args.float32 else torch.float64
    backends = args.backends.split(",")
    print(f"# {platform.processor() or platform.machine()}, torch {torch.__version__}, device {args.device}, "
          f"threads {torch.get_num_threads()}, {dtype}, compile={args.compile}, frames={args.frames}, "
          f"load average {os.getloadavg()[0]:.2f} on {os.cpu_count()} cores")
    print("backend  batch  points/scene  substeps  wall s  particle-substeps/s  s per 500-frame run  vs paper (50 min)")
    for b in (int(x) for x in args.batches.split(",")):
        for backend in backends:
            torch_only = backend == "torch"
            r = measure(b, args.frames, args.device, dtype if torch_only else torch.float64, args.compile and torch_only,
                        backend)
            print(f"{r['backend']:>7}  {r['batch']:5d}  {r['points_per_scene']:12d}  {r['substeps']:8d}  "
                  f"{r['wall_s']:6.1f}  {r['rate']:19.3e}  {r['s_per_500_frame_run']:19.1f}  "
                  f"{REFERENCE_S_PER_RUN / r['s_per_500_frame_run']:8.0f}x", flush=True)


if __name__ == "__main__":
    main()
