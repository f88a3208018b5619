"""The scene data model: domain, time, materials, regions and the scene they make, and its
checks (check_scene: every range of runout.scene.limits and every polygon, one sentence naming
what is wrong), which every scene file and every changed copy of a scene passes.

Units everywhere: metres, seconds, degrees for friction angles, kPa for cohesion, MPa for
Young's modulus, kg/m^3 for density. Defaults come from runout.defaults.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np

from runout import defaults
from runout.contract import encode_material, spacing_for_cells
from runout.errors import InputError
from runout.scene.geometry import points_in_polygon, polygon_area, polygon_self_intersects, polygons_overlap
from runout.scene.limits import (
    MAX_DENSITY, MAX_DOMAIN, MAX_FRAMES, MAX_LATTICE_POINTS, MAX_SPEED, MAX_STRENGTH, MAX_YOUNGS_MODULUS, SMALLEST_SIZE,
)


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
        check_scene(out, source)
        return out

    def with_materials(self, **changes: dict[str, float]) -> "Scene":
        """A copy with material properties changed, e.g. with_materials(sand={"cohesion": 20})."""
        mats = dict(self.materials)
        for name, props in changes.items():
            mats[name] = replace(mats[name], **props)
        out = replace(self, materials=mats)
        check_scene(out, "<scene>")
        return out


# ----------------------------------------------------------------------------- checks


def lattice_points(domain: Domain) -> np.ndarray:
    """Candidate point positions: centres of a regular sub-grid, points_per_cell per direction."""
    s = domain.point_spacing
    nx = int(round(domain.width / s))
    ny = int(round(domain.height / s))
    xs = (np.arange(nx) + 0.5) * s
    ys = (np.arange(ny) + 0.5) * s
    gx, gy = np.meshgrid(xs, ys, indexing="xy")
    return np.column_stack([gx.ravel(), gy.ravel()])


def _in_range(value, lo, hi, key, where, source, unit="", lo_open=False, hi_open=False) -> None:
    bad_lo = value <= lo if lo_open else value < lo
    bad_hi = value >= hi if hi_open else value > hi
    subnormal = lo_open and lo == 0 and 0 < value < SMALLEST_SIZE
    if bad_lo or bad_hi or subnormal:
        left = "(" if lo_open else "["
        right = ")" if hi_open else "]"
        hi_txt = "inf" if hi == math.inf else f"{hi:g}"
        note = f" (a positive size is at least {SMALLEST_SIZE:.3g})" if subnormal else ""
        raise InputError(
            f"{source}: {where}.{key} = {value:g} is outside the allowed range "
            f"{left}{lo:g}, {hi_txt}{right}{unit}{note}."
        )


def _check_speed(velocity, where: str, source) -> None:
    """The start speed, the length of the velocity vector, is at most MAX_SPEED."""
    speed = math.hypot(*velocity)
    if not speed <= MAX_SPEED:  # a NaN fails too
        shown = ", ".join(f"{v:g}" for v in velocity)
        raise InputError(f"{source}: {where}.velocity = [{shown}] m/s has a speed of {speed:g} m/s, outside the "
                         f"allowed range [0, {MAX_SPEED:g}] m/s.")


def check_scene(scene: Scene, source: str = "<scene>") -> None:
    """Check every range and every polygon; raise InputError with one sentence on failure."""
    d = scene.domain
    _in_range(d.width, 0, MAX_DOMAIN, "width", "domain", source, " m", lo_open=True)
    _in_range(d.height, 0, MAX_DOMAIN, "height", "domain", source, " m", lo_open=True)
    _in_range(d.cell_size, 0, min(d.width, d.height) / 2, "cell_size", "domain", source, " m", lo_open=True)
    _in_range(d.points_per_cell, 1, 6, "points_per_cell", "domain", source)
    candidates = np.round(d.width / d.point_spacing) * np.round(d.height / d.point_spacing)  # float: inf when huge
    if candidates > MAX_LATTICE_POINTS:
        raise InputError(
            f"{source}: the domain {d.width:g} x {d.height:g} m at {d.point_spacing:g} m point spacing has "
            f"{candidates:.3g} candidate points, more than the {MAX_LATTICE_POINTS:.3g} allowed; "
            "use a larger domain.cell_size or a smaller domain."
        )
    if d.base_friction != math.inf:  # inf: "rough", no slip
        _in_range(d.base_friction, 0, 10, "base_friction", "domain", source)
    _in_range(d.wall_friction, 0, 10, "wall_friction", "domain", source)
    t = scene.time
    _in_range(t.frame_dt, 0, 10, "frame_dt", "time", source, " s", lo_open=True)
    _in_range(t.frames, 1, MAX_FRAMES, "frames", "time", source)
    _in_range(t.cfl, 0, 1, "cfl", "time", source, lo_open=True)
    if t.flip != defaults.FLIP_WAVE:  # "wave": exp(-dt c_p / dx) per substep
        _in_range(t.flip, 0, 1, "flip", "time", source)
    _in_range(t.damping, 0, 0.5, "damping", "time", source)
    for name, m in scene.materials.items():
        where = f"materials.{name}"
        _in_range(m.friction_angle, 0, 60, "friction_angle", where, source, " degrees")
        _in_range(m.cohesion, 0, MAX_STRENGTH, "cohesion", where, source, " kPa")
        _in_range(m.youngs_modulus, 0, MAX_YOUNGS_MODULUS, "youngs_modulus", where, source, " MPa", lo_open=True)
        _in_range(m.poisson_ratio, 0, 0.5, "poisson_ratio", where, source, lo_open=True, hi_open=True)
        _in_range(m.density, 0, MAX_DENSITY, "density", where, source, " kg/m3", lo_open=True)
        _in_range(m.tension_cutoff, 0, MAX_STRENGTH, "tension_cutoff", where, source, " kPa")
        if m.k0 is not None:
            _in_range(m.k0, 0, 5, "k0", where, source, lo_open=True)
    polys = []
    for k, r in enumerate(scene.regions):
        where = f"regions[{k}]"
        if r.material not in scene.materials:
            raise InputError(
                f"{source}: {where}.material = '{r.material}' is not defined; defined materials are "
                f"{', '.join(scene.materials)}."
            )
        _check_speed(r.velocity, where, source)
        p = np.asarray(r.polygon, dtype=float)
        for x, y in p:
            if not (0.0 <= x <= d.width and 0.0 <= y <= d.height):
                raise InputError(
                    f"{source}: {where}.polygon vertex ({x:g}, {y:g}) lies outside the domain "
                    f"[0, {d.width:g}] x [0, {d.height:g}] m."
                )
        if abs(polygon_area(p)) < 1e-9:
            raise InputError(f"{source}: {where}.polygon has zero area.")
        if polygon_self_intersects(p):
            raise InputError(f"{source}: {where}.polygon intersects itself.")
        if not points_in_polygon(lattice_points(d), p).any():
            raise InputError(
                f"{source}: {where}.polygon is too small to hold a single point at "
                f"{d.point_spacing:g} m spacing (cell_size / points_per_cell)."
            )
        polys.append(p)
    for a in range(len(polys)):
        for b in range(a + 1, len(polys)):
            if polygons_overlap(polys[a], polys[b]):
                raise InputError(f"{source}: regions[{a}] and regions[{b}] overlap.")
