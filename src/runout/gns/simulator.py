"""The learned simulator: features, normalisation, noise, the noise-corrected target, the
loss mask and the position update, as in DeepMind's learned_simulator.

Step units throughout: positions in m, velocities v = x_t - x_{t-1} in m per step,
accelerations a = v_t - v_{t-1} in m per step^2, where a step spans schema.frame_stride
dataset frames (1 frame, 0.0375 s, unless trained with --frame-stride). The network
(runout.gns.network) sees only normalised, dimensionless features.

Training, rollout and the inverse tell one story with one Case (the domain bounds, which
points move, the wall clamp):

    case = Case.of(particle_type, bounds, positions, graph, simulator.point_spacing)
    window = simulator.pushforward(window, n, particle_type, material, case)            # train, n >= 0 steps
    noisy, target = simulator.training_inputs(window, next_position, case, generator)   # train
    loss = simulator.loss(simulator(noisy, particle_type, material, case.bounds), target, case)
    next_position = simulator.step(window, particle_type, material, case)                # rollout
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import torch
from torch import nn

from runout.contract import spacing_for_radius
from runout.defaults import PARTICLE_TYPE_KINEMATIC
from runout.gns.graph import radius_graph
from runout.gns.network import EncodeProcessDecode
from runout.gns.schema import FeatureSchema, NetworkConfig


@dataclass(frozen=True)
class Normalisation:
    """Dataset statistics in step units (stride-K differences for a model of frame stride
    K), and the training noise they are widened by."""

    vel_mean: tuple[float, float]  # m / step
    vel_std: tuple[float, float]
    acc_mean: tuple[float, float]  # m / step^2
    acc_std: tuple[float, float]
    noise_std: float  # m / step: velocity noise (runout train --noise times the data's velocity std)

    @classmethod
    def from_metadata(cls, meta: dict, noise_std: float) -> "Normalisation":
        pick = lambda k: tuple(float(x) for x in meta[k])  # noqa: E731
        return cls(pick("vel_mean"), pick("vel_std"), pick("acc_mean"), pick("acc_std"), float(noise_std))

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict) -> "Normalisation":
        return cls(tuple(d["vel_mean"]), tuple(d["vel_std"]), tuple(d["acc_mean"]), tuple(d["acc_std"]), d["noise_std"])

    @staticmethod
    def problem(d: dict) -> str | None:
        """The first malformed statistic of a stored dictionary, as a phrase, or None."""
        for key in ("vel_mean", "vel_std", "acc_mean", "acc_std"):
            v = d[key]
            if not isinstance(v, (list, tuple)) or len(v) != 2 or not all(_finite(x) for x in v):
                return f"{key} = {v!r} must be a pair of finite numbers (m per step)"
            if key.endswith("std") and min(v) < 0:
                return f"{key} = {list(v)} must not be negative"
        if not _finite(d["noise_std"]) or not 0 <= d["noise_std"] <= MAX_NOISE_PER_STEP:
            return f"noise_std = {d['noise_std']!r} is outside the allowed range [0, {MAX_NOISE_PER_STEP:g}] m per step"
        return None


# m / step: noise far beyond any per-step displacement of soil, yet above the largest noise
# `runout train` allows (10 m/s x 0.0375 s x 16 frames = 6 m)
MAX_NOISE_PER_STEP = 10.0
def _finite(x) -> bool:
    return isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x)


@dataclass(frozen=True)
class Ground:
    """The rigid ground of one or more scenes, as the lowest height a soil point may take in
    each vertical column (m): the centre of the column's topmost kinematic point less
    GROUND_TOLERANCE point spacings (none where a column has no ground: -inf)."""

    floor: torch.Tensor  # [G, C] m
    width: float  # m, column width (one point spacing), columns from x = 0

    @classmethod
    def of(cls, positions: torch.Tensor, kinematic: torch.Tensor, graph: torch.Tensor | None, spacing: float) -> "Ground":
        col = torch.floor(positions[:, 0] / spacing).long().clamp(min=0)
        g = torch.zeros_like(col) if graph is None else graph.long()
        n_graphs, n_cols = int(g.max()) + 1 if len(g) else 1, int(col.max()) + 1 if len(col) else 1
        floor = torch.full((n_graphs * n_cols,), -math.inf, dtype=positions.dtype, device=positions.device)
        if kinematic.any():
            floor = floor.scatter_reduce(0, (g * n_cols + col)[kinematic], positions[kinematic, 1], "amax")
        return cls((floor - GROUND_TOLERANCE * spacing).reshape(n_graphs, n_cols), float(spacing))

    def floor_at(self, positions: torch.Tensor, graph: torch.Tensor | None) -> torch.Tensor:
        """The floor (m) of the column each of positions [N, 2] stands in."""
        col = torch.floor(positions[:, 0] / self.width).long().clamp(0, self.floor.shape[1] - 1)
        g = torch.zeros_like(col) if graph is None else graph.long()
        return self.floor[g, col].to(positions.dtype)

    def clamp(self, predicted: torch.Tensor, current: torch.Tensor, graph: torch.Tensor | None) -> torch.Tensor:
        """predicted [N, 2] kept out of the ground by the points now above it (at `current`):
        one that would sink below its column's floor is raised to it, and one that would move
        sideways into a column whose floor is above it (a step of the ground) keeps its x, as
        at a wall. A point now below its column's floor (under an overhang of a fixed region)
        is left alone."""
        here, there = self.floor_at(current, graph), self.floor_at(predicted, graph)
        above = current[:, 1] >= here
        blocked = above & (current[:, 1] < there)
        x = torch.where(blocked, current[:, 0], predicted[:, 0])
        floor = torch.where(blocked, here, there)
        y = torch.where(above, torch.maximum(predicted[:, 1], floor), predicted[:, 1])
        return torch.stack([x, y], dim=1)


# point spacings below the centre of a column's topmost ground point that a soil point may
# reach: the MPM's soil stays within 0.85 m (0.21 spacings) of it on 16 validation scenes of
# data/ft8 over all 480 frames, stepped ground included (docs/gns.md)
GROUND_TOLERANCE = 0.25


@dataclass(frozen=True)
class Case:
    """The setup a graph batch is simulated in (LagrangeBench's case setup): the domain
    bounds [[x_lo, x_hi], [y_lo, y_hi]] (m; [2, 2], or [N, 2, 2] per point), the mask of
    the points that move (not kinematic, type 3) and, when given, the rigid ground and the
    scene of each point. Kinematic points keep their positions; moving points are clamped
    into the domain (the rigid walls) and kept out of the ground (the MPM's fixed ground
    nodes, which soil does not pass)."""

    bounds: torch.Tensor
    movable: torch.Tensor  # [N] bool
    ground: Ground | None = None
    graph: torch.Tensor | None = None  # [N] scene of each point (None: one scene)

    @classmethod
    def of(cls, particle_type: torch.Tensor, bounds, positions: torch.Tensor | None = None,
           graph: torch.Tensor | None = None, spacing: float | None = None) -> "Case":
        """positions [N, 2] (m) and spacing (m): also keep soil out of the ground that the
        kinematic points among them fill."""
        bounds = torch.as_tensor(bounds, device=particle_type.device)
        movable = particle_type != PARTICLE_TYPE_KINEMATIC
        ground = None if positions is None or spacing is None else Ground.of(positions, ~movable, graph, spacing)
        return cls(bounds, movable, ground, graph)

    def constrain(self, predicted: torch.Tensor, current: torch.Tensor) -> torch.Tensor:
        """Predicted positions [N, 2] with kinematic points held at `current`, every point
        clamped into the domain and, with a ground, no soil point below its column's floor."""
        if self.ground is not None:
            predicted = self.ground.clamp(predicted, current, self.graph)
        predicted = torch.where(self.movable[:, None], predicted, current)
        return torch.clamp(predicted, self.bounds[..., 0], self.bounds[..., 1])


def _normalisation_buffers(stats: Normalisation) -> dict[str, torch.Tensor]:
    """Means and scales of velocities and accelerations; the scales are the statistics widened
    by the training noise, as in the public GNS."""
    noise2 = stats.noise_std**2
    return {
        "vel_mean": torch.tensor(stats.vel_mean),
        "vel_scale": torch.tensor(stats.vel_std).square().add(noise2).sqrt(),
        "acc_mean": torch.tensor(stats.acc_mean),
        "acc_scale": torch.tensor(stats.acc_std).square().add(noise2).sqrt(),
    }


class Simulator(nn.Module):
    """GNS: maps a window of `schema.history` positions per point to the next positions."""

    def __init__(self, schema: FeatureSchema, stats: Normalisation, radius: float, config: NetworkConfig = NetworkConfig()):
        super().__init__()
        self.schema = schema
        self.stats = stats
        self.radius = float(radius)  # m, connectivity radius R
        self.config = config
        self.data_ranges: dict | None = None  # what it was trained on (runout.learned.training_range)
        self.type_embedding = nn.Embedding(schema.particle_types, schema.type_embedding)
        self.network = EncodeProcessDecode(
            schema.node_width, schema.edge_width, schema.dim,
            config.latent, config.hidden, config.hidden_layers, config.message_passing_steps,
        )
        for name, value in _normalisation_buffers(stats).items():
            self.register_buffer(name, value)

    def use_statistics(self, stats: Normalisation) -> None:
        """Normalise with other dataset statistics from now on (same weights)."""
        self.stats = stats
        for name, value in _normalisation_buffers(stats).items():
            getattr(self, name).copy_(value)

    def renormalise(self, stats: Normalisation) -> None:
        """Normalise with `stats` from now on, the weights changed so that the model predicts
        the same next positions (up to rounding): the node encoder's velocity columns and the
        decoder's last layer absorb the change of the velocity and acceleration scales and means.

        Fine-tuning at another noise needs this: the scales are widened by the training noise,
        and a model that keeps a noisier base's scales learns its targets as a small fraction of
        its output range (noise 0.3 widens the acceleration scale about 20x past the data's)."""
        old = {name: getattr(self, name).detach().clone().double() for name in ("vel_mean", "vel_scale", "acc_mean", "acc_scale")}
        new = {name: value.double() for name, value in _normalisation_buffers(stats).items()}
        with torch.no_grad():
            # velocity inputs: (v - m) / s = ((v - m') / s') * (s' / s) + (m' - m) / s, per column (history - 1 steps x dim)
            first = self.network.node_encoder[0]
            n_vel = (self.schema.history - 1) * self.schema.dim
            ratio = (new["vel_scale"] / old["vel_scale"]).repeat(self.schema.history - 1)
            shift = ((new["vel_mean"] - old["vel_mean"]) / old["vel_scale"]).repeat(self.schema.history - 1)
            w = first.weight[:, :n_vel].double()
            first.bias.add_((w @ shift).to(first.bias.dtype))
            first.weight[:, :n_vel] = (w * ratio).to(first.weight.dtype)
            # accelerations: y' a' + m' = y a + m, so y' = y (a / a') + (m - m') / a'
            last = self.network.decoder[-1]
            scale = old["acc_scale"] / new["acc_scale"]
            last.weight.copy_((last.weight.double() * scale[:, None]).to(last.weight.dtype))
            last.bias.copy_(((last.bias.double() * old["acc_scale"] + old["acc_mean"] - new["acc_mean"]) / new["acc_scale"]).to(last.bias.dtype))
        self.use_statistics(stats)

    @property
    def frame_stride(self) -> int:
        """Dataset frames per step (schema.frame_stride; 1 for checkpoints that record none)."""
        return self.schema.frame_stride

    @property
    def window_frames(self) -> int:
        """Dataset frames one input window spans: (history - 1) x frame_stride + 1."""
        return self.schema.window_frames

    @property
    def point_spacing(self) -> float:
        """The lattice spacing (m) of the points the model was trained on: its data_ranges'
        point_spacing_m, or the spacing of its radius (runout.contract) for a checkpoint that records none.
        Scenes are filled at this spacing for the model (runout.learned.scenes.at_model_spacing)."""
        recorded = (self.data_ranges or {}).get("point_spacing_m")
        return float(recorded) if recorded else spacing_for_radius(self.radius)

    def forward(self, window, particle_type, material, bounds, graph=None, recompute_steps: bool = False) -> torch.Tensor:
        """Normalised acceleration [N, 2] from window [N, history, 2] (m), particle_type [N],
        material [N, k], bounds [2, 2] or [N, 2, 2] ([[x_lo, x_hi], [y_lo, y_hi]], m) and the
        graph index of each point [N] (None: one graph). recompute_steps: recompute each
        processor step in the backward pass (training with less memory)."""
        senders, receivers = radius_graph(window[:, -1], self.radius, graph)
        nodes = self.node_features(window, particle_type, material, bounds, graph)
        edges = self.edge_features(window[:, -1], senders, receivers)
        return self.network(nodes, edges, senders, receivers, recompute_steps)

    def node_features(self, window, particle_type, material, bounds, graph=None) -> torch.Tensor:
        velocity = (window[:, 1:] - window[:, :-1] - self.vel_mean) / self.vel_scale  # [N, history-1, 2]
        x = window[:, -1]
        clip = self.schema.wall_clip
        lo, hi = bounds[..., 0], bounds[..., 1]
        walls = torch.cat([(x - lo) / self.radius, (hi - x) / self.radius], dim=1).clamp(-clip, clip)
        parts = [velocity.flatten(1), walls]
        if self.schema.overburden:
            spacing = spacing_for_radius(self.radius)
            depth = overburden_depth(x, particle_type != PARTICLE_TYPE_KINEMATIC, graph, 2 * spacing, spacing**2)
            parts.append((depth / OVERBURDEN_SCALE)[:, None].to(x.dtype))
        parts += [self.type_embedding(particle_type), material.to(x.dtype)]
        return torch.cat(parts, dim=1)

    def edge_features(self, x, senders, receivers) -> torch.Tensor:
        displacement = (x[senders] - x[receivers]) / self.radius
        return torch.cat([displacement, displacement.norm(dim=1, keepdim=True)], dim=1)

    def normalise_acceleration(self, acceleration: torch.Tensor) -> torch.Tensor:
        return (acceleration - self.acc_mean) / self.acc_scale

    def next_positions(self, window, particle_type, material, bounds, graph=None) -> torch.Tensor:
        """Semi-implicit Euler in step units: v' = (x_t - x_{t-1}) + a, x' = x_t + v'."""
        acceleration = self(window, particle_type, material, bounds, graph).float() * self.acc_scale + self.acc_mean
        velocity = window[:, -1] - window[:, -2] + acceleration
        return window[:, -1] + velocity

    def step(self, window, particle_type, material, case: Case, graph=None) -> torch.Tensor:
        """One rollout step: the next positions [N, 2] (m), constrained by the case."""
        return case.constrain(self.next_positions(window, particle_type, material, case.bounds, graph), window[:, -1])

    @torch.no_grad()
    def pushforward(self, window, steps: int, particle_type, material, case: Case, graph=None) -> torch.Tensor:
        """The window [N, history, 2] (m) after `steps` rollout steps of this model from
        `window`, without gradient: each step appends its prediction, constrained as in
        `step`, and drops the oldest position, as runout.gns.rollout does (Brandstetter et
        al. 2022's pushforward: training inputs that carry the model's own errors)."""
        for _ in range(steps):
            nxt = self.step(window, particle_type, material, case, graph)
            window = torch.cat([window[:, 1:], nxt[:, None]], dim=1)
        return window

    def training_inputs(self, window, next_position, case: Case, generator: torch.Generator,
                        held: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor]:
        """(noisy window [N, history, 2] m, normalised noise-corrected target acceleration
        [N, 2]): random-walk noise of std stats.noise_std on the moving points' inputs, none
        on the `held` [N] leading positions that are the scene at rest (exact in a rollout)."""
        noise = random_walk_noise(window, self.stats.noise_std, case.movable, generator, held)
        noisy = window + noise
        return noisy, self.normalise_acceleration(corrected_target(noisy, next_position, noise))

    @staticmethod
    def loss(predicted: torch.Tensor, target: torch.Tensor, case: Case, weights: torch.Tensor | None = None) -> torch.Tensor:
        """Mean squared error of the normalised accelerations over the movable (not kinematic)
        points, each weighted by `weights` [N] when given (a weighted mean)."""
        error = (predicted.float() - target).square().sum(dim=1)
        w = case.movable.to(error.dtype) if weights is None else case.movable * weights
        return (error * w).sum() / w.sum().clamp(min=1e-12)


OVERBURDEN_SCALE = 100.0  # m: the overburden input is the depth of soil above a point over this


@torch.no_grad()
def overburden_depth(x: torch.Tensor, soil: torch.Tensor, graph: torch.Tensor | None, column: float, area: float) -> torch.Tensor:
    """Depth (m) of the soil above each point [N]: the soil points (`soil` [N] bool) strictly
    higher than it in its vertical column (columns `column` m wide from x = 0, two point
    spacings in the model: one MPM cell of 2 x 2 points; one set per
    graph), each standing for `area` m² of soil, spread over the column's width. At rest it is
    the depth below the surface (to a point spacing), the overburden that sets a point's
    geostatic stress, γ times this depth; a point sees only 46 m around it through 5
    message-passing steps of 9.2 m, less than the height of most slopes. No gradient: the
    count is piecewise constant in the positions."""
    n = x.shape[0]
    col = torch.floor(x[:, 0] / column).long()
    col = col - col.min() if n else col
    g = torch.zeros_like(col) if graph is None else graph.long()
    key = g * (int(col.max()) + 1 if n else 1) + col
    by_height = torch.argsort(x[:, 1], descending=True, stable=True)
    order = by_height[torch.argsort(key[by_height], stable=True)]  # by column, then from the top down
    counted = soil[order].long()
    before = torch.cumsum(counted, 0) - counted  # soil points earlier in the order (all columns)
    sorted_key, sorted_y = key[order], x[order, 1]
    starts_column = torch.ones(n, dtype=torch.bool, device=x.device)
    starts_column[1:] = sorted_key[1:] != sorted_key[:-1]
    starts_level = starts_column.clone()  # points at one height (at rest: one lattice row) are not above each other
    starts_level[1:] |= sorted_y[1:] != sorted_y[:-1]
    index = torch.arange(n, device=x.device)
    column_start = torch.cummax(torch.where(starts_column, index, 0), 0).values
    level_start = torch.cummax(torch.where(starts_level, index, 0), 0).values
    above = before[level_start] - before[column_start]
    depth = torch.empty(n, dtype=x.dtype, device=x.device)
    depth[order] = above.to(x.dtype) * (area / column)
    return depth


def random_walk_noise(window: torch.Tensor, noise_std: float, movable: torch.Tensor, generator: torch.Generator,
                      held: torch.Tensor | None = None):
    """Position noise [N, history, 2] (m) whose velocities are a random walk: each of the
    history - 1 velocity increments ~ N(0, noise_std^2 / (history - 1)), so the last input
    velocity carries noise of std noise_std; the first position is untouched and kinematic
    points get none. With held [N], a point's first held positions (the scene at rest, which a
    rollout starts from exactly) get none either: the walk starts at the last of them, as a
    rollout's error starts growing only with its first step."""
    n, history, dim = window.shape
    step = torch.randn((n, history - 1, dim), generator=generator, device=window.device, dtype=window.dtype)
    if held is not None:  # increment i moves position i + 1: none while that position is still held
        step = step * (torch.arange(1, history, device=window.device)[None, :, None] >= held[:, None, None])
    velocity_noise = torch.cumsum(step * (noise_std / (history - 1) ** 0.5), dim=1)
    position_noise = torch.cat([torch.zeros_like(window[:, :1]), torch.cumsum(velocity_noise, dim=1)], dim=1)
    return position_noise * movable[:, None, None]


def corrected_target(noisy_window: torch.Tensor, next_position: torch.Tensor, noise: torch.Tensor) -> torch.Tensor:
    """Target acceleration (m / step^2) for noisy inputs. The next position is moved by the
    same noise as the current one (public recipe), so the update with this acceleration
    gives x_t + noise_t + (x_{t+1} - x_t): the true next velocity from the noisy position."""
    target = next_position + noise[:, -1]
    return (target - noisy_window[:, -1]) - (noisy_window[:, -1] - noisy_window[:, -2])
