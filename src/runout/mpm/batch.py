"""Run a built batch (runout.mpm.setup): the geostatic relaxation, then frame by frame."""

from __future__ import annotations

import time

import numpy as np
import torch
from tqdm.auto import tqdm

from runout.mpm.geostatic import GRAVITY
from runout.mpm.mohr_coulomb import return_map
from runout.mpm.setup import Batch
from runout.mpm.solver import Points, substep
from runout.trajectory import Trajectory, trajectory_for_scene

RELAX_CFL = 1.5  # relaxation step as a share of the scene CFL step on the wave speed alone
RELAX_PERIODS = 3.0  # length of the geostatic relaxation in periods of the slowest mode
RELAX_DAMPING = 0.8  # local damping share during the relaxation (FLAC's default for static equilibrium)


def relax_geostatic(batch: Batch, step=substep, held=None) -> int:
    """Bring the K0 stresses into the discrete equilibrium of this grid before release.

    Damped elastic-plastic dynamics with the points held in place: stresses absorb the strain
    the grid would impose, through the materials' own yield and tension cut-off, until grid
    forces balance gravity; then the velocities are reset. The start is so statically and
    plastically admissible wherever the scene can stand: a cut whose crest cracks in tension
    has cracked before release, instead of opening (and being counted as moving) after it.
    A scene that cannot stand still fails on release. The damping is local (Cundall's, as in
    FLAC's static solutions): RELAX_DAMPING of each component of the unbalanced nodal force,
    which damps every mode alike. Viscous damping tuned to the slowest mode left the opening
    at a cut's face (soil held at the tension cut-off, which has no stiffness against opening)
    still moving at 0.05 m/s after three periods, and an opened face coasts on that speed after
    release (docs/scene-format.md, solver version 5). RELAX_PERIODS periods of the slowest
    vertical mode (4 H / c_p for the scene's tallest body H) are run at the wave-speed CFL step;
    a scene that has finished holds its stresses while others go on, so a batch relaxes each
    scene exactly as it would alone. `held` (kernels.WarpSubstep.relax) runs all the held
    substeps at once in place, instead of `step` one by one. Returns the substeps run."""
    pts, grid = batch.pts, batch.grid
    if len(pts.x) == 0:
        return 0
    dt, steps_p, total = relaxation_schedule(batch)
    x0, v0 = pts.x.clone(), pts.v.clone()
    pts.v = torch.zeros_like(v0)
    if held is not None:
        held(pts, grid, dt, batch.flip, RELAX_DAMPING, steps_p, total)
    else:
        for k in range(total):
            stress = pts.stress
            step(pts, grid, dt, batch.flip, RELAX_DAMPING)
            pts.stress = torch.where((k < steps_p)[:, None], pts.stress, stress)
            pts.x = x0
    pts.x, pts.v = x0, v0
    pts.C = torch.zeros_like(pts.C)
    pts.volume = torch.full_like(pts.volume, float(batch.scenes[0].domain.point_spacing) ** 2)
    pts.stress = return_map(pts.stress, pts.mat)
    return total


def relaxation_schedule(batch: Batch) -> tuple[float, torch.Tensor, int]:
    """The relaxation's step (s), each point's number of stress-updating substeps [P] (its
    scene's RELAX_PERIODS periods) and the substeps run (the longest scene's)."""
    pts, grid = batch.pts, batch.grid
    n_scenes = len(batch.scenes)
    height = torch.zeros(n_scenes, dtype=pts.x.dtype, device=pts.x.device)
    height.scatter_reduce_(0, pts.scene, pts.x[:, 1], reduce="amax")
    c_p = torch.zeros_like(height)
    c_p.scatter_reduce_(0, pts.scene, torch.sqrt((pts.mat.lam + 2 * pts.mat.shear) * pts.volume / pts.mass),
                        reduce="amax")
    period = 4 * height / c_p  # s, per scene
    # points are held, so only the wave speed limits the step (no fall speed as in batch.dt)
    dt = max(batch.dt, RELAX_CFL * batch.scenes[0].time.cfl * grid.dx / float(c_p.max()))
    steps = torch.ceil(RELAX_PERIODS * period / dt).long()  # per scene
    return dt, steps[pts.scene], int(steps.max())


BACKENDS = ("torch", "warp")  # the substep as torch tensor operations (solver) or as Warp kernels (kernels)
BACKEND = "warp"  # the one every command runs; "torch" is the test oracle (docs/scene-format.md)


def run_batch(batch: Batch, frames: int, progress: bool = True, compile: bool = False,
              backend: str = BACKEND) -> list[Trajectory]:
    """Advance every scene of the batch through `frames` output frames (frame 0 = start).

    The substep runs as fused Warp kernels (runout.mpm.kernels, float64). backend="torch" runs
    the tensor solver (runout.mpm.solver) instead, the oracle the tests compare the kernels
    with: the same positions, 4-9x slower; only it takes a float32 batch or compile=True
    (torch.compile of the substep, a minute or more of compilation first). No command
    selects it."""
    if backend not in BACKENDS:
        raise ValueError(f"MPM backend {backend!r} is not one of {', '.join(BACKENDS)}")
    if backend == "warp" and compile:
        raise ValueError("compile=True is for the torch backend; the Warp backend is compiled already")
    pts, grid = batch.pts, batch.grid
    n_scenes = len(batch.scenes)
    with torch.no_grad():
        if backend == "warp":
            from runout.mpm.kernels import WarpSubstep  # imported here: warp loads only when asked for

            step = WarpSubstep(grid, pts)
            relax_steps = relax_geostatic(batch, held=step.relax)
        else:
            step = torch.compile(substep, dynamic=True) if compile else substep
            relax_steps = relax_geostatic(batch, step)
    record = [pts.x.detach().to("cpu", torch.float32)]
    ke0, pe0 = energies(pts, n_scenes)
    kinetic, potential = [ke0.cpu()], [pe0.cpu()]
    start = time.perf_counter()
    with torch.no_grad():
        for _ in tqdm(range(frames - 1), desc=f"MPM {n_scenes} scene(s)", unit="frame", disable=not progress):
            if backend == "warp":  # the scene groups side by side through the frame's substeps
                step.advance(pts, grid, batch.dt, batch.flip, batch.damping, batch.n_sub)
            else:
                for _ in range(batch.n_sub):
                    step(pts, grid, batch.dt, batch.flip, batch.damping)
            record.append(pts.x.to("cpu", torch.float32))
            ke, pe = energies(pts, n_scenes)
            kinetic.append(ke.cpu())
            potential.append(pe.cpu())
    wall = time.perf_counter() - start
    moving_all = torch.stack(record).numpy()  # [T, P, 2]
    kinetic = torch.stack(kinetic).numpy()
    potential = torch.stack(potential).numpy()
    scene_of = pts.scene.cpu().numpy()
    out = []
    for k, s in enumerate(batch.scenes):
        moving, ptype, mid = batch.order[k]
        positions = np.empty((frames, len(moving), 2), dtype=np.float32)
        positions[:, moving] = moving_all[:, scene_of == k]
        positions[:, ~moving] = batch.fixed_xy[k][None].astype(np.float32)
        traj = trajectory_for_scene(s, positions, ptype, mid)
        traj.info = {
            "engine": "mpm",
            "backend": backend,
            "substeps_per_frame": batch.n_sub,
            "relaxation_substeps": relax_steps,
            "dt": batch.dt,
            "wall_time_s": wall,
            "batch_size": n_scenes,
            "kinetic_energy": kinetic[:, k].tolist(),
            "potential_energy": potential[:, k].tolist(),
        }
        out.append(traj)
    return out


def energies(pts: Points, n_scenes: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Kinetic and gravitational potential energy (J per metre of thickness) per scene."""
    ke = torch.zeros(n_scenes, dtype=pts.x.dtype, device=pts.x.device)
    pe = torch.zeros_like(ke)
    ke.index_add_(0, pts.scene, 0.5 * pts.mass * (pts.v**2).sum(1))
    pe.index_add_(0, pts.scene, pts.mass * GRAVITY * pts.x[:, 1])
    return ke, pe
