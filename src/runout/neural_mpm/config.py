"""The neural MPM's config, torch-free: NeuralMPMConfig (everything that fixes the engine's
inputs and outputs, stored in every checkpoint) and the allowed value of each field, which
the checkpoint reader and `runout train --engine neural-mpm` check."""

from __future__ import annotations

from dataclasses import asdict, dataclass

from runout.defaults import FRAME_DT

# Allowed [lowest, highest] of every number of the config
CONFIG_LIMITS = {
    "cell_size": (1e-3, 1e4), "point_spacing": (1e-3, 1e4), "frame_dt": (1e-6, 10.0), "history": (1, 16),
    "frames_per_call": (1, 64), "material_width": (1, 2), "velocity_scale": (1e-9, 1e3), "pad": (1, 8),
    "velocity_sweeps": (0, 64),
}
WHOLE = ("history", "frames_per_call", "material_width", "pad", "velocity_sweeps")
MAX_WIDTH = 1024  # U-Net channels at one level
MAX_LEVELS = 6  # U-Net levels


@dataclass(frozen=True)
class NeuralMPMConfig:
    """Everything that fixes the engine's inputs and outputs; stored in every checkpoint."""

    cell_size: float = 8.0  # m between grid nodes
    point_spacing: float = 4.0  # m between the training data's points
    frame_dt: float = FRAME_DT  # s between the frames the engine steps through
    history: int = 3  # past frame velocities per input
    frames_per_call: int = 8  # m: frames predicted per U-Net call
    widths: tuple[int, ...] = (32, 64, 96)  # U-Net channels per level
    material_width: int = 2  # [tan phi, c / 100 kPa]
    velocity_scale: float = 0.0  # m per frame: the unit of the velocity channels (0: from the training data)
    pad: int = 2  # grid nodes outside each wall
    velocity_sweeps: int = 0  # sharpening sweeps of the input velocities (0: the mass-weighted mean per node)

    @property
    def in_channels(self) -> int:
        return 2 + 2 * self.history + self.material_width + 2

    def as_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, table: dict) -> "NeuralMPMConfig":
        values = dict(table)
        values["widths"] = tuple(int(w) for w in values.get("widths", cls.widths))
        return cls(**values)


def widths_allowed(widths) -> bool:
    """Whether `widths` are 1 to MAX_LEVELS whole numbers of channels in [1, MAX_WIDTH]."""
    return (isinstance(widths, (list, tuple)) and 1 <= len(widths) <= MAX_LEVELS
            and all(not isinstance(w, bool) and isinstance(w, int) and 1 <= w <= MAX_WIDTH for w in widths))
