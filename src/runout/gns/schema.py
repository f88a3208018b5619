"""What a GNS checkpoint records beyond the learned engines' contract (runout.contract), torch-free
so that the command line reads it without the network:

    FeatureSchema   the node-feature layout stored in every checkpoint: runout.contract's
                    WindowSchema (history, stride, particle types, material features) and the
                    GNS's own inputs, the wall distances clipped to +-wall_clip, the type
                    embedding's width and the overburden input
    NetworkConfig   the layer sizes every checkpoint stores, NETWORK_LIMITS their allowed range
    MAX_STEPS       the most training steps one records

Node features, in this column order (material features last, so a model can be widened
with one more material input by appending zero columns to the encoder's first layer):

    velocities   (history - 1) x dim   normalised per-step velocities, oldest first
    walls        2 x dim               clip((x - lo) / R), clip((hi - x) / R) per dimension
    overburden   1 (when on)           depth of soil above the point / 100 m (runout.gns.features)
    type         type_embedding        learned embedding of the particle type
    material     len(material_features) e.g. [tan phi, c / 100 kPa]
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

from runout.contract import SCHEMA_LIMITS as WINDOW_LIMITS
from runout.contract import WindowSchema

# Allowed [lowest, highest] of the numeric fields of a GNS checkpoint's schema, in the order checked.
SCHEMA_LIMITS = {
    "history": WINDOW_LIMITS["history"], "dim": WINDOW_LIMITS["dim"], "wall_clip": (0.0, 100.0),
    "particle_types": WINDOW_LIMITS["particle_types"], "type_embedding": (1, 256), "frame_stride": WINDOW_LIMITS["frame_stride"],
}
MAX_STEPS = 1_000_000_000  # the most training steps a checkpoint may record (as `runout train --steps` allows)
# Allowed layer sizes: [lowest, highest] of each NetworkConfig field.
NETWORK_LIMITS = {"latent": (1, 1024), "hidden": (1, 1024), "hidden_layers": (1, 8), "message_passing_steps": (1, 50)}


@dataclass(frozen=True)
class FeatureSchema(WindowSchema):
    wall_clip: float = 1.0  # wall distances / R are clipped to [-wall_clip, wall_clip]
    type_embedding: int = 16
    overburden: bool = False  # a node input: the depth of soil above each point in its column (checkpoints without it: none)

    LIMITS: ClassVar[dict] = SCHEMA_LIMITS
    WHOLE: ClassVar[tuple[str, ...]] = ("history", "dim", "particle_types", "type_embedding", "frame_stride")
    MODEL_ONLY: ClassVar[tuple[str, ...]] = ("overburden",)  # the overburden input is the model's own: data never call for it

    @property
    def node_width(self) -> int:
        """Columns entering the node encoder."""
        return (self.history - 1) * self.dim + 2 * self.dim + int(self.overburden) + self.type_embedding + self.material_width

    @property
    def edge_width(self) -> int:
        """Relative displacement / R (dim columns) and its length."""
        return self.dim + 1

    @classmethod
    def _other_problem(cls, d: dict) -> str | None:
        if not isinstance(d.get("overburden", False), bool):
            return f"overburden = {d['overburden']!r} must be true or false"
        return None


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
