"""GNS rollout against the MPM on the paper's four-layer slope, at the model's point spacing.

Issue 25, item 4: the same scene (examples/four_layer_slope.toml filled at the model's own
point spacing), the same frames, the same CPU. Times, in wall seconds:

- the MPM (Warp kernels, float64, a fresh run: the cache is not read);
- the GNS rollout from rest, every frame (no early stop), as `runout compare` runs it:
  eager float32 (what every command runs), the network through torch.compile (the first,
  compiling rollout is timed apart from a second one), bf16 autocast, and several copies of
  the scene in one graph batch per call (runout.gns.rollout.rollout_trajectories), per scene;
- how far each variant's deposit lies from the eager one's (mean point distance at the last
  frame, m), so that a faster variant that changes the answer is seen.

A model of frame stride K makes 1/K of the steps for the same 18 s; its stride is printed.
Take it on a quiet machine (no training beside it) and write the figures to
docs/benchmarks.md with the machine and the command:

    OMP_NUM_THREADS=2 .venv/bin/python bench/gns_slope_speed.py --model models/slope.pt [--frames 480] [--batch 4] [--compile] [--bf16]
"""

from __future__ import annotations

import argparse
import json
import time
from contextlib import nullcontext
from pathlib import Path

import numpy as np
import torch

from runout.gns.checkpoint import load_simulator
from runout.gns.rollout import rollout_trajectories, rollout_trajectory
from runout.learned.scenes import at_model_spacing, scene_at_rest
from runout.mpm import simulate
from runout.scene import load_scene

ROOT = Path(__file__).resolve().parents[1]


def timed(run):
    t0 = time.perf_counter()
    out = run()
    return out, time.perf_counter() - t0


def spread(a, b) -> float:
    """Mean distance (m) between the soil points of two trajectories at their last frame."""
    n = min(a.n_frames, b.n_frames)
    soil = a.soil
    return float(np.linalg.norm(a.positions[n - 1, soil] - b.positions[n - 1, soil], axis=1).mean())


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--model", type=Path, default=ROOT / "models" / "slope.pt")
    parser.add_argument("--scene", type=Path, default=ROOT / "examples" / "four_layer_slope.toml")
    parser.add_argument("--frames", type=int, default=480, help="dataset frames (0.0375 s apart), frame 0 included")
    parser.add_argument("--batch", type=int, default=0, help="also roll out this many copies of the scene in one call")
    parser.add_argument("--compile", action="store_true", help="also time the network through torch.compile")
    parser.add_argument("--bf16", action="store_true", help="also time bf16 autocast")
    parser.add_argument("--json", type=Path, help="write the figures here too")
    args = parser.parse_args()

    simulator = load_simulator(args.model, "cpu")
    scene = at_model_spacing(load_scene(args.scene), simulator, args.scene.name, print).with_frames(args.frames)
    start = scene_at_rest(scene)
    result = {
        "model": str(args.model), "scene": str(args.scene), "frames": args.frames, "points": start.n_points,
        "soil_points": int(start.soil.sum()), "cell_size_m": scene.domain.cell_size,
        "frame_stride": simulator.frame_stride, "threads": torch.get_num_threads(),
        "cpu": next((line.split(":", 1)[1].strip() for line in open("/proc/cpuinfo") if line.startswith("model name")), "?"),
    }
    print(f"{result['points']} points ({result['soil_points']} soil) at {scene.domain.cell_size:g} m cells, "
          f"{args.frames} frames, model frame stride {simulator.frame_stride}, {result['threads']} threads")

    (mpm,), result["mpm_s"] = timed(lambda: simulate([scene], progress=False))
    print(f"MPM (Warp, fresh run): {result['mpm_s']:.1f} s")

    def gns(context=nullcontext):
        with context():
            return rollout_trajectory(simulator, start, args.frames, stop_speed=None)

    eager, result["gns_eager_s"] = timed(gns)
    steps = eager.n_frames - 1
    result["gns_steps"] = steps
    print(f"GNS eager float32: {result['gns_eager_s']:.1f} s ({1e3 * result['gns_eager_s'] / steps:.1f} ms per step, "
          f"{steps} steps); MPM / GNS = {result['mpm_s'] / result['gns_eager_s']:.2f}")

    if args.bf16:
        fast, result["gns_bf16_s"] = timed(lambda: gns(lambda: torch.autocast("cpu", dtype=torch.bfloat16)))
        result["gns_bf16_spread_m"] = spread(fast, eager)
        print(f"GNS bf16 autocast: {result['gns_bf16_s']:.1f} s; deposit {result['gns_bf16_spread_m']:.2f} m from eager's (mean)")

    if args.batch > 1:
        copies, wall = timed(lambda: rollout_trajectories(simulator, [start] * args.batch, args.frames, stop_speed=None))
        result["gns_batched"] = {"scenes": args.batch, "wall_s": wall, "per_scene_s": wall / args.batch,
                                 "spread_m": max(spread(c, eager) for c in copies)}
        print(f"GNS, {args.batch} copies in one call: {wall:.1f} s, {wall / args.batch:.1f} s per scene; "
              f"largest deposit difference from the single rollout {result['gns_batched']['spread_m']:.2e} m")

    if args.compile:
        simulator.network.compile(dynamic=True)
        _, result["gns_compiled_first_s"] = timed(gns)  # compiles
        compiled, result["gns_compiled_s"] = timed(gns)
        result["gns_compiled_spread_m"] = spread(compiled, eager)
        print(f"GNS torch.compile: {result['gns_compiled_s']:.1f} s (first run, compiling: "
              f"{result['gns_compiled_first_s']:.1f} s); deposit {result['gns_compiled_spread_m']:.2e} m from eager's")

    print(json.dumps(result, indent=2))
    if args.json:
        args.json.write_text(json.dumps(result, indent=2))


if __name__ == "__main__":
    main()
