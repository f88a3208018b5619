"""The contract of the learned engines, below everything that reads or writes their data: torch-free.

What a scene, a trajectory file, a dataset and every learned engine's checkpoint agree on, one
owner each:

    material codec      a material enters a learned engine as [tan phi, c / 100 kPa] (paper
                        Table 1, note a; a base model reads only the first column):
                        encode_material, decode_material, decode_materials, MATERIAL_FEATURE_NAMES
    history             HISTORY = 6 positions per input window (5 velocities)
    radius per spacing  the connectivity radius of a dataset (metadata.json's
                        default_connectivity_radius) is RADIUS_PER_SPACING point spacings
                        (radius_for_spacing, spacing_for_radius); the points sit
                        cell_size / points_per_cell apart (spacing_for_cells)
    WindowSchema        what a model reads of the data: a window of `history` positions
                        `frame_stride` frames apart, each point's type (of `particle_types`) and
                        its material features; the frames a rollout starts from and needs
                        (start_frames, check_frames)

What one engine alone needs stays in its package: the GNS's node inputs (wall clipping, the
type embedding, the overburden) and layer sizes are runout.gns.schema.

A step spans `frame_stride` dataset frames: the window holds the positions at frames t,
t + K, ..., t + (history - 1) K, the velocities are differences over K frames and the model
predicts frame t + history K (K = 1: every frame, the paper's GNS). Every rollout starts from
rest: its window is frame 0 held, so it needs frame 0 and predicts frame K first.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields, replace
from typing import ClassVar

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
SCHEMA_LIMITS = {"history": (2, 20), "dim": (2, 2), "particle_types": (PARTICLE_TYPE_SOIL + 1, 64), "frame_stride": (1, 16)}


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


# ----------------------------------------------------------------------------- window schema


@dataclass(frozen=True)
class WindowSchema:
    """What a learned model reads of the data, stored in its checkpoint."""

    history: int = HISTORY  # positions per input window -> history - 1 velocities
    dim: int = 2
    particle_types: int = 9
    material_features: tuple[str, ...] = MATERIAL_FEATURE_NAMES
    frame_stride: int = 1  # dataset frames per step (checkpoints without it: 1)

    LIMITS: ClassVar[dict] = SCHEMA_LIMITS  # [lowest, highest] of each numeric field, in the order checked
    WHOLE: ClassVar[tuple[str, ...]] = ("history", "dim", "particle_types", "frame_stride")  # whole-number fields
    MODEL_ONLY: ClassVar[tuple[str, ...]] = ()  # fields that are the model's own choice: data never call for them

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

    def with_material_features(self, names: tuple[str, ...]):
        return replace(self, material_features=tuple(names))

    def to_dict(self) -> dict:
        d = asdict(self)
        d["material_features"] = list(self.material_features)
        return d

    @classmethod
    def from_dict(cls, d: dict):
        known = {f.name for f in fields(cls)}
        kwargs = {k: v for k, v in d.items() if k in known}
        if "material_features" in kwargs:
            kwargs["material_features"] = tuple(kwargs["material_features"])
        return cls(**kwargs)

    @classmethod
    def problem(cls, d: dict) -> str | None:
        """The first stored field outside LIMITS or naming an unknown material feature, as a
        phrase, or None."""
        for key, (lo, hi) in cls.LIMITS.items():
            v = d.get(key, getattr(cls, key))
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not lo <= v <= hi:
                return f"{key} = {v!r} is outside the allowed range [{lo:g}, {hi:g}]"
        for key in cls.WHOLE:
            if not isinstance(d.get(key, 0), int):
                return f"{key} = {d[key]!r} must be a whole number"
        return cls._other_problem(d) or _material_problem(d)

    @classmethod
    def _other_problem(cls, d: dict) -> str | None:
        """The first problem of a field that is neither a number in LIMITS nor the material features."""
        return None

    def difference(self, other: "WindowSchema") -> str | None:
        """The first field in which `other` differs, as a phrase, or None when equal (the
        model's own fields, MODEL_ONLY, are not compared)."""
        for f in fields(self):
            if f.name in self.MODEL_ONLY:
                continue
            mine, theirs = getattr(self, f.name), getattr(other, f.name)
            if mine != theirs:
                return f"{f.name} is {_show(mine)} in the model but {_show(theirs)} in the data"
        return None


def _material_problem(d: dict) -> str | None:
    names = d.get("material_features", MATERIAL_FEATURE_NAMES)
    if not isinstance(names, (list, tuple)) or list(names) != list(MATERIAL_FEATURE_NAMES[: len(names)]) or not names:
        return f"material_features = {names!r} must be [tan_phi] or [tan_phi, c_over_100kPa]"
    return None


def _show(value) -> str:
    if isinstance(value, tuple):
        return "[" + ", ".join(value) + "]"
    return repr(value)


def material_names_for_width(width: int) -> tuple[str, ...]:
    """Names of the first `width` material features ([tan phi], [tan phi, c / 100 kPa])."""
    return MATERIAL_FEATURE_NAMES[:width]


# ----------------------------------------------------------------------------- material codec
# runout.learned.materials.encode_materials is the same encoding, differentiable, for the inverse.


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
