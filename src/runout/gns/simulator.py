"""The learned simulator: features, normalisation and the position update, as in DeepMind's
learned_simulator (its noise, corrected target and loss are runout.gns.training's; the walls,
ground and overburden input runout.gns.features').

Step units throughout: positions in m, velocities v = x_t - x_{t-1} in m per step,
accelerations a = v_t - v_{t-1} in m per step^2, where a step spans schema.frame_stride
dataset frames (1 frame, 0.0375 s, unless trained with --frame-stride). The network
(runout.gns.network) sees only normalised, dimensionless features.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import torch
from torch import nn

from runout.contract import spacing_for_radius
from runout.defaults import PARTICLE_TYPE_KINEMATIC
from runout.gns.features import OVERBURDEN_SCALE, Constraints, overburden_depth
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



def normalisation_buffers(stats: Normalisation) -> dict[str, torch.Tensor]:
    """Means and scales of velocities and accelerations; the scales are the statistics widened
    by the training noise, as in the public GNS."""
    noise2 = stats.noise_std**2
    return {
        "vel_mean": torch.tensor(stats.vel_mean),
        "vel_scale": torch.tensor(stats.vel_std).square().add(noise2).sqrt(),
        "acc_mean": torch.tensor(stats.acc_mean),
        "acc_scale": torch.tensor(stats.acc_std).square().add(noise2).sqrt(),
    }


class GraphNetworkSimulator(nn.Module):
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
        for name, value in normalisation_buffers(stats).items():
            self.register_buffer(name, value)

    def use_statistics(self, stats: Normalisation) -> None:
        """Normalise with other dataset statistics from now on (same weights)."""
        self.stats = stats
        for name, value in normalisation_buffers(stats).items():
            getattr(self, name).copy_(value)

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

    def step(self, window, particle_type, material, constraints: Constraints, graph=None) -> torch.Tensor:
        """One rollout step: the next positions [N, 2] (m), kept within the constraints."""
        return constraints.constrain(self.next_positions(window, particle_type, material, constraints.bounds, graph), window[:, -1])
