"""The neural MPM: particles to grid, a U-Net predicting the grid velocities of the next m
frames at once, grid to particles (after NeuralMPM, Rochman-Sharabi, Lewin & Louppe, TMLR
2025; design only, no code of theirs).

One call, from the points' positions and their velocities over the last `history` frames:

1. particles to grid with the MPM's quadratic B-spline (runout.transfer) at the engine's cell
   size dx: per node the soil fill and the ground fill (the points' area spacing^2 / dx^2
   spread over the stencil, ~1 inside a full cell), the soil's mass-weighted mean velocity of
   each of the last `history` frames (m per frame / velocity_scale; with velocity_sweeps,
   sharpened towards the field that carries the points as they moved: `sharpened`), its mass-weighted
   material features [tan phi, c / 100 kPa], and two static masks: nodes on or outside the
   domain's walls, and nodes inside the domain;
2. the U-Net maps these channels to 2 m channels: the grid velocity (m per frame /
   velocity_scale) of each of the next m frames;
3. frame by frame, each soil point moves by the grid velocity interpolated at its current
   position, and is kept inside the domain (rigid walls); kinematic points (type 3, ground
   and foundations) never move.

The grid's node (i, j) lies at the domain's lower-left corner + (i - pad, j - pad) dx, with
`pad` nodes outside every wall and the sides rounded up to the U-Net's multiple, so a point
anywhere in the domain has its whole stencil on the grid. Every operation is a tensor
operation on the points' positions and material features, so a rollout is differentiable in
both (the inverse analysis runs through it).
"""

from __future__ import annotations

import math
from contextlib import contextmanager
from dataclasses import dataclass, field

import numpy as np
import torch
from torch import nn
from torch.utils.checkpoint import checkpoint as recompute_in_backward
from tqdm.auto import tqdm

from runout.defaults import PARTICLE_TYPE_KINEMATIC
from runout.errors import InputError, RolloutDiverged
from runout.neural_mpm.config import NeuralMPMConfig  # noqa: F401  (the engine's config, re-exported)
from runout.neural_mpm.unet import UNet
from runout.transfer import GridTransfer

ENGINE_NAME = "neural-mpm"
MIN_FRAMES_BEFORE_STOP = 40  # dataset frames: a slope at rest needs time to start failing
FILL_FLOOR = 0.05  # fill below which a node's mean velocity and material fade to zero (no soil there)


@dataclass
class Points:
    """A batch of scenes' points as one flat set: what a call needs besides the history."""

    fixed: torch.Tensor  # [P] bool, kinematic points
    material: torch.Tensor  # [P, k]
    scene: torch.Tensor  # [P] long, the point's scene in the batch
    bounds: torch.Tensor  # [B, 2, 2] m, [[x_lo, x_hi], [y_lo, y_hi]] of each scene
    lo: torch.Tensor = field(init=False)  # [P, 2] m
    hi: torch.Tensor = field(init=False)

    def __post_init__(self):
        self.lo = self.bounds[self.scene, :, 0]
        self.hi = self.bounds[self.scene, :, 1]

    @property
    def batch(self) -> int:
        return self.bounds.shape[0]


class NeuralMPM(nn.Module):
    """The engine; also the learned-engine contract (runout.learned.engine) every command uses."""

    name = ENGINE_NAME
    frame_stride = 1  # it steps through every dataset frame
    particle_types = 9  # type 3 is kinematic, every other type below 9 is soil

    def __init__(self, config: NeuralMPMConfig):
        super().__init__()
        self.config = config
        self.net = UNet(config.in_channels, 2 * config.frames_per_call, config.widths)
        self.data_ranges: dict | None = None  # what it was trained on (runout.learned.training_range)
        self.bf16 = False  # autocast the U-Net to bfloat16 (training's --bf16, inside bfloat16())

    @contextmanager
    def bfloat16(self, enabled: bool = True):
        """Inside the block (when enabled) the U-Net runs in bfloat16 autocast; the transfers
        between points and grid and the positions stay float32 (a bfloat16 position of 800 m
        would be off by up to 2 m)."""
        before, self.bf16 = self.bf16, enabled
        try:
            yield self
        finally:
            self.bf16 = before

    # ------------------------------------------------------------------ contract of a learned engine

    @property
    def point_spacing(self) -> float:
        return self.config.point_spacing

    @property
    def device(self) -> torch.device:
        return self.net.out.weight.device

    @property
    def material_width(self) -> int:
        return self.config.material_width

    def start_frames(self, from_rest: bool = True) -> int:
        if not from_rest:
            raise InputError("the neural MPM starts every run from rest (frame 0); --from-frames is the GNS's alone.")
        return 1

    def check_frames(self, frames: int, where: str, from_rest: bool = True) -> None:
        if frames < self.start_frames(from_rest) + 1:
            raise InputError(f"{where} = {frames} must be at least 2: frame 0 and the first frame the engine predicts.")

    def freeze(self) -> None:
        self.requires_grad_(False)

    def velocity_statistics(self) -> tuple[list[float], list[float]]:
        """Mean and standard deviation per axis of the soil's training velocities, m per frame
        (data_ranges' velocity_m_per_frame; without it, zero and velocity_scale)."""
        recorded = (self.data_ranges or {}).get("velocity_m_per_frame")
        if recorded:
            return list(recorded["mean"]), list(recorded["std"])
        return [0.0, 0.0], [self.config.velocity_scale] * 2

    def rollout_trajectory(self, start, n_frames: int, stop_speed: float | None = 0.05, progress: bool = False,
                           from_rest: bool = True):
        """The engine's run of `start`'s frame 0 (a Trajectory; its start_velocity() for points
        thrown at frame 0) over n_frames frames; with stop_speed (m/s), ends after the first
        call in which no soil point moved faster (never before MIN_FRAMES_BEFORE_STOP)."""
        from dataclasses import replace

        self.start_frames(from_rest)
        check_frame_dt(self, start.frame_dt, start.name)
        x0, velocity = start_state(start.positions[0], start.start_velocity())
        ptype = torch.from_numpy(np.asarray(start.particle_type))
        material = torch.from_numpy(start.material_features(self.material_width))
        with torch.inference_mode():  # no gradient wanted: autograd neither records nor checks versions
            frames = self.rollout(x0, ptype, material, np.asarray(start.bounds, dtype=np.float32), n_frames, velocity,
                                  stop_speed=None if stop_speed is None else stop_speed * self.config.frame_dt,
                                  progress=progress)
        info = {"engine": ENGINE_NAME, "frames_requested": n_frames, "frame_stride": 1, "start": "rest"}
        return replace(start, positions=frames.cpu().numpy().astype(np.float32), frame_dt=self.config.frame_dt,
                       info=info)

    def forward_model(self, initial, initial_velocity, particle_type, frame_dt: float, frames: list[int], steps: int,
                      bounds, checkpoint: bool = True, progress: bool = False):
        """Material features [N, k] -> positions [F, N, 2] (m) at `frames` of a rollout from rest
        over `steps` frames, differentiable in the features (runout.learned.engine)."""
        check_frame_dt(self, frame_dt, "the observation")
        x0, velocity = start_state(initial, initial_velocity)
        ptype = torch.as_tensor(np.asarray(particle_type))
        chosen = torch.tensor(frames, device=self.device)
        box = np.asarray(bounds, dtype=np.float32)

        def forward(features: torch.Tensor) -> torch.Tensor:
            return self.rollout(x0, ptype, features, box, steps + 1, velocity, checkpoint=checkpoint,
                                progress=progress)[chosen]

        return forward

    # ------------------------------------------------------------------ the grid

    def grid(self, bounds: torch.Tensor) -> tuple[torch.Tensor, tuple[int, int]]:
        """Origins [B, 2] (m) and the common (NX, NY) of the grids of scenes with bounds [B, 2, 2]."""
        dx, pad, mult = self.config.cell_size, self.config.pad, self.net.multiple
        size = (bounds[:, :, 1] - bounds[:, :, 0]).amax(0)
        cells = [math.ceil(float(s) / dx - 1e-9) for s in size]
        shape = tuple(mult * math.ceil((c + 1 + 2 * pad) / mult) for c in cells)
        return bounds[:, :, 0] - pad * dx, shape

    def layout(self, bounds: torch.Tensor) -> tuple[torch.Tensor, tuple[int, int], torch.Tensor]:
        """(origins, (NX, NY), static channels) of the grids of scenes with bounds [B, 2, 2]."""
        origin, shape = self.grid(bounds)
        return origin, shape, self.static_channels(bounds, origin, shape)

    def static_channels(self, bounds: torch.Tensor, origin: torch.Tensor, shape: tuple[int, int]) -> torch.Tensor:
        """[B, 2, NX, NY]: nodes on or outside a wall (1), nodes strictly inside the domain (1)."""
        dx = self.config.cell_size
        i = torch.arange(shape[0], dtype=bounds.dtype, device=bounds.device)
        j = torch.arange(shape[1], dtype=bounds.dtype, device=bounds.device)
        x = origin[:, 0, None, None] + i[None, :, None] * dx  # [B, NX, 1]
        y = origin[:, 1, None, None] + j[None, None, :] * dx  # [B, 1, NY]
        tol = 1e-6 * dx
        inside = ((x > bounds[:, 0, 0, None, None] + tol) & (x < bounds[:, 0, 1, None, None] - tol)
                  & (y > bounds[:, 1, 0, None, None] + tol) & (y < bounds[:, 1, 1, None, None] - tol))
        return torch.stack((~inside, inside), 1).to(bounds.dtype)

    # ------------------------------------------------------------------ one call

    def call(self, x: torch.Tensor, velocities: torch.Tensor, pts: Points, static: torch.Tensor,
             origin: torch.Tensor, shape: tuple[int, int]) -> torch.Tensor:
        """Positions [m, P, 2] (m) of the next m frames from positions x [P, 2] (m) and the last
        `history` frame velocities [history, P, 2] (m per frame, oldest first)."""
        cfg = self.config
        dx = cfg.cell_size
        grid_shape = (pts.batch, *shape)
        point_origin = origin[pts.scene]
        transfer = _transfer(x, pts, point_origin, dx, grid_shape)
        area = (cfg.point_spacing / dx) ** 2
        soil = (~pts.fixed).to(x.dtype)[:, None] * area
        ground = pts.fixed.to(x.dtype)[:, None] * area
        vel = velocities.permute(1, 0, 2).reshape(x.shape[0], -1) / cfg.velocity_scale
        g = transfer.to_grid(torch.cat([soil, ground, soil * vel, soil * pts.material], 1))
        fill = g[:, :1]
        fade = 1.0 / torch.clamp(fill, min=FILL_FLOOR)
        means = g[:, 2:] * fade
        if cfg.velocity_sweeps:
            means = torch.cat([sharpened(transfer, vel, soil, means[:, :vel.shape[1]], fade, cfg.velocity_sweeps),
                               means[:, vel.shape[1]:]], 1)
        inputs = torch.cat([fill, g[:, 1:2], means, static], 1)
        with torch.autocast(self.device.type, dtype=torch.bfloat16, enabled=self.bf16):
            out = self.net(inputs)
        grid_velocity = out.to(inputs.dtype) * cfg.velocity_scale  # [B, 2 m, NX, NY] m per frame (bf16 back to the points' type)
        moving = (~pts.fixed)[:, None]
        frames = []
        for k in range(cfg.frames_per_call):
            here = transfer if k == 0 else _transfer(x, pts, point_origin, dx, grid_shape)
            v = here.to_points(grid_velocity[:, 2 * k:2 * k + 2])
            x = torch.where(moving, torch.minimum(torch.maximum(x + v, pts.lo), pts.hi), x)
            frames.append(x)
        return torch.stack(frames)

    # ------------------------------------------------------------------ rollouts

    def rollout(self, positions: torch.Tensor, particle_type: torch.Tensor, material: torch.Tensor,
                bounds, n_frames: int, start_velocity: torch.Tensor | None = None, scene: torch.Tensor | None = None,
                checkpoint: bool = False, stop_speed: float | None = None, progress: bool = False) -> torch.Tensor:
        """Positions [n_frames, P, 2] (m), frame 0 = positions [P, 2] (m), one frame every
        frame_dt. start_velocity [P, 2] m/s at frame 0 (None: at rest, how every scene starts);
        material [P, k] (may require grad); bounds [2, 2] m, or [B, 2, 2] with scene [P] the
        point's scene when several scenes run together. checkpoint: recompute each call in the
        backward pass (memory of one call instead of all). stop_speed (m per frame): end after
        the first call, past MIN_FRAMES_BEFORE_STOP, in which no soil point moved faster (fewer
        frames come back)."""
        cfg = self.config
        device = self.device
        x = positions.to(device)
        bounds = torch.as_tensor(bounds, dtype=x.dtype, device=device)
        if bounds.dim() == 2:
            bounds = bounds[None]
        scene = torch.zeros(x.shape[0], dtype=torch.long, device=device) if scene is None else scene.to(device)
        pts = Points(particle_type.to(device) == PARTICLE_TYPE_KINEMATIC, material.to(device, x.dtype), scene, bounds)
        step = (torch.zeros_like(x) if start_velocity is None
                else torch.as_tensor(start_velocity, dtype=x.dtype, device=device) * cfg.frame_dt)
        velocities = step[None].expand(cfg.history, -1, -1)
        calls = math.ceil((n_frames - 1) / cfg.frames_per_call)
        layout = self.layout(pts.bounds)  # the same grid for every call
        out = [x[None]]
        for k in tqdm(range(calls), disable=not progress, desc="neural MPM rollout", unit="call"):
            frames, velocities = self.advance(out[-1][-1], velocities, pts, 1, checkpoint, keep_velocities=True,
                                              layout=layout)
            out.append(frames)
            if not bool(torch.isfinite(frames[-1]).all()):
                raise RolloutDiverged(f"the neural MPM produced non-finite positions by frame {(k + 1) * cfg.frames_per_call}.")
            done = (k + 1) * cfg.frames_per_call
            if stop_speed is not None and done >= MIN_FRAMES_BEFORE_STOP and not torch.is_grad_enabled():
                if float(velocities[:, ~pts.fixed].norm(dim=-1).amax()) < stop_speed:
                    break
        return torch.cat(out)[:n_frames]

    def advance(self, x: torch.Tensor, velocities: torch.Tensor, pts: Points, calls: int,
                checkpoint: bool = False, keep_velocities: bool = False, layout: tuple | None = None):
        """Positions [calls m, P, 2] of the frames after x [P, 2], chaining `calls` calls (and the
        last `history` frame velocities after them when keep_velocities). layout: self.layout of
        pts.bounds, when the caller keeps it from call to call."""
        origin, shape, static = self.layout(pts.bounds) if layout is None else layout
        h = self.config.history
        out = []
        for _ in range(calls):
            if checkpoint and torch.is_grad_enabled():
                frames = recompute_in_backward(self.call, x, velocities, pts, static, origin, shape, use_reentrant=False)
            else:
                frames = self.call(x, velocities, pts, static, origin, shape)
            chain = torch.cat([x[None], frames])
            velocities = torch.cat([velocities, chain[1:] - chain[:-1]])[-h:]
            x = frames[-1]
            out.append(frames)
        return (torch.cat(out), velocities) if keep_velocities else torch.cat(out)


def sharpened(transfer: GridTransfer, values: torch.Tensor, soil: torch.Tensor, grid: torch.Tensor,
              fade: torch.Tensor, sweeps: int) -> torch.Tensor:
    """The grid field [B, C, NX, NY] whose interpolation at the points comes closer to their
    values [P, C]: from their mass-weighted mean per node (grid), `sweeps` Richardson sweeps
    preconditioned by the nodes' mass, grid += P2G(mass x (values - G2P(grid))) / mass, towards
    the least-squares field. The mean alone smooths a front's speed away (a field that carries
    every point as the MPM did exists at the engine's cells; the mean carries a dam's front
    9-31 % short: experiments/neural_mpm_grid_floor.py); with it the U-Net has to sharpen, with
    the swept field keeping a velocity is a copy. Nodes below FILL_FLOOR stay damped by `fade`
    (1 / max(fill, FILL_FLOOR)), as the mean is."""
    for _ in range(sweeps):
        grid = grid + transfer.to_grid(soil * (values - transfer.to_points(grid))) * fade
    return grid


def _transfer(x, pts: Points, point_origin, dx, grid_shape) -> GridTransfer:
    return GridTransfer(x - point_origin, pts.scene, dx, grid_shape)


def check_frame_dt(engine: NeuralMPM, frame_dt: float, source) -> None:
    """InputError unless a trajectory's frames are the engine's frame_dt apart."""
    if not math.isclose(frame_dt, engine.config.frame_dt, rel_tol=1e-6):
        raise InputError(f"{source}: frames are {frame_dt:g} s apart but the neural MPM steps {engine.config.frame_dt:g} s; "
                         "give a trajectory at the engine's frame spacing.")


def start_state(initial: np.ndarray, velocity: np.ndarray | None) -> tuple[torch.Tensor, torch.Tensor | None]:
    """Tensors of a scene's frame 0 (m) and its start velocity (m/s; None when at rest)."""
    x = torch.as_tensor(np.asarray(initial, dtype=np.float32))
    if velocity is None or not np.any(velocity):
        return x, None
    return x, torch.as_tensor(np.asarray(velocity, dtype=np.float32))
