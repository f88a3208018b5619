"""Speed of `runout hazard`: N realisations of the four-layer slope's hazard study (8 m
cells, 400 frames) batched through runout.mpm.simulate, against the same N realisations run
one scene at a time (what N separate `runout mpm` runs compute, without their start-up and
files). Prints wall times in seconds and particle-substeps per second.

With --commands K it also runs the whole `runout hazard` command for the N realisations and
K of the same realisations as separate whole `runout mpm --no-animate` commands (each a fresh
process: start-up, imports, files and its two pictures, as a user running them one by one
pays; no animation, which the hazard study does not draw either), and
extrapolates those K to N (issue 56 item 3: the batched study must beat N separate runs).

    PYTHONPATH=src python bench/hazard.py [N]
    PYTHONPATH=src python bench/hazard.py 200 --commands 20
"""

from __future__ import annotations

import argparse
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import runout.mpm
from runout.hazard import load_spec, run_hazard
from runout.hazard.run import realisation_scene
from runout.hazard.sampling import draw_inputs
from runout.mpm.setup import substeps_per_frame
from runout.scene import fill_points, save_scene

SPEC = Path(__file__).resolve().parents[1] / "examples" / "hazard_four_layer_slope.toml"
RUNOUT = Path(sys.executable).parent / "runout"


def main(count: int) -> None:
    spec = replace(load_spec(SPEC), realisations=count, batch=min(count, 20))
    scene = spec.scene
    work = len(fill_points(scene)) * substeps_per_frame(scene) * (scene.time.frames - 1) * count
    with tempfile.TemporaryDirectory() as out:
        start = time.perf_counter()
        run_hazard(spec, out, progress=False)
        batched = time.perf_counter() - start
    inputs = draw_inputs(spec)
    start = time.perf_counter()
    for k in range(count):
        runout.mpm.simulate([realisation_scene(spec, k, inputs[k])], progress=False)
    separate = time.perf_counter() - start
    print(f"{count} realisations, {len(fill_points(scene))} points, {substeps_per_frame(scene)} substeps/frame, "
          f"{scene.time.frames} frames")
    print(f"batched (whole study, files included): {batched:.1f} s, {work / batched:.3g} particle-substeps/s")
    print(f"one at a time: {separate:.1f} s, {work / separate:.3g} particle-substeps/s; batched is {separate / batched:.2f}x")


def commands(count: int, separate: int) -> None:
    """The whole `runout hazard` command for `count` realisations against `separate` of them run
    as separate `runout mpm` commands, extrapolated to `count`."""
    spec = replace(load_spec(SPEC), realisations=count)
    inputs = draw_inputs(spec)
    with tempfile.TemporaryDirectory() as work:
        work = Path(work)
        spec_file = SPEC.parent / f".bench_hazard_{count}.toml"  # beside the example: its scene path is relative
        text = SPEC.read_text()
        spec_file.write_text(text.replace("realisations = 200", f"realisations = {count}", 1))
        try:
            start = time.perf_counter()
            subprocess.run([str(RUNOUT), "hazard", str(spec_file), "--out", str(work / "hazard")], check=True,
                           stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        finally:
            spec_file.unlink()
        batched = time.perf_counter() - start
        times = []
        for k in range(separate):
            scene_file = work / f"realisation_{k:04d}.toml"
            save_scene(realisation_scene(spec, k, inputs[k]), scene_file)
            start = time.perf_counter()
            subprocess.run([str(RUNOUT), "mpm", str(scene_file), "--out", str(work / f"mpm_{k:04d}"), "--no-animate"],
                           check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
            times.append(time.perf_counter() - start)
            shutil.rmtree(work / f"mpm_{k:04d}")
    median = statistics.median(times)
    print(f"`runout hazard`, {count} realisations, whole command: {batched:.1f} s")
    print(f"`runout mpm`, {separate} of the same realisations one command each: median {median:.2f} s "
          f"(min {min(times):.2f}, max {max(times):.2f}); {count} of them: {median * count:.0f} s by the median "
          f"({sum(times) / separate * count:.0f} s by the mean); batched is {median * count / batched:.1f}x faster")


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("count", type=int, nargs="?", default=16, help="realisations")
    parser.add_argument("--commands", type=int, default=0,
                        help="also time the whole hazard command and this many separate `runout mpm` commands")
    args = parser.parse_args()
    if args.commands:
        commands(args.count, args.commands)
    else:
        main(args.count)
