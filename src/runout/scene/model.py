"""The scene data model: domain, time, materials, regions and the scene they make.

Units everywhere: metres, seconds, degrees for friction angles, kPa for cohesion, MPa for
Young's modulus, kg/m^3 for density. Defaults come from runout.defaults.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

from runout import defaults
from runout.contract import encode_material, spacing_for_cells
from runout.errors import InputError
from runout.scene.validation import MAX_FRAMES, validate_scene


@dataclass(frozen=True)
class Domain:
    """Rectangular domain [0, width] x [0, height] (m) with rigid walls on all four sides."""

    width: float
    height: float
    cell_size: float = defaults.CELL_SIZE  # m, square background-grid cells
    points_per_cell: int = defaults.POINTS_PER_CELL  # per direction: 2 -> 4 points per cell
    base_friction: float = defaults.BASE_FRICTION  # on the base and fixed ground: Coulomb mu, or inf ("rough": no slip)
    wall_friction: float = defaults.WALL_FRICTION  # on the side walls (and top); 0 = free slip

    @property
    def point_spacing(self) -> float:
        return spacing_for_cells(self.cell_size, self.points_per_cell)


@dataclass(frozen=True)
class TimeSpec:
    frame_dt: float = defaults.FRAME_DT  # s between output frames
    frames: int = defaults.FRAMES
    cfl: float = defaults.CFL  # Courant number on dx / (c_p + v_max); the substep count follows
    flip: float | str = defaults.FLIP  # FLIP share of the point-velocity update (the rest APIC): "wave" or [0, 1]; docs/scene-format.md
    damping: float = 0.0  # local (Cundall) damping share of the unbalanced nodal force (the reference MPM used 0.05)


@dataclass(frozen=True)
class Material:
    """Mohr-Coulomb (psi = 0, tension cut-off) or linear-elastic material."""

    name: str
    model: str = "mohr-coulomb"  # or "elastic"
    friction_angle: float = defaults.FRICTION_ANGLE  # degrees
    cohesion: float = defaults.COHESION  # kPa
    youngs_modulus: float = defaults.YOUNGS_MODULUS  # MPa
    poisson_ratio: float = defaults.POISSON_RATIO
    density: float = defaults.DENSITY  # kg/m^3
    k0: float | None = None  # lateral earth-pressure coefficient; default 1 - sin(phi)
    tension_cutoff: float = defaults.TENSION_CUTOFF  # kPa, capped at c / tan(phi)

    def features(self) -> list[float]:
        """GNS material features [tan(phi), c / 100 kPa] (paper Table 1, note a)."""
        return encode_material(self.friction_angle, self.cohesion)


@dataclass(frozen=True)
class Region:
    material: str
    polygon: tuple[tuple[float, float], ...]  # m, either orientation
    velocity: tuple[float, float] = (0.0, 0.0)  # m/s
    fixed: bool = False  # stationary points (ground): particle type 3


@dataclass(frozen=True)
class Scene:
    domain: Domain
    materials: dict[str, Material]
    regions: tuple[Region, ...]
    time: TimeSpec = field(default_factory=TimeSpec)
    name: str = "scene"

    @property
    def material_names(self) -> list[str]:
        return list(self.materials)

    def with_frames(self, frames: int) -> "Scene":
        if not 1 <= frames <= MAX_FRAMES:
            raise InputError(f"frames = {frames} is outside the allowed range [1, {MAX_FRAMES}].")
        return replace(self, time=replace(self.time, frames=frames))

    def with_point_spacing(self, spacing: float, source: str = "<scene>") -> "Scene":
        """A copy whose cells are sized so that its points sit `spacing` m apart
        (cell_size = spacing x points_per_cell), checked like a scene file."""
        cell = round(spacing * self.domain.points_per_cell, 6)  # m
        out = replace(self, domain=replace(self.domain, cell_size=cell))
        validate_scene(out, source)
        return out

    def with_materials(self, **changes: dict[str, float]) -> "Scene":
        """A copy with material properties changed, e.g. with_materials(sand={"cohesion": 20})."""
        mats = dict(self.materials)
        for name, props in changes.items():
            mats[name] = replace(mats[name], **props)
        out = replace(self, materials=mats)
        validate_scene(out, "<scene>")
        return out
