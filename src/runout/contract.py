"""The GNS contract, below everything that reads or writes GNS data: torch-free.

What a scene, a trajectory file, a dataset and a checkpoint agree on, one owner each:

    material codec      a material enters the GNS as [tan phi, c / 100 kPa] (paper Table 1,
                        note a; a base model reads only the first column): encode_material,
                        decode_material, decode_materials, MATERIAL_FEATURE_NAMES
    history             HISTORY = 6 positions per input window (5 velocities)
    radius per spacing  the connectivity radius is RADIUS_PER_SPACING point spacings
                        (radius_for_spacing, spacing_for_radius); the points sit
                        cell_size / points_per_cell apart (spacing_for_cells)
    FeatureSchema       the node-feature layout stored in every checkpoint, and the frames
                        a rollout starts from and needs (start_frames, check_frames)
    NetworkConfig       the layer sizes every checkpoint stores, NETWORK_LIMITS their
                        allowed range, MAX_STEPS the most training steps one records

Node features, in this column order (material features last, so a model can be widened
with one more material input by appending zero columns to the encoder's first layer):

    velocities   (history - 1) x dim   normalised per-step velocities, oldest first
    walls        2 x dim               clip((x - lo) / R), clip((hi - x) / R) per dimension
    type         type_embedding        learned embedding of the particle type
    material     len(material_features) e.g. [tan phi, c / 100 kPa]

A step spans `frame_stride` dataset frames: the window holds the positions at frames t,
t + K, ..., t + (history - 1) K, the velocities are differences over K frames and the model
predicts frame t + history K (K = 1: every frame, the paper's GNS). Every rollout starts from
rest: its window is frame 0 held, so it needs frame 0 and predicts frame K first.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields

import numpy as np

from runout.defaults import PARTICLE_TYPE_SOIL, POINTS_PER_CELL
from runout.errors import InputError

MATERIAL_FEATURE_NAMES = ("tan_phi", "c_over_100kPa")  # the order of encode_material
COHESION_SCALE = 100.0  # kPa: the second material feature is c / COHESION_SCALE
HISTORY = 6  # positions per input window -> 5 velocities
# Default connectivity radius as a multiple of the point spacing: 2.3 x 2 m = 4.6 m gives
# ~16 neighbours per point at 4 points per 4 m cell.
RADIUS_PER_SPACING = 2.3
MAX_RADIUS = 1000.0  # m: a connectivity radius beyond this would join a whole domain into one clique
# Allowed [lowest, highest] of the numeric fields a checkpoint stores; every type table holds
# the kinematic (3) and soil (6) types a scene fills.
SCHEMA_LIMITS = {
    "history": (2, 20), "dim": (2, 2), "wall_clip": (0.0, 100.0), "particle_types": (PARTICLE_TYPE_SOIL + 1, 64),
    "type_embedding": (1, 256), "frame_stride": (1, 16),
}

MAX_STEPS = 1_000_000_000  # the most training steps a checkpoint may record (as `runout train --steps` allows)
# Allowed layer sizes: [lowest, highest] of each NetworkConfig field.
NETWORK_LIMITS = {"latent": (1, 1024), "hidden": (1, 1024), "hidden_layers": (1, 8), "message_passing_steps": (1, 50)}


@dataclass(frozen=True)
class NetworkConfig:
    """The layer sizes of the encode-process-decode network, stored in every checkpoint."""

    latent: int = 128
    hidden: int = 128
    hidden_layers: int = 2
    message_passing_steps: int = 10

    @staticmethod
    def problem(d: dict) -> str | None:
        """The first layer size outside NETWORK_LIMITS, as a phrase, or None."""
        for key, (lo, hi) in NETWORK_LIMITS.items():
            v = d.get(key, getattr(NetworkConfig, key))
            if isinstance(v, bool) or not isinstance(v, int) or not lo <= v <= hi:
                return f"{key} = {v!r} is outside the allowed range [{lo}, {hi}] (a whole number)"
        return None


# ----------------------------------------------------------------------------- spacing and radius


def spacing_for_cells(cell_size: float, points_per_cell: int = POINTS_PER_CELL) -> float:
    """Point spacing (m) of a lattice of points_per_cell x points_per_cell points per cell."""
    return cell_size / points_per_cell


def radius_for_spacing(spacing: float) -> float:
    """The default connectivity radius (m) of points `spacing` m apart."""
    return RADIUS_PER_SPACING * spacing


def spacing_for_radius(radius: float) -> float:
    """The point spacing (m) whose default connectivity radius is `radius` m."""
    return radius / RADIUS_PER_SPACING


# ----------------------------------------------------------------------------- node-feature schema


@dataclass(frozen=True)
class FeatureSchema:
    history: int = HISTORY  # positions per input window -> history - 1 velocities
    dim: int = 2
    wall_clip: float = 1.0  # wall distances / R are clipped to [-wall_clip, wall_clip]
    particle_types: int = 9
    type_embedding: int = 16
    material_features: tuple[str, ...] = MATERIAL_FEATURE_NAMES
    frame_stride: int = 1  # dataset frames per step (checkpoints without it: 1)
    overburden: bool = False  # a node input: the depth of soil above each point in its column (checkpoints without it: none)

    @property
    def window_frames(self) -> int:
        """Dataset frames one input window spans: (history - 1) x frame_stride + 1."""
        return (self.history - 1) * self.frame_stride + 1

    def start_frames(self, from_rest: bool = True) -> int:
        """Dataset frames a rollout starts from: frame 0 (held, from rest) or the frames its
        window spans (the public GNS's start from simulated frames)."""
        return 1 if from_rest else self.window_frames

    def check_frames(self, frames: int, where: str, from_rest: bool = True) -> None:
        """InputError unless a run of `frames` dataset frames holds the frames a rollout
        starts from and the first one it predicts, frame_stride frames later (so a rollout
        can be compared with it)."""
        least = self.start_frames(from_rest) + self.frame_stride
        if frames < least:
            start = "frame 0" if from_rest else f"the {self.window_frames} frames of the model's window"
            raise InputError(f"{where} = {frames} must be at least {least}: {start} and the first frame the "
                             f"model predicts, {self.frame_stride} frame{'s' if self.frame_stride > 1 else ''} on.")

    @property
    def material_width(self) -> int:
        return len(self.material_features)

    @property
    def node_width(self) -> int:
        """Columns entering the node encoder."""
        return (self.history - 1) * self.dim + 2 * self.dim + int(self.overburden) + self.type_embedding + self.material_width

    @property
    def edge_width(self) -> int:
        """Relative displacement / R (dim columns) and its length."""
        return self.dim + 1

    def with_material_features(self, names: tuple[str, ...]) -> "FeatureSchema":
        return FeatureSchema(**{**asdict(self), "material_features": tuple(names)})

    def to_dict(self) -> dict:
        d = asdict(self)
        d["material_features"] = list(self.material_features)
        return d

    @classmethod
    def from_dict(cls, d: dict) -> "FeatureSchema":
        known = {f.name for f in fields(cls)}
        kwargs = {k: v for k, v in d.items() if k in known}
        if "material_features" in kwargs:
            kwargs["material_features"] = tuple(kwargs["material_features"])
        return cls(**kwargs)

    @staticmethod
    def problem(d: dict) -> str | None:
        """The first stored field outside SCHEMA_LIMITS or naming an unknown material
        feature, as a phrase, or None."""
        for key, (lo, hi) in SCHEMA_LIMITS.items():
            v = d.get(key, getattr(FeatureSchema, key))
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not lo <= v <= hi:
                return f"{key} = {v!r} is outside the allowed range [{lo:g}, {hi:g}]"
        for key in ("history", "dim", "particle_types", "type_embedding", "frame_stride"):
            if not isinstance(d.get(key, 0), int):
                return f"{key} = {d[key]!r} must be a whole number"
        if not isinstance(d.get("overburden", False), bool):
            return f"overburden = {d['overburden']!r} must be true or false"
        names = d.get("material_features", MATERIAL_FEATURE_NAMES)
        if not isinstance(names, (list, tuple)) or list(names) != list(MATERIAL_FEATURE_NAMES[: len(names)]) or not names:
            return f"material_features = {names!r} must be [tan_phi] or [tan_phi, c_over_100kPa]"
        return None

    def difference(self, other: "FeatureSchema") -> str | None:
        """The first field in which `other` differs, as a phrase, or None when equal (the
        overburden input is the model's own: data never call for it)."""
        for f in fields(self):
            if f.name == "overburden":
                continue
            mine, theirs = getattr(self, f.name), getattr(other, f.name)
            if mine != theirs:
                return f"{f.name} is {_show(mine)} in the model but {_show(theirs)} in the data"
        return None


def _show(value) -> str:
    if isinstance(value, tuple):
        return "[" + ", ".join(value) + "]"
    return repr(value)


def material_names_for_width(width: int) -> tuple[str, ...]:
    """Names of the first `width` material features ([tan phi], [tan phi, c / 100 kPa])."""
    return MATERIAL_FEATURE_NAMES[:width]


# ----------------------------------------------------------------------------- material codec
# runout.gns.schema.encode_materials_torch is the same encoding, differentiable, for the inverse.


def encode_material(friction_angle: float, cohesion: float) -> list[float]:
    """[tan phi, c / 100 kPa] of one material (phi in degrees, c in kPa)."""
    return [math.tan(math.radians(friction_angle)), cohesion / COHESION_SCALE]


def decode_material(row) -> tuple[float, float]:
    """(phi in degrees, c in kPa) of one feature row [tan phi] or [tan phi, c / 100 kPa];
    c is 0 when the row has one column."""
    phi = math.degrees(math.atan(float(row[0])))
    c = float(row[1]) * COHESION_SCALE if len(row) > 1 else 0.0
    return phi, c


def decode_materials(features: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
    """(phi [N] in degrees, c [N] in kPa or None for one column) of feature rows [N, k]."""
    features = np.asarray(features)
    phi = np.degrees(np.arctan(features[:, 0]))
    return phi, features[:, 1] * COHESION_SCALE if features.shape[1] > 1 else None
