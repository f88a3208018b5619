"""Batched explicit MPM for plane-strain Mohr-Coulomb runout (see solver.py for the scheme).

    from runout.mpm import simulate
    trajectories = simulate([scene_a, scene_b], device="cpu")

Scenes that share cell size, frame interval, FLIP share, frame count and CFL substep count advance
together in one flat point array; others run as separate batches. Each scene's result is
the same as running it alone.
"""

from __future__ import annotations

from collections import defaultdict

import torch

from runout import checks
from runout.mpm.batch import BACKEND, run_batch
from runout.mpm.setup import build_batch, substeps_per_frame
from runout.scene import Scene
from runout.trajectory import Trajectory

SOLVER_VERSION = "6"  # 6: volumetric rate averaged through the nodes, weighted by the mobilised strength; 5: FLIP share a fixed rate in time (exp(-dt c_p / dx)), relaxation with local damping 0.8; 4: rough (no-slip) base by default, points without contacts keep no affine velocity; 3: consistent cut-off return, APIC, elastic-plastic relaxation, fixed-ground normals, dilute points

__all__ = ["simulate", "substeps_per_frame"]


def simulate(
    scenes: list[Scene],
    device: str | torch.device = "cpu",
    progress: bool = True,
    frames: int | None = None,
    dtype: torch.dtype = torch.float64,
    compile: bool = False,
    backend: str = BACKEND,
) -> list[Trajectory]:
    """Run every scene through the MPM; returns one Trajectory per scene, in order.

    The substep runs as fused Warp kernels in float64 (runout.mpm.kernels). backend="torch"
    is the tensor solver the tests compare them with (runout.mpm.batch.run_batch); dtype
    float32 and compile=True are for it alone."""
    checks.device(str(device))
    device = torch.device(device)
    groups: dict[tuple, list[int]] = defaultdict(list)
    for k, s in enumerate(scenes):
        n = frames if frames is not None else s.time.frames
        key = (s.domain.cell_size, s.domain.points_per_cell, s.time.frame_dt, s.time.flip, s.time.damping, n, substeps_per_frame(s))
        groups[key].append(k)
    out: list[Trajectory | None] = [None] * len(scenes)
    for (*_, n, _), members in groups.items():
        batch = build_batch([scenes[k] for k in members], device, dtype)
        for k, traj in zip(members, run_batch(batch, n, progress, compile, backend)):
            out[k] = traj
    return out
