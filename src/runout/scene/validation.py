"""Scene validation: every range and every polygon, one sentence naming what is wrong."""

from __future__ import annotations

import math
import sys
from typing import TYPE_CHECKING

import numpy as np

from runout.defaults import FLIP_WAVE
from runout.errors import InputError
from runout.scene.geometry import points_in_polygon, polygon_area, polygon_self_intersects, polygons_overlap
from runout.scene.seeding import lattice_points

if TYPE_CHECKING:
    from runout.scene.model import Scene

# Physical upper bounds of scene values (beyond them a run is meaningless or cannot finish).
MAX_DOMAIN = 20_000.0  # m, width and height
MAX_LATTICE_POINTS = 2_000_000  # candidate points (domain / point spacing, both ways)
MAX_FRAMES = 1_000_000
MAX_SPEED = 100.0  # m/s, the speed (length of the vector) of an initial velocity (fast rock avalanches)
MAX_YOUNGS_MODULUS = 1e5  # MPa (100 GPa, stiffer than intact granite)
MAX_STRENGTH = 1e4  # kPa, cohesion and tension cut-off (10 MPa, soft rock)
MAX_DENSITY = 1e4  # kg/m^3
SMALLEST_SIZE = sys.float_info.min  # 2.2e-308: below it a float is subnormal and a size divided by it overflows


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


def validate_scene(scene: Scene, source: str = "<scene>") -> None:
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
    if t.flip != FLIP_WAVE:  # "wave": exp(-dt c_p / dx) per substep
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
