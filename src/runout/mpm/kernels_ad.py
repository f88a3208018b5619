"""The MPM's substeps on the fused Warp kernels (runout.mpm.kernels) as a differentiable torch
function of the start state and the strengths: reverse mode for runout.mpm.differentiable.

    run = WarpRun(batch, longest=16)
    ends, x, v, C, stress, volume = warp_substeps(run, schedule, x, v, C, stress, volume, *strengths)

The substeps run in segments (an output frame, or a stretch of the geostatic relaxation); `ends`
[S, P, 2] holds the positions at the end of each. The forward pass keeps only the state at each
segment's start (x, v, C, stress, volume: 13 numbers per point); the backward pass recomputes one
segment at a time, every substep writing into arrays of its own (Warp's adjoint of a kernel needs
the kernel's inputs unchanged), and launches the kernels' own adjoints (Warp's generated code) back
through it. That is what a wp.Tape does, but with every launch (forward and adjoint) packed once
per schedule and replayed (wp.Launch) instead of packed anew, adjoint structs included, at each
call: on the small dam (336 points, 595 substeps) that made the backward pass 0.79 -> 0.22 s
(loaded 2-core machine), the same gradients. The adjoint launches get empty structs, so Warp's
adjoint code reads and adds into each array's own .grad (its documented fallback).
The strengths enter as the per-point constants that follow phi and c (STRENGTHS), so torch's
autograd carries their gradients on to phi and c through the K0 start and MaterialTable.
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from contextlib import nullcontext
from dataclasses import dataclass

import torch
import warp as wp

from runout.mpm.geostatic import GRAVITY
from runout.mpm.solver import flip_shares
from runout.mpm.kernels import (
    FREE, UPDATE_STEP, MaterialConstants, NewState, NodeArrays, PointArrays, Real, g2p, grid_update, nodal_rate, node_arrays, p2g,
    update_points, with_transfers,
)
from runout.mpm.mohr_coulomb import MaterialArrays
from runout.mpm.setup import Batch
from runout.mpm.warp_runtime import start_warp

STATE = ("x", "v", "C", "stress", "volume")
STRENGTHS = ("sin_phi", "cohesion", "tension", "c_cos", "corner3")  # the MaterialConstants that follow phi and c
_TYPES = {"x": wp.vec2d, "v": wp.vec2d, "C": wp.mat22d, "stress": wp.vec4d, "volume": Real}
_SCATTERED = ("mass", "momentum", "impulse", "volumetric")  # node arrays p2g and g2p add into
_TRANSFERS = _SCATTERED + ("velocity", "velocity_before", "rate")


def strength_tensors(mat: MaterialArrays) -> tuple[torch.Tensor, ...]:
    """[P] tensors of STRENGTHS, in order, from a point's MaterialArrays (autograd graph kept)."""
    return tuple(getattr(mat, name) for name in STRENGTHS)


@dataclass(frozen=True)
class Schedule:
    """How one warp_substeps call runs: the step, FLIP share and local damping of every substep,
    and its segments as (index of the first substep, substeps)."""

    dt: float  # s
    flip: float | str
    damping: float
    segments: tuple[tuple[int, int], ...]
    hold: bool = False  # the geostatic relaxation: points held in place
    last_stress_step: torch.Tensor | None = None  # [P] relaxation: the point's stress changes while step < this

    @classmethod
    def frames(cls, batch: Batch, count: int) -> Schedule:
        """`count` output frames of batch.n_sub substeps each."""
        return cls(batch.dt, batch.flip, batch.damping, ((0, batch.n_sub),) * count)

    @classmethod
    def relaxation(cls, batch: Batch, dt: float, damping: float, steps: torch.Tensor, total: int,
                   length: int) -> Schedule:
        """batch.relax_geostatic's `total` held substeps, point p's stress updated in the first
        steps[p], in segments of at most `length` substeps."""
        segments = tuple((k, min(length, total - k)) for k in range(0, total, length))
        return cls(dt, batch.flip, damping, segments, hold=True, last_stress_step=steps)


class WarpRun:
    """The Warp arrays of one batch's differentiable run: per-point constants, and the state,
    transfer and move arrays of up to `longest` substeps (one segment), each with its gradient.

    On a CPU with more than one torch thread (`threads`, default torch.get_num_threads()) it
    holds two such sets, so that the backward pass recomputes the next segment's forward on
    one thread while the adjoints of this segment run on the other (Warp runs a launch on one
    thread and lets go of the GIL). The arithmetic, and its order, is that of one set."""

    def __init__(self, batch: Batch, longest: int, threads: int | None = None):
        pts = batch.pts
        if pts.x.dtype != torch.float64:
            raise ValueError(f"the Warp MPM kernels run in float64; got points in {pts.x.dtype}")
        start_warp()
        self.device = wp.device_from_torch(pts.x.device)
        self.stream = wp.stream_from_torch(pts.x.device) if pts.x.is_cuda else None  # torch's, so no race with it
        self.dx, self.n_points, self.n_nodes, self.longest = batch.grid.dx, len(pts.x), batch.grid.size, longest
        self.last_step = wp.full(self.n_points, FREE, dtype=wp.int32, device=self.device)
        self.mat = self._materials(pts.mat)
        self.wave_rate = pts.wave_rate.detach().to(torch.float64).contiguous().clone()  # c_p / dx, 1/s (flip_shares)
        rules = node_arrays(batch.grid, self.device)
        constants = {name: self._copy(getattr(pts, name), dtype) for name, dtype in (
            ("rest_volume", Real), ("mass", Real), ("upper", wp.vec2d),
            ("node_base", wp.int32), ("ny", wp.int32))}
        threads = threads if threads is not None else torch.get_num_threads()
        sets = 2 if self.device.is_cpu and threads > 1 else 1
        self.sets = [_ArraySet(self, rules, constants) for _ in range(sets)]
        self._recorded: tuple | None = None  # the schedule settings the sets' launches were packed for
        self._pool: ThreadPoolExecutor | None = None

    def on_torch_stream(self):
        """Context in which the run's launches and copies follow torch's CUDA stream."""
        return wp.ScopedStream(self.stream) if self.stream is not None else nullcontext()

    def prepare(self, schedule: Schedule, strengths) -> None:
        """Load the strengths [P] (STRENGTHS order) and the schedule's relaxation steps."""
        for name, t in zip(STRENGTHS, strengths):
            getattr(self.mat, name).assign(wp.from_torch(t.detach().contiguous()))
        if schedule.last_stress_step is None:
            self.last_step.fill_(FREE)
        else:
            self.last_step.assign(wp.from_torch(schedule.last_stress_step.to(torch.int32).contiguous()))
        settings = (schedule.dt, schedule.flip, schedule.damping, schedule.hold)
        if settings != self._recorded:
            for arrays in self.sets:
                arrays.record(schedule)
            self._recorded = settings

    def segment(self, schedule: Schedule, first: int, n: int, state, which: int = 0) -> None:
        """n substeps from `state` (torch tensors, STATE order) into set `which`'s states[1..n]."""
        self.sets[which].segment(first, n, state)

    def state(self, k: int, which: int = 0) -> tuple[torch.Tensor, ...]:
        """The state after k substeps of the last segment, as torch tensors (copies)."""
        return tuple(wp.to_torch(self.sets[which].states[k][name]).clone() for name in STATE)

    def adjoints(self, schedule: Schedule, starts: list, adj, grad_ends) -> tuple[torch.Tensor, ...]:
        """The whole schedule's vector-Jacobian product, segment by segment from the last: the
        adjoint of the first segment's start state from `adj` (that of the end state) and
        grad_ends [S] (those of the positions at each segment's end). With two array sets the
        next segment's forward is recomputed on another thread meanwhile."""
        order = list(reversed(range(len(schedule.segments))))

        def recompute(j: int, which: int) -> None:
            first, n = schedule.segments[j]
            self.sets[which].recompute(first, n, starts[j])

        if len(self.sets) == 1:
            for j in order:
                recompute(j, 0)
                adj = self.sets[0].reverse(*schedule.segments[j], (adj[0] + grad_ends[j], *adj[1:]))
            return adj
        if self._pool is None:
            self._pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="runout-mpm-ad")
        recompute(order[0], 0)
        pending = None
        try:
            for i, j in enumerate(order):
                if pending is not None:
                    pending.result()
                    pending = None
                which = i % 2
                if i + 1 < len(order):  # the other set is free: its reverse pass (i - 1) has ended
                    pending = self._pool.submit(recompute, order[i + 1], 1 - which)
                adj = self.sets[which].reverse(*schedule.segments[j], (adj[0] + grad_ends[j], *adj[1:]))
        finally:
            if pending is not None:
                pending.result()
        return adj

    def zero_strength_grads(self) -> None:
        for name in STRENGTHS:
            getattr(self.mat, name).grad.zero_()

    def strength_grads(self) -> tuple[torch.Tensor, ...]:
        return tuple(wp.to_torch(getattr(self.mat, name).grad).clone() for name in STRENGTHS)

    def _zeros(self, dtype) -> wp.array:
        return wp.zeros(self.n_points, dtype=dtype, device=self.device, requires_grad=True)

    def _copy(self, t: torch.Tensor, dtype) -> wp.array:
        kind = torch.int32 if dtype == wp.int32 else torch.float64
        return wp.from_torch(t.detach().to(kind).contiguous().clone(), dtype=dtype)

    def _materials(self, mat: MaterialArrays) -> MaterialConstants:
        out = MaterialConstants()
        fixed = {"lam": mat.lam, "shear": mat.shear, "k": mat.k, "ratio": mat.ratio, "inv_k": mat.apex[0],
                 "inv_lam": mat.apex[1]}
        for name, t in fixed.items():
            setattr(out, name, self._copy(t, Real))
        out.plastic = self._copy(mat.plastic, wp.int32)
        for name in STRENGTHS:
            setattr(out, name, self._zeros(Real))
        return out

    def __del__(self):
        if getattr(self, "_pool", None) is not None:
            self._pool.shutdown(wait=False)


class _ArraySet:
    """One segment's arrays of a WarpRun (states, node transfers, moves, each with its gradient)
    and the substeps' launches on them, forward and adjoint, packed once per schedule."""

    def __init__(self, run: WarpRun, rules: NodeArrays, constants: dict):
        self.run = run
        longest = run.longest
        self.nodes = [with_transfers(rules, requires_grad=True) for _ in range(longest)]
        self.states = [{name: run._zeros(t) for name, t in _TYPES.items()} for _ in range(longest + 1)]
        self.moves = [{"x_moved": run._zeros(wp.vec2d), "C_grid": run._zeros(wp.mat22d)} for _ in range(longest)]
        self.inputs = [self._point_arrays(self.states[k], constants) for k in range(longest + 1)]
        self.outputs = [self._new_state(self.states[k + 1], self.moves[k]) for k in range(longest)]
        self._forward: list[list[wp.Launch]] = []  # [k] substep k's five launches
        self._backward: list[list[wp.Launch]] = []  # [k] their adjoints, in reverse order

    def record(self, schedule: Schedule) -> None:
        self._shares = flip_shares(self.run.wave_rate, schedule.dt, schedule.flip)  # kept alive: the launches view it
        self.shares = wp.from_torch(self._shares)
        self._forward = [self._record(schedule, k, adjoint=False) for k in range(self.run.longest)]
        self._backward = [self._record(schedule, k, adjoint=True)[::-1] for k in range(self.run.longest)]

    def segment(self, first: int, n: int, state) -> None:
        """n substeps from `state` (torch tensors, STATE order) into self.states[1..n]."""
        for name, t in zip(STATE, state):
            self.states[0][name].assign(wp.from_torch(t.detach().contiguous(), dtype=_TYPES[name]))
        for nodes in self.nodes[:n]:
            for name in _SCATTERED:
                getattr(nodes, name).zero_()
        for k in range(n):
            self._replay(self._forward[k], first + k)

    def recompute(self, first: int, n: int, start) -> None:
        """The segment's forward again from its kept start, gradients cleared, for `reverse`."""
        for arrays in self.states[: n + 1] + self.moves[:n]:
            for a in arrays.values():
                a.grad.zero_()
        for nodes in self.nodes[:n]:
            for name in _TRANSFERS:
                getattr(nodes, name).grad.zero_()
        self.segment(first, n, start)

    def reverse(self, first: int, n: int, adj_end) -> tuple[torch.Tensor, ...]:
        """The adjoints of a recomputed segment: the start state's from the end state's."""
        for name, g in zip(STATE, adj_end):
            self.states[n][name].grad.assign(wp.from_torch(g.contiguous(), dtype=_TYPES[name]))
        for k in reversed(range(n)):
            self._replay(self._backward[k], first + k)
        return tuple(wp.to_torch(self.states[0][name].grad).clone() for name in STATE)

    def _replay(self, launches: list[wp.Launch], step: int) -> None:
        """Run packed launches of one substep, update_points told it is substep `step`."""
        for launch in launches:
            if launch.kernel is update_points:
                launch.set_param_at_index(UPDATE_STEP, step)
            launch.launch()

    def _record(self, schedule: Schedule, k: int, adjoint: bool) -> list[wp.Launch]:
        """Substep k's five launches (or their adjoints), packed once for replaying."""
        return [wp.launch(kernel, dim=dim, inputs=inputs, adj_inputs=[_empty(a) for a in inputs] if adjoint else [],
                          adjoint=adjoint, device=self.run.device, record_cmd=True)
                for kernel, dim, inputs in self._launches(schedule, k)]

    def _launches(self, schedule: Schedule, k: int) -> list[tuple]:
        """The five kernels of a substep of the schedule from self.states[k] into self.states[k + 1],
        as (kernel, threads, inputs), in order; update_points' step is set when replayed."""
        run = self.run
        pts, nodes, out, dx, dt = self.inputs[k], self.nodes[k], self.outputs[k], run.dx, schedule.dt
        p, g = run.n_points, run.n_nodes
        return [
            (p2g, p, [pts, nodes, dx, dt * (4.0 / dx**2)]),
            (grid_update, g, [nodes, GRAVITY * dt, float(schedule.damping)]),
            (g2p, p, [pts, nodes, dx, dt, self.shares, out]),
            (nodal_rate, g, [nodes]),
            (update_points, p, [pts, run.mat, nodes, dx, dt, 0, int(schedule.hold), out]),
        ]

    def _point_arrays(self, state: dict, constants: dict) -> PointArrays:
        a = PointArrays()
        for name, array in {**state, **constants}.items():
            setattr(a, name, array)
        a.last_stress_step = self.run.last_step
        return a

    @staticmethod
    def _new_state(state: dict, move: dict) -> NewState:
        out = NewState()
        for name, array in {**state, **move}.items():
            setattr(out, name, array)
        return out


def _empty(argument):
    """An adjoint launch's argument for `argument`: a struct with no arrays (Warp's adjoint code
    then uses each array's own .grad), nothing for a number or a lone array (the FLIP shares,
    constants)."""
    return None if isinstance(argument, (int, float, wp.array)) else type(argument)()


class _Substeps(torch.autograd.Function):
    """(state, strengths) -> (positions at each segment's end, end state); see warp_substeps."""

    @staticmethod
    def forward(ctx, run: WarpRun, schedule: Schedule, *tensors):
        state, strengths = tensors[: len(STATE)], tensors[len(STATE):]
        kept, ends = [], []
        with run.on_torch_stream():
            run.prepare(schedule, strengths)
            for first, n in schedule.segments:
                kept.append(tuple(t.detach() for t in state))
                run.segment(schedule, first, n, state)
                state = run.state(n)
                ends.append(state[0])
        ctx.run, ctx.schedule = run, schedule
        # saved, not kept on ctx, so that runout.inverse.memory's saved-tensor hooks count the checkpoints
        # (the run's own arrays, one segment's worth, do not grow with the frames and are not counted)
        ctx.save_for_backward(*(t.detach() for t in strengths), *(t for start in kept for t in start))
        return (torch.stack(ends), *state)

    @staticmethod
    def backward(ctx, grad_ends, *grad_state):
        run, schedule = ctx.run, ctx.schedule
        saved = ctx.saved_tensors
        strengths, kept = saved[: len(STRENGTHS)], saved[len(STRENGTHS):]
        adj = tuple(g.detach() for g in grad_state)
        with run.on_torch_stream():
            run.prepare(schedule, strengths)  # another call may have used the run since
            run.zero_strength_grads()
            starts = [kept[j * len(STATE): (j + 1) * len(STATE)] for j in range(len(schedule.segments))]
            adj = run.adjoints(schedule, starts, adj, grad_ends)
            grads = (*adj, *run.strength_grads())
        return (None, None, *(g if need else None for g, need in zip(grads, ctx.needs_input_grad[2:])))


def warp_substeps(run: WarpRun, schedule: Schedule, x, v, C, stress, volume, *strengths):
    """The schedule's substeps from the state (x, v, C, stress, volume) with the per-point
    strengths (STRENGTHS order), differentiable in all of them: returns the positions at the end
    of each segment [S, P, 2] and the end state (x, v, C, stress, volume)."""
    return _Substeps.apply(run, schedule, x, v, C, stress, volume, *strengths)
