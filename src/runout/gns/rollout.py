"""Autoregressive GNS rollouts: differentiable tensors in, tensors out; Trajectory in, out.

A model of frame stride K steps K dataset frames at a time: `rollout` works in its steps,
`rollout_trajectory` in dataset frames (its window is the start's frames 0, K, ...,
(history - 1) K, and it returns one frame every K, frame_dt K times the start's).
Kinematic points (type 3) keep their given positions; soil points are clamped into the
domain after every step (the rigid walls); a non-finite position stops the run with
RolloutDiverged. With `checkpoint=True` each step is recomputed in the backward pass
(torch.utils.checkpoint), so memory grows only by one [N, 2] frame per step.
"""

from __future__ import annotations

import math

import numpy as np
import torch
from torch.utils.checkpoint import checkpoint as recompute_in_backward
from tqdm.auto import tqdm

from runout.errors import InputError, RolloutDiverged  # noqa: F401  (RolloutDiverged re-exported)
from runout.gns.features import Constraints
from runout.gns.simulator import GraphNetworkSimulator
from runout.trajectory import Trajectory

CHECK_EVERY = 10  # steps between host checks for NaN and for a stopped flow
MIN_FRAMES_BEFORE_STOP = 40  # dataset frames: a slope at rest needs time to start failing


def rollout(
    simulator: GraphNetworkSimulator,
    initial_positions: torch.Tensor,
    particle_type: torch.Tensor,
    material: torch.Tensor,
    n_steps: int,
    bounds,
    checkpoint: bool = False,
    progress: bool = False,
    stop_speed: float | None = None,
    graph: torch.Tensor | None = None,
) -> torch.Tensor:
    """Positions [history + steps, N, 2] (m) from initial_positions [history, N, 2] (m),
    one per model step (frame_stride dataset frames).

    particle_type [N] (3 = kinematic), material [N, k] (may require grad), bounds
    [[x_lo, x_hi], [y_lo, y_hi]] (m), or [N, 2, 2] per point. Differentiable w.r.t.
    material and the model. stop_speed (m per step): stop early once every soil point moved
    less than this per step over the last CHECK_EVERY steps (never before
    MIN_FRAMES_BEFORE_STOP dataset frames). graph [N]: the scene of each point when several
    are rolled out together (no edge joins two scenes; None: one scene).
    """
    device = simulator.vel_mean.device
    window = initial_positions.to(device).transpose(0, 1)  # [N, history, 2]
    particle_type = particle_type.to(device)
    material = material.to(device)
    graph = None if graph is None else graph.to(device)
    constraints = Constraints.of(particle_type, torch.as_tensor(bounds, dtype=window.dtype, device=device), window[:, 0],
                                 graph, simulator.point_spacing)
    frames = list(window.unbind(1))
    min_frames = math.ceil(MIN_FRAMES_BEFORE_STOP / simulator.frame_stride)  # in steps
    for step in tqdm(range(n_steps), disable=not progress, desc="GNS rollout", unit="step"):
        if checkpoint and torch.is_grad_enabled():
            nxt = recompute_in_backward(simulator.step, window, particle_type, material, constraints, graph, use_reentrant=False)
        else:
            nxt = simulator.step(window, particle_type, material, constraints, graph)
        frames.append(nxt)
        window = torch.cat([window[:, 1:], nxt[:, None]], dim=1)
        if (step + 1) % CHECK_EVERY == 0 or step + 1 == n_steps:
            if _check(frames, constraints, step, stop_speed, min_frames):
                break
    return torch.stack(frames)


def _check(frames, constraints: Constraints, step, stop_speed, min_frames) -> bool:
    """Raise on NaN; True when the flow has stopped (one host sync per CHECK_EVERY steps)."""
    recent = torch.stack(frames[-CHECK_EVERY - 1:]).detach()
    soil = constraints.movable
    speed = (recent[1:, soil] - recent[:-1, soil]).norm(dim=-1).amax() if soil.any() else recent.new_zeros(())
    finite, fastest = bool(torch.isfinite(recent[-1]).all()), float(speed)
    if not finite:
        raise RolloutDiverged(
            f"GNS rollout produced non-finite positions by step {step + 1}; the model is outside "
            "what it was trained on (check the material features, domain and radius)."
        )
    return stop_speed is not None and len(frames) >= min_frames and fastest < stop_speed


def start_window(initial: np.ndarray, velocity: np.ndarray, history: int, step_dt: float) -> np.ndarray:
    """[history, N, 2] float32 m: the window a rollout starts from, the scene at frame 0 (initial
    [N, 2] m) and before it each point moving at its frame-0 velocity ([N, 2] m/s), one model step
    (step_dt s) apart; a point at rest (zero velocity) is frame 0 held, as the scene at rest is.
    Training draws the same windows (runout.gns.windows), so a rollout starts where it learned to."""
    lag = step_dt * np.arange(history - 1, -1, -1, dtype=np.float64)  # s before frame 0: (history - 1) K dt, ..., 0
    window = np.asarray(initial, dtype=np.float64)[None] - lag[:, None, None] * np.asarray(velocity, dtype=np.float64)[None]
    return window.astype(np.float32)


def material_tensor(simulator: GraphNetworkSimulator, traj: Trajectory) -> torch.Tensor:
    """[N, k] material features of a trajectory, in the width the simulator expects."""
    return torch.from_numpy(traj.material_features(simulator.schema.material_width))


def rollout_trajectory(
    simulator: GraphNetworkSimulator,
    initial: Trajectory,
    n_frames: int,
    stop_speed: float | None = 0.05,
    progress: bool = False,
    from_rest: bool = True,
) -> Trajectory:
    """GNS trajectory over n_frames frames of `initial` (its frame_dt, frame 0 included):
    ceil((n_frames - 1) / K) + 1 frames K x initial.frame_dt apart for a model of frame stride
    K, the last at or beyond frame n_frames - 1; stop_speed in m/s (None: run all frames).

    from_rest (the default, and how every scene starts): the window is `initial`'s frame 0
    repeated, the points at rest, and the rollout's frame 0 is that frame; points that move at
    frame 0 (initial.start_velocity(): a scene region's `velocity`, or a trajectory's first-frame
    motion faster than START_SPEED) enter the window at that velocity (start_window). Otherwise the window
    is `initial`'s frames 0, K, ..., (history - 1) K (the public GNS's start from simulated
    frames), and they are the rollout's first frames."""
    return rollout_trajectories(simulator, [initial], n_frames, stop_speed, progress, from_rest)[0]


def rollout_trajectories(
    simulator: GraphNetworkSimulator,
    initials: list[Trajectory],
    n_frames: int,
    stop_speed: float | None = 0.05,
    progress: bool = False,
    from_rest: bool = True,
) -> list[Trajectory]:
    """rollout_trajectory for several scenes in one graph batch (one network call per step
    for all of them, each scene its own graph and domain): the same trajectories, to float32
    rounding; faster where a bigger graph fills the device (on a 2-core CPU it was not).
    A stop_speed stops them all once every scene has stopped."""
    history, stride = simulator.schema.history, simulator.frame_stride
    given = 1 if from_rest else history  # frames of each initial that its rollout starts from
    starts = [initial.every(stride) for initial in initials]
    for initial, start in zip(initials, starts):
        if not from_rest and start.n_frames < history:
            raise InputError(f"{initial.name} has {initial.n_frames} frames, fewer than the {simulator.window_frames} "
                             f"that the model's window of {history} positions at frame stride {stride} spans.")
    if len({s.frame_dt for s in starts}) > 1:
        raise InputError(f"{', '.join(t.name for t in initials)}: frames {sorted({t.frame_dt for t in initials})} s apart; "
                         "scenes rolled out together need one frame time step.")
    windows = [start_window(s.positions[0], initial.start_velocity(), history, s.frame_dt) if from_rest
               else s.positions[:history] for initial, s in zip(initials, starts)]
    sizes = [t.n_points for t in initials]
    one = len(initials) == 1  # one scene: one graph and one domain, as always
    bounds = initials[0].bounds if one else np.concatenate([np.repeat(t.bounds[None], t.n_points, 0) for t in initials])
    graph = None if one else torch.repeat_interleave(torch.arange(len(initials)), torch.tensor(sizes))
    per_step = None if stop_speed is None else stop_speed * starts[0].frame_dt  # m/s -> m per step
    with torch.no_grad():
        positions = rollout(
            simulator,
            torch.from_numpy(np.ascontiguousarray(np.concatenate(windows, axis=1))),
            torch.from_numpy(np.concatenate([t.particle_type for t in initials])),
            torch.cat([material_tensor(simulator, t) for t in initials]),
            max(math.ceil((n_frames - 1) / stride) + 1 - given, 0),
            bounds,
            progress=progress,
            stop_speed=per_step,
            graph=graph,
        )
    positions = positions[history - given:].cpu().numpy().astype(np.float32)  # from rest: the window's copies of frame 0 become one frame 0
    parts = np.split(positions, np.cumsum(sizes)[:-1], axis=1)
    return [
        Trajectory(
            part, initial.particle_type, initial.material_id, initial.materials, start.frame_dt, initial.bounds,
            initial.name, {"engine": "gns", "frames_requested": n_frames, "frame_stride": stride,
                           "start": "rest" if from_rest else "frames"},
        )
        for part, initial, start in zip(parts, initials, starts)
    ]
