"""Speed of `runout hazard`: N realisations of the four-layer slope's hazard study (8 m
cells, 400 frames) batched through runout.mpm.simulate, against the same N realisations run
one scene at a time (what N separate `runout mpm` runs compute, without their start-up and
files). Prints wall times in seconds and particle-substeps per second.

    PYTHONPATH=src python bench/hazard.py [N]
"""

from __future__ import annotations

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
from runout.scene import fill_points

SPEC = Path(__file__).resolve().parents[1] / "examples" / "hazard_four_layer_slope.toml"


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


if __name__ == "__main__":
    main(int(sys.argv[1]) if len(sys.argv) > 1 else 16)
