"""A learned engine against the MPM it learned, whole commands side by side, on the paper's
four-layer slope (issue 57 item 6: the neural MPM's rollout must be at least 5x faster than
our MPM of the same scene on the same CPU).

Both commands are run fresh in one sitting, alternately, `--repeats` times each (the median is
reported): `runout mpm SCENE` (Warp kernels, float64) and `runout rollout --model MODEL SCENE`
(any learned engine: the file says which), each at the model's point spacing (the scene is
first written filled at it, so both run the same points), the same frames, no animation, no
early stop. Wall seconds of the whole command include Python's start-up and the imports. Take
it on a quiet machine (no training beside it) and write the figures to docs/benchmarks.md with
the machine and the command:

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


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--model", type=Path, required=True)
    ap.add_argument("--scene", type=Path, default=ROOT / "examples" / "four_layer_slope.toml")
    ap.add_argument("--frames", type=int, default=400)
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args()

    from runout.learned.load import load_engine
    from runout.learned.scenes import at_model_spacing
    from runout.scene import load_scene, save_scene

    engine = load_engine(args.model)
    env = {**os.environ, "PYTHONWARNINGS": "ignore"}
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        scene = at_model_spacing(load_scene(args.scene), engine).with_frames(args.frames)
        save_scene(scene, tmp / "scene.toml")
        times = {"mpm": [], engine.name: []}
        for k in range(args.repeats):
            times["mpm"].append(timed([*RUNOUT, "mpm", str(tmp / "scene.toml"), "--out", str(tmp / f"mpm{k}"),
                                       "--no-animate"], env))
            times[engine.name].append(timed([*RUNOUT, "rollout", "--model", str(args.model), str(tmp / "scene.toml"),
                                             "--out", str(tmp / f"rollout{k}"), "--no-animation", "--stop-speed", "0"],
                                            env))
    median = {k: statistics.median(v) for k, v in times.items()}
    print(json.dumps({"scene": args.scene.name, "cell_size_m": scene.domain.cell_size, "frames": args.frames,
                      "threads": os.environ.get("OMP_NUM_THREADS"), "wall_s": times, "median_s": median,
                      "mpm_over_engine": median["mpm"] / median[engine.name]}, indent=1))


if __name__ == "__main__":
    main()
