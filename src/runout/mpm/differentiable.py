"""The MPM as a differentiable function of the per-material strengths phi and c.

    model = DifferentiableMpm(scene, frames=[10, 20])
    positions = model(phi_deg, c_kpa)  # [F, N, 2] m, every point in output order

Reverse-mode AD runs through the whole MPM: the K0 start (K0 = 1 - sin phi unless a material
gives k0), the geostatic relaxation (elastic-plastic, points held), every substep's Jaumann
trial, Mohr-Coulomb return and tension cut-off (T = min(T_given, c / tan phi)), and the frame
outputs. The batch is built once from the scene by runout.mpm.setup, as for the batched run,
and so are the K0 start and the materials, from the strengths given here. The substep count,
the relaxation length and the grid follow from stiffness, density and geometry, never from phi
or c, so they stay fixed while an optimiser moves the strengths.

The relaxation and the frames run on the fused Warp kernels (runout.mpm.kernels, float64) with
their own adjoints (runout.mpm.kernels_ad). Memory stays bounded: the forward keeps only the
state (x, v, C, stress, volume: 13 numbers per point) at each output frame and every
RELAX_SEGMENT relaxation substeps, and the backward pass recomputes one segment at a time, so
the memory grows by about 100 bytes per point per frame instead of by every substep's
temporaries. The K0 start, the materials and the return after the relaxation stay in torch.
The small dam's evaluation at P = 3 took 0.31 s against 4.47 s on the torch solver (loaded
2-core CPU, 2026-12-03), with nothing to compile beyond Warp's cached module.

backend="torch" is the oracle the tests compare the kernels with (same positions and gradients
to rounding, tests/test_mpm_kernels_ad.py): the torch solver under autograd, checkpointed with
torch.utils.checkpoint (reentrant) per frame and per relaxation substep; only it takes float32,
checkpoint=False (autograd keeps every substep) or compile=True (torch.compile of each frame's
substeps: four graphs, 2-3 minutes of compilation on a 2-core CPU). No command selects it.
"""

from __future__ import annotations

from dataclasses import replace
from functools import partial

import torch
from torch.utils.checkpoint import checkpoint

from runout.mpm.batch import BACKEND, BACKENDS, RELAX_DAMPING, relax_geostatic, relaxation_schedule
from runout.mpm.mohr_coulomb import MaterialArrays, return_map
from runout.mpm.setup import Strengths, build_batch
from runout.mpm.solver import Points, substep
from runout.scene import Scene

_STATE = ("x", "v", "C", "stress", "volume")
_STRENGTHS = ("sin_phi", "cos_phi", "cohesion", "tension")  # the MaterialArrays fields that follow phi and c
RELAX_SEGMENT = 16  # backend="warp": relaxation substeps recomputed together in the backward pass


class DifferentiableMpm:
    """One scene's MPM run: (phi [M] degrees, c [M] kPa) -> positions [F, N, 2] m at `frames`.

    M follows scene.material_names; frames are output-frame indices (0 = start), increasing."""

    def __init__(self, scene: Scene, frames, device: str | torch.device = "cpu", dtype: torch.dtype = torch.float64,
                 checkpoint: bool = True, compile: bool = False, backend: str = BACKEND):
        if backend not in BACKENDS:
            raise ValueError(f"differentiable MPM backend {backend!r} is not one of {', '.join(BACKENDS)}")
        if backend == "warp" and (compile or not checkpoint or dtype != torch.float64):
            raise ValueError("the Warp backend runs in float64 with per-frame checkpoints and is compiled already "
                             "(compile=False, checkpoint=True, dtype=torch.float64)")
        self.scene = scene
        self.backend = backend
        self.substeps = compiled_substeps() if compile else substeps  # n substeps of a Points in place
        self.checkpoint = checkpoint  # False: autograd keeps every substep (memory grows with them)
        self.frames = [int(f) for f in frames]
        self.batch = build_batch([scene], torch.device(device), dtype)
        pts = self.batch.pts
        moving = self.batch.order[0][0]
        opt = dict(dtype=dtype, device=pts.x.device)
        self.moving_index = torch.as_tensor(self.batch.moving_index[0], device=pts.x.device)
        self.template = torch.zeros(len(moving), 2, **opt)
        self.template[torch.as_tensor(~moving)] = torch.as_tensor(self.batch.fixed_xy[0], **opt)
        self.start = {name: getattr(pts, name).clone() for name in _STATE}
        self.warp = None
        if backend == "warp" and len(pts.x):
            from runout.mpm.kernels_ad import WarpRun  # imported here: warp loads only when asked for

            self.warp = WarpRun(self.batch, max(self.batch.n_sub, RELAX_SEGMENT))

    @property
    def substeps_per_frame(self) -> int:
        return self.batch.n_sub

    def initial_points(self, phi: torch.Tensor, c: torch.Tensor) -> Points:
        """The K0 start and materials of these strengths (phi [M] degrees, c [M] kPa), before relaxation."""
        strengths = Strengths.of(phi, c)
        table, dtype = self.batch.materials, self.batch.pts.x.dtype
        start = {name: t.clone() for name, t in self.start.items()}
        stress = table.start_stress(self.batch.sigma_v, strengths, dtype)
        return replace(self.batch.pts, mat=table.arrays(strengths, dtype), **{**start, "stress": stress})

    def __call__(self, phi: torch.Tensor, c: torch.Tensor) -> torch.Tensor:
        """Positions [F, N, 2] (m) at the frames, differentiable w.r.t. phi [M] and c [M]."""
        pts = self.initial_points(phi, c)
        if self.warp is not None:
            return self._warp_positions(pts)
        batch = replace(self.batch, pts=pts)
        if len(pts.x):
            relax_geostatic(batch, step=partial(_relaxation_substep, keep_start_only=self.checkpoint,
                                                advance=self.substeps))
        wanted = set(self.frames)
        out = {0: pts.x} if 0 in wanted else {}
        for frame in range(1, self.frames[-1] + 1):
            _advance(pts, batch.grid, batch.dt, batch.flip, batch.damping, batch.n_sub, self.checkpoint, self.substeps)
            if frame in wanted:
                out[frame] = pts.x
        return torch.stack([self._all_points(out[f]) for f in self.frames])

    def _warp_positions(self, pts: Points) -> torch.Tensor:
        """__call__ on the Warp kernels: batch.relax_geostatic, then the frames, as two
        differentiable Warp runs (runout.mpm.kernels_ad)."""
        from runout.mpm.kernels_ad import Schedule, strength_tensors, warp_substeps

        batch = replace(self.batch, pts=pts)
        strengths = strength_tensors(pts.mat)
        dt, steps, total = relaxation_schedule(batch)
        stress = pts.stress
        if total:
            relax = Schedule.relaxation(batch, dt, RELAX_DAMPING, steps, total, RELAX_SEGMENT)
            stress = warp_substeps(self.warp, relax, pts.x, torch.zeros_like(pts.v), pts.C, stress, pts.volume,
                                   *strengths)[4]
        stress = return_map(stress, pts.mat)
        volume = torch.full_like(pts.volume, float(self.scene.domain.point_spacing) ** 2)
        ends = warp_substeps(self.warp, Schedule.frames(batch, self.frames[-1]), pts.x, pts.v,
                             torch.zeros_like(pts.C), stress, volume, *strengths)[0] if self.frames[-1] else None
        return torch.stack([self._all_points(pts.x if f == 0 else ends[f - 1]) for f in self.frames])

    def _all_points(self, x: torch.Tensor) -> torch.Tensor:
        return self.template.index_put((self.moving_index,), x)


def substeps(pts: Points, grid, dt: float, flip, damping: float, n: int, *tensors: torch.Tensor
             ) -> tuple[torch.Tensor, ...]:
    """n substeps from the state and strengths `tensors` (_STATE, then _STRENGTHS) with pts's other
    fields; returns the new state (x, v, C, stress, volume)."""
    base = pts.mat
    strengths = dict(zip(_STRENGTHS, tensors[len(_STATE):]))
    mat = MaterialArrays(lam=base.lam, shear=base.shear, plastic=base.plastic, **strengths)
    p = replace(pts, mat=mat, **dict(zip(_STATE, tensors[: len(_STATE)])))
    for _ in range(n):
        substep(p, grid, dt, flip, damping)
    return tuple(getattr(p, name) for name in _STATE)


_COMPILED = []


def compiled_substeps():
    """`substeps` through torch.compile, made once per process: one graph for the n substeps of
    a frame (AOTAutograd fuses their forward and backward into a few C++ kernels). Four graphs
    (no grad / grad, relaxation / frame); shapes static for the first scene, dynamic after."""
    if not _COMPILED:
        _COMPILED.append(torch.compile(substeps))
    return _COMPILED[0]


def _advance(pts: Points, grid, dt: float, flip: float, damping: float, n: int, keep_start_only: bool = True,
             advance=substeps) -> None:
    """n substeps of pts in place, recomputed in the backward pass (only their start is kept).

    The reentrant checkpoint runs the forward without building a graph (as fast as the plain
    MPM); the strengths are passed as explicit inputs so that their gradients come back."""

    def run(*tensors):
        if advance is not substeps:  # compiled: one requires_grad pattern per grad mode, so no recompiles
            grad = torch.is_grad_enabled()
            tensors = tuple(t if grad and t.requires_grad else t.detach().requires_grad_(grad) for t in tensors)
        return advance(pts, grid, dt, flip, damping, n, *tensors)

    inputs = tuple(getattr(pts, name) for name in _STATE) + tuple(getattr(pts.mat, name) for name in _STRENGTHS)
    if keep_start_only and torch.is_grad_enabled() and any(t.requires_grad for t in inputs):
        state = checkpoint(run, *inputs, use_reentrant=True)
    else:
        state = run(*inputs)
    for name, value in zip(_STATE, state):
        setattr(pts, name, value)


def _relaxation_substep(pts: Points, grid, dt: float, flip: float = 0.0, damping: float = 0.0,
                        keep_start_only: bool = True, advance=substeps) -> None:
    """relax_geostatic's step, kept only by its start state (keep_start_only)."""
    _advance(pts, grid, dt, flip, damping, 1, keep_start_only, advance)
