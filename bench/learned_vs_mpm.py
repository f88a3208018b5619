"""A learned engine against the MPM it learned, whole commands side by side, on the paper's
four-layer slope (issue 57 item 6: the neural MPM's rollout must be at least 5x faster than
our MPM of the same scene on the same CPU).

Two comparisons, each of `runout mpm SCENE --no-animate` (Warp kernels, float64) against
`runout rollout --model MODEL SCENE --no-animation --stop-speed 0` (any learned engine: the
file says which):

- equal_points: the scene refilled at the model's point spacing (written to a file first),
  `--frames` frames, so both commands run the same points;
- as_written: the scene file unchanged, so the MPM runs its own cells and points per cell
  and the learned engine refills it at its own spacing, both over the scene's frames.

Every command runs in a fresh process, the two cases and the two engines alternating,
`--repeats` times each (medians reported). Wall seconds of the whole command include Python's
start-up, the imports and the files written; each engine's own seconds inside it are what the
command records: the MPM's frame loop (metadata.json info.wall_time_s; its geostatic
relaxation and Warp's start-up come before) and the learned engine's rollout
(metrics.json wall_s). Take it on a quiet machine (no training beside it) and write the
figures to docs/benchmarks.md with the machine and the command:

    OMP_NUM_THREADS=2 .venv/bin/python bench/learned_vs_mpm.py --model models/neural-mpm.pt [--frames 400] [--repeats 3]
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
RUNOUT = [sys.executable, "-m", "runout"]


def timed(argv: list[str], env: dict) -> float:
    t0 = time.perf_counter()
    subprocess.run(argv, check=True, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    return time.perf_counter() - t0


def run_mpm(scene: Path, out: Path, env: dict) -> dict:
    wall = timed([*RUNOUT, "mpm", str(scene), "--out", str(out), "--no-animate"], env)
    meta = json.loads((out / "metadata.json").read_text())
    return {"wall_s": wall, "engine_s": meta["info"]["wall_time_s"], "frames": meta["sequence_length"]}


def run_rollout(model: Path, scene: Path, out: Path, env: dict) -> dict:
    wall = timed([*RUNOUT, "rollout", "--model", str(model), str(scene), "--out", str(out), "--no-animation",
                  "--stop-speed", "0"], env)
    metrics = json.loads((out / "metrics.json").read_text())
    return {"wall_s": wall, "engine_s": metrics["wall_s"], "frames": metrics["frames"]}


def points(out: Path) -> int:
    from runout.trajectory import load_trajectory

    return load_trajectory(out).n_points


def summary(runs: dict[str, list[dict]], engine: str, scene_cells: dict, n_points: dict) -> dict:
    median = {name: {key: statistics.median(r[key] for r in rs) for key in ("wall_s", "engine_s")}
              for name, rs in runs.items()}
    return {
        "cell_size_m": scene_cells, "points": n_points, "frames": {name: rs[0]["frames"] for name, rs in runs.items()},
        "runs": runs, "median": median,
        "mpm_over_engine_whole_command": median["mpm"]["wall_s"] / median[engine]["wall_s"],
        "mpm_over_engine_own_seconds": median["mpm"]["engine_s"] / median[engine]["engine_s"],
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--model", type=Path, required=True)
    ap.add_argument("--scene", type=Path, default=ROOT / "examples" / "four_layer_slope.toml")
    ap.add_argument("--frames", type=int, default=400, help="frames of the equal_points case (as_written: the scene's)")
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args()

    from runout.learned.load import load_engine
    from runout.learned.scenes import at_model_spacing
    from runout.scene import load_scene, save_scene

    engine = load_engine(args.model)
    written = load_scene(args.scene)
    env = {**os.environ, "PYTHONWARNINGS": "ignore"}
    load_before = os.getloadavg()[0]
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        refilled = at_model_spacing(written, engine).with_frames(args.frames)
        save_scene(refilled, tmp / "equal_points.toml")
        cases = {"equal_points": (tmp / "equal_points.toml", refilled.domain.cell_size), "as_written": (args.scene, None)}
        runs = {case: {"mpm": [], engine.name: []} for case in cases}
        for k in range(args.repeats):
            for case, (scene, _) in cases.items():
                runs[case]["mpm"].append(run_mpm(scene, tmp / f"{case}_mpm{k}", env))
                runs[case][engine.name].append(run_rollout(args.model, scene, tmp / f"{case}_rollout{k}", env))
        results = {}
        for case, (_, engine_cells) in cases.items():
            cells = {"mpm": load_scene(cases[case][0]).domain.cell_size,
                     engine.name: engine_cells or at_model_spacing(written, engine).domain.cell_size}
            n_points = {"mpm": points(tmp / f"{case}_mpm0"), engine.name: points(tmp / f"{case}_rollout0")}
            results[case] = summary(runs[case], engine.name, cells, n_points)
    print(json.dumps({"scene": args.scene.name, "model": str(args.model), "engine": engine.name,
                      "threads": os.environ.get("OMP_NUM_THREADS"), "repeats": args.repeats,
                      "load_average": [load_before, os.getloadavg()[0]], **results}, indent=1))


if __name__ == "__main__":
    main()
