"""What an MPM run will cost, known before it starts: points, grid nodes, substeps, memory.

    check_budget(scenes, frames=None, device="cpu", source="scene.toml")

raises InputError (one sentence) when the run would need more memory than the machine has
or more substeps than MAX_SUBSTEPS. The memory model is deliberately generous: it was
measured on CPU at 3-6 kB per point for the state and substep temporaries in float64
(four-layer slope, 6,750 and 27,000 points), and we count 8 kB, plus the recorded
float32 positions held three times (the frame list, the stacked array, each scene's
trajectory) and half a GiB for the interpreter and torch.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from runout.errors import InputError
from runout.memory import GIB, device_memory, host_memory
from runout.mpm.setup import grid_shape, substeps_per_frame
from runout.scene import Scene, fill_points

BYTES_PER_POINT = 8 * 1024  # state and substep temporaries, float64
BYTES_PER_NODE = 256  # grid mass, momentum, velocity and the per-node temporaries
BYTES_PER_POINT_FRAME = 3 * 2 * 4  # float32 (x, y), held three times
BASE_BYTES = GIB // 2  # interpreter, torch, matplotlib
MAX_SUBSTEPS = 100_000_000  # per run: more than a day on any machine we know


@dataclass(frozen=True)
class Estimate:
    points: int  # moving and fixed, all scenes
    nodes: int  # grid nodes, all scenes
    frames: int  # the longest run
    substeps_per_frame: int  # the largest
    device_bytes: int  # held where the solver runs
    host_bytes: int  # recorded frames (always on the host) and the base

    @property
    def substeps(self) -> int:
        return self.frames * self.substeps_per_frame


def estimate(scenes: list[Scene], frames: int | None = None) -> Estimate:
    """Points and substeps of every scene as `runout.mpm.simulate` would run them together."""
    points = sum(len(fill_points(s)) for s in scenes)
    nodes = sum(math.prod(grid_shape(s)) for s in scenes)
    n_frames = max(frames if frames is not None else s.time.frames for s in scenes)
    per_frame = max(substeps_per_frame(s) for s in scenes)
    return Estimate(
        points=points, nodes=nodes, frames=n_frames, substeps_per_frame=per_frame,
        device_bytes=points * BYTES_PER_POINT + nodes * BYTES_PER_NODE,
        host_bytes=points * n_frames * BYTES_PER_POINT_FRAME + BASE_BYTES,
    )


def check_budget(scenes: list[Scene], frames: int | None = None, device="cpu", source: str = "the scene") -> Estimate:
    """The estimate, or InputError when the run would not fit this machine or never end."""
    e = estimate(scenes, frames)
    what = f"{e.points} points, {e.frames} frames, {e.substeps_per_frame} substeps per frame"
    if e.substeps_per_frame * e.frames > MAX_SUBSTEPS:
        raise InputError(
            f"{source}: the MPM run would take {e.substeps:.3g} substeps ({what}), more than the "
            f"{MAX_SUBSTEPS:.0e} allowed; use a larger cell_size, a softer youngs_modulus or fewer frames."
        )
    on_host = torch.device(device).type != "cuda"
    need = e.host_bytes + (e.device_bytes if on_host else 0)
    have = host_memory()
    if not on_host and e.device_bytes > device_memory(device):
        need, have = e.device_bytes, device_memory(device)
    if need > have:
        raise InputError(
            f"{source}: the MPM run needs about {need / GIB:.1f} GiB of memory ({what}) but this machine has "
            f"{have / GIB:.1f} GiB; use a larger cell_size, a smaller domain, fewer frames or fewer scenes per batch."
        )
    return e
