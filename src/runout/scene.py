"""Scenes: domain, materials and polygonal regions; scene files; filling regions with points.

Units everywhere: metres, seconds, degrees for friction angles, kPa for cohesion, MPa for
Young's modulus, kg/m^3 for density. A scene file is TOML (or JSON with the same keys);
see docs/scene-format.md.
"""

from __future__ import annotations

import json
import math
import tomllib
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

import numpy as np

from runout import defaults
from runout.defaults import PARTICLE_TYPE_KINEMATIC, PARTICLE_TYPE_SOIL
from runout.errors import InputError
from runout.gns.schema import encode_material

# Physical upper bounds of scene values (beyond them a run is meaningless or cannot finish).
MAX_DOMAIN = 20_000.0  # m, width and height
MAX_LATTICE_POINTS = 2_000_000  # candidate points (domain / point spacing, both ways)
MAX_FRAMES = 1_000_000
MAX_SPEED = 100.0  # m/s, each component of an initial velocity (fast rock avalanches)
MAX_YOUNGS_MODULUS = 1e5  # MPa (100 GPa, stiffer than intact granite)
MAX_STRENGTH = 1e4  # kPa, cohesion and tension cut-off (10 MPa, soft rock)
MAX_DENSITY = 1e4  # kg/m^3


@dataclass(frozen=True)
class Domain:
    """Rectangular domain [0, width] x [0, height] (m) with rigid walls on all four sides."""

    width: float
    height: float
    cell_size: float = defaults.CELL_SIZE  # m, square background-grid cells
    points_per_cell: int = defaults.POINTS_PER_CELL  # per direction: 2 -> 4 points per cell
    base_friction: float = defaults.BASE_FRICTION  # Coulomb coefficient on the base and on fixed ground
    wall_friction: float = defaults.WALL_FRICTION  # on the side walls (and top); 0 = free slip

    @property
    def point_spacing(self) -> float:
        return self.cell_size / self.points_per_cell


@dataclass(frozen=True)
class TimeSpec:
    frame_dt: float = defaults.FRAME_DT  # s between output frames
    frames: int = defaults.FRAMES
    cfl: float = defaults.CFL  # Courant number on dx / (c_p + v_max); the substep count follows
    flip: float = 0.0  # FLIP share of the point-velocity update (the rest APIC); see docs/scene-format.md
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

    @property
    def k0_value(self) -> float:
        if self.k0 is not None:
            return self.k0
        return 1.0 - math.sin(math.radians(self.friction_angle))

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

    def with_materials(self, **changes: dict[str, float]) -> "Scene":
        """A copy with material properties changed, e.g. with_materials(sand={"cohesion": 20})."""
        mats = dict(self.materials)
        for name, props in changes.items():
            mats[name] = replace(mats[name], **props)
        out = replace(self, materials=mats)
        validate_scene(out, "<scene>")
        return out


# ----------------------------------------------------------------------------- parsing

_DOMAIN_KEYS = {"width", "height", "cell_size", "points_per_cell", "base_friction", "wall_friction"}
_TIME_KEYS = {"frame_dt", "frames", "cfl", "flip", "damping"}
_MATERIAL_KEYS = {
    "model", "friction_angle", "cohesion", "youngs_modulus", "poisson_ratio", "density", "k0",
    "tension_cutoff",
}
_REGION_KEYS = {"material", "polygon", "velocity", "fixed"}
_TOP_KEYS = {"domain", "time", "materials", "regions", "name"}


def _check_keys(table: dict, allowed: set[str], where: str, source: str) -> None:
    if not isinstance(table, dict):
        raise InputError(f"{source}: [{where}] must be a table of keys.")
    unknown = sorted(set(table) - allowed)
    if unknown:
        raise InputError(
            f"{source}: unknown key '{unknown[0]}' in [{where}]; allowed keys are "
            f"{', '.join(sorted(allowed))}."
        )


def _number(table: dict, key: str, where: str, source: str, default=None) -> float:
    if key not in table:
        if default is None:
            raise InputError(f"{source}: [{where}] is missing the required key '{key}'.")
        return default
    value = table[key]
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise InputError(f"{source}: {where}.{key} = {value!r} must be a finite number.")
    return float(value)


def _in_range(value, lo, hi, key, where, source, unit="", lo_open=False, hi_open=False) -> None:
    bad_lo = value <= lo if lo_open else value < lo
    bad_hi = value >= hi if hi_open else value > hi
    if bad_lo or bad_hi:
        left = "(" if lo_open else "["
        right = ")" if hi_open else "]"
        hi_txt = "inf" if hi == math.inf else f"{hi:g}"
        raise InputError(
            f"{source}: {where}.{key} = {value:g} is outside the allowed range "
            f"{left}{lo:g}, {hi_txt}{right}{unit}."
        )


def scene_from_dict(data: dict, source: str = "<scene>") -> Scene:
    """Build and validate a Scene from the dictionary form of a scene file."""
    _check_keys(data, _TOP_KEYS, "top level", source)
    for required in ("domain", "materials", "regions"):
        if required not in data:
            raise InputError(f"{source}: the scene has no [{required}] section.")

    d = data["domain"]
    _check_keys(d, _DOMAIN_KEYS, "domain", source)
    ppc = d.get("points_per_cell", Domain.points_per_cell)
    if isinstance(ppc, bool) or not isinstance(ppc, int):
        raise InputError(f"{source}: domain.points_per_cell = {ppc!r} must be a whole number in [1, 6].")
    domain = Domain(
        width=_number(d, "width", "domain", source),
        height=_number(d, "height", "domain", source),
        cell_size=_number(d, "cell_size", "domain", source, Domain.cell_size),
        points_per_cell=ppc,
        base_friction=_number(d, "base_friction", "domain", source, Domain.base_friction),
        wall_friction=_number(d, "wall_friction", "domain", source, Domain.wall_friction),
    )

    t = data.get("time", {})
    _check_keys(t, _TIME_KEYS, "time", source)
    frames = t.get("frames", TimeSpec.frames)
    if isinstance(frames, bool) or not isinstance(frames, int):
        raise InputError(f"{source}: time.frames = {frames!r} must be a positive whole number.")
    time = TimeSpec(
        frame_dt=_number(t, "frame_dt", "time", source, TimeSpec.frame_dt),
        frames=frames,
        cfl=_number(t, "cfl", "time", source, TimeSpec.cfl),
        flip=_number(t, "flip", "time", source, TimeSpec.flip),
        damping=_number(t, "damping", "time", source, TimeSpec.damping),
    )

    mats_in = data["materials"]
    if not isinstance(mats_in, dict) or not mats_in:
        raise InputError(f"{source}: [materials] must define at least one material table.")
    materials = {}
    for name, m in mats_in.items():
        where = f"materials.{name}"
        _check_keys(m, _MATERIAL_KEYS, where, source)
        model = m.get("model", Material.model)
        if model not in ("mohr-coulomb", "elastic"):
            raise InputError(f"{source}: {where}.model = {model!r} must be 'mohr-coulomb' or 'elastic'.")
        k0 = m.get("k0")
        materials[name] = Material(
            name=name,
            model=model,
            friction_angle=_number(m, "friction_angle", where, source, Material.friction_angle),
            cohesion=_number(m, "cohesion", where, source, Material.cohesion),
            youngs_modulus=_number(m, "youngs_modulus", where, source, Material.youngs_modulus),
            poisson_ratio=_number(m, "poisson_ratio", where, source, Material.poisson_ratio),
            density=_number(m, "density", where, source, Material.density),
            k0=None if k0 is None else _number(m, "k0", where, source),
            tension_cutoff=_number(m, "tension_cutoff", where, source, Material.tension_cutoff),
        )

    regions_in = data["regions"]
    if not isinstance(regions_in, list) or not regions_in:
        raise InputError(f"{source}: [[regions]] must list at least one region.")
    regions = []
    for k, r in enumerate(regions_in):
        where = f"regions[{k}]"
        _check_keys(r, _REGION_KEYS, where, source)
        if "material" not in r:
            raise InputError(f"{source}: {where} is missing the required key 'material'.")
        if "polygon" not in r:
            raise InputError(f"{source}: {where} is missing the required key 'polygon'.")
        poly = r["polygon"]
        if (
            not isinstance(poly, list)
            or len(poly) < 3
            or not all(isinstance(p, list) and len(p) == 2 for p in poly)
            or not all(isinstance(v, (int, float)) and not isinstance(v, bool) for p in poly for v in p)
        ):
            raise InputError(
                f"{source}: {where}.polygon must be a list of at least 3 [x, y] pairs of numbers (m)."
            )
        vel = r.get("velocity", [0.0, 0.0])
        if not (isinstance(vel, list) and len(vel) == 2 and all(isinstance(v, (int, float)) for v in vel)):
            raise InputError(f"{source}: {where}.velocity must be a pair [vx, vy] of numbers (m/s).")
        fixed = r.get("fixed", False)
        if not isinstance(fixed, bool):
            raise InputError(f"{source}: {where}.fixed = {fixed!r} must be true or false.")
        regions.append(
            Region(
                material=str(r["material"]),
                polygon=tuple((float(x), float(y)) for x, y in poly),
                velocity=(float(vel[0]), float(vel[1])),
                fixed=fixed,
            )
        )
    scene = Scene(domain, materials, tuple(regions), time, str(data.get("name", Path(source).stem)))
    validate_scene(scene, source)
    return scene


def load_scene(path: str | Path) -> Scene:
    """Read a TOML (or JSON) scene file; raise InputError naming what is wrong."""
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: no such scene file.")
    try:
        if path.suffix.lower() == ".json":
            data = json.loads(path.read_text())
        else:
            data = tomllib.loads(path.read_text())
    except (tomllib.TOMLDecodeError, json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise InputError(f"{path}: not a valid TOML/JSON scene file ({exc}).") from None
    data.setdefault("name", path.stem)
    return scene_from_dict(data, str(path))


def scene_to_dict(scene: Scene) -> dict:
    out = {
        "name": scene.name,
        "domain": asdict(scene.domain),
        "time": asdict(scene.time),
        "materials": {},
        "regions": [],
    }
    for name, m in scene.materials.items():
        md = asdict(m)
        md.pop("name")
        if md["k0"] is None:
            md.pop("k0")
        out["materials"][name] = md
    for r in scene.regions:
        out["regions"].append(
            {
                "material": r.material,
                "polygon": [list(p) for p in r.polygon],
                "velocity": list(r.velocity),
                "fixed": r.fixed,
            }
        )
    return out


def _toml_value(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        return repr(v)
    if isinstance(v, str):
        return json.dumps(v)
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    raise TypeError(f"cannot write {type(v).__name__} to TOML")


def scene_to_toml(scene: Scene) -> str:
    """The scene as a TOML scene file (the inverse of load_scene)."""
    d = scene_to_dict(scene)
    lines = [f"name = {_toml_value(d['name'])}", "", "[domain]"]
    lines += [f"{k} = {_toml_value(v)}" for k, v in d["domain"].items()]
    lines += ["", "[time]"] + [f"{k} = {_toml_value(v)}" for k, v in d["time"].items()]
    for name, m in d["materials"].items():
        lines += ["", f"[materials.{json.dumps(name)}]"]
        lines += [f"{k} = {_toml_value(v)}" for k, v in m.items()]
    for r in d["regions"]:
        lines += ["", "[[regions]]"] + [f"{k} = {_toml_value(v)}" for k, v in r.items()]
    return "\n".join(lines) + "\n"


def save_scene(scene: Scene, path: str | Path) -> None:
    Path(path).write_text(scene_to_toml(scene))


# ----------------------------------------------------------------------------- validation


def validate_scene(scene: Scene, source: str = "<scene>") -> None:
    """Check every range and every polygon; raise InputError with one sentence on failure."""
    d = scene.domain
    _in_range(d.width, 0, MAX_DOMAIN, "width", "domain", source, " m", lo_open=True)
    _in_range(d.height, 0, MAX_DOMAIN, "height", "domain", source, " m", lo_open=True)
    _in_range(d.cell_size, 0, min(d.width, d.height) / 2, "cell_size", "domain", source, " m", lo_open=True)
    _in_range(d.points_per_cell, 1, 6, "points_per_cell", "domain", source)
    candidates = round(d.width / d.point_spacing) * round(d.height / d.point_spacing)
    if candidates > MAX_LATTICE_POINTS:
        raise InputError(
            f"{source}: the domain {d.width:g} x {d.height:g} m at {d.point_spacing:g} m point spacing has "
            f"{candidates:.3g} candidate points, more than the {MAX_LATTICE_POINTS:.3g} allowed; "
            "use a larger domain.cell_size or a smaller domain."
        )
    _in_range(d.base_friction, 0, 10, "base_friction", "domain", source)
    _in_range(d.wall_friction, 0, 10, "wall_friction", "domain", source)
    t = scene.time
    _in_range(t.frame_dt, 0, 10, "frame_dt", "time", source, " s", lo_open=True)
    _in_range(t.frames, 1, MAX_FRAMES, "frames", "time", source)
    _in_range(t.cfl, 0, 1, "cfl", "time", source, lo_open=True)
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
        for axis, v in zip("xy", r.velocity):
            if not math.isfinite(v) or abs(v) > MAX_SPEED:
                raise InputError(
                    f"{source}: {where}.velocity {axis} = {v:g} is outside the allowed range "
                    f"[-{MAX_SPEED:g}, {MAX_SPEED:g}] m/s."
                )
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


# ----------------------------------------------------------------------------- geometry


def polygon_area(p: np.ndarray) -> float:
    """Signed area (m^2), positive for counter-clockwise vertices."""
    x, y = p[:, 0], p[:, 1]
    return 0.5 * float(np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y))


def _edges(p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    return p, np.roll(p, -1, axis=0)


def _cross_pairs(p: np.ndarray, q: np.ndarray, tol: float) -> np.ndarray:
    """[Ep, Eq] bool: edge i of p and edge j of q cross at a point interior to both
    (touching, sharing a vertex or running collinear is not crossing)."""
    a, b = (e[:, None, :] for e in _edges(p))
    c, d = (e[None, :, :] for e in _edges(q))

    def orient(u, v, w):
        return (v[..., 0] - u[..., 0]) * (w[..., 1] - u[..., 1]) - (v[..., 1] - u[..., 1]) * (w[..., 0] - u[..., 0])

    o1, o2, o3, o4 = orient(a, b, c), orient(a, b, d), orient(c, d, a), orient(c, d, b)
    return (((o1 > tol) & (o2 < -tol)) | ((o1 < -tol) & (o2 > tol))) & (
        ((o3 > tol) & (o4 < -tol)) | ((o3 < -tol) & (o4 > tol))
    )


def edges_cross(p: np.ndarray, q: np.ndarray, tol: float) -> bool:
    """True when an edge of polygon p properly crosses an edge of polygon q."""
    return bool(_cross_pairs(p, q, tol).any())


def polygon_self_intersects(p: np.ndarray) -> bool:
    n = len(p)
    scale = max(1.0, float(np.abs(p).max()))
    cross = _cross_pairs(p, p, 1e-9 * scale * scale)
    i, j = np.triu_indices(n, k=2)
    keep = ~((i == 0) & (j == n - 1))  # the closing edge is adjacent to the first
    return bool(cross[i[keep], j[keep]].any())


def points_in_polygon(points: np.ndarray, poly: np.ndarray) -> np.ndarray:
    """Crossing-number test with the half-open rule, so a point on an edge shared by two
    polygons belongs to exactly one of them. points [N, 2] -> bool [N]."""
    x, y = points[:, 0][:, None], points[:, 1][:, None]
    x0, y0 = poly[:, 0][None, :], poly[:, 1][None, :]
    x1, y1 = np.roll(poly[:, 0], -1)[None, :], np.roll(poly[:, 1], -1)[None, :]
    straddles = (y0 <= y) != (y1 <= y)
    with np.errstate(divide="ignore", invalid="ignore"):
        x_cross = x0 + (y - y0) * (x1 - x0) / (y1 - y0)
    crossings = straddles & (x < x_cross)
    return (crossings.sum(axis=1) % 2) == 1


def _strictly_inside(points: np.ndarray, poly: np.ndarray, tol: float) -> np.ndarray:
    """[N] bool: inside the polygon and farther than tol from its boundary."""
    a, b = _edges(poly)
    ab = b - a
    rel = points[:, None, :] - a[None]
    t = np.clip((rel * ab[None]).sum(-1) / np.maximum((ab**2).sum(-1), 1e-30)[None], 0, 1)
    dist = np.linalg.norm(rel - t[..., None] * ab[None], axis=-1).min(axis=1)
    return points_in_polygon(points, poly) & (dist > tol)


def _probes(p: np.ndarray, n: int = 16) -> np.ndarray:
    """Vertices, edge midpoints and a grid of interior points of polygon p."""
    lo, hi = p.min(axis=0), p.max(axis=0)
    gx, gy = np.meshgrid(np.linspace(lo[0], hi[0], n + 2)[1:-1], np.linspace(lo[1], hi[1], n + 2)[1:-1])
    grid = np.column_stack([gx.ravel(), gy.ravel()])
    a, b = _edges(p)
    return np.vstack([p, 0.5 * (a + b), grid[points_in_polygon(grid, p)]])


def polygons_overlap(p: np.ndarray, q: np.ndarray) -> bool:
    """True when the interiors of two simple polygons intersect; shared edges are allowed.

    Either an edge of one properly crosses an edge of the other, or a vertex, edge midpoint
    or interior sample of one lies strictly inside the other."""
    scale = max(1.0, float(np.abs(p).max()), float(np.abs(q).max()))
    tol = 1e-7 * scale
    if _cross_pairs(p, q, tol * scale).any():
        return True
    return bool(_strictly_inside(_probes(p), q, tol).any() or _strictly_inside(_probes(q), p, tol).any())


# ----------------------------------------------------------------------------- points


def lattice_points(domain: Domain) -> np.ndarray:
    """Candidate point positions: centres of a regular sub-grid, points_per_cell per direction."""
    s = domain.point_spacing
    nx = int(round(domain.width / s))
    ny = int(round(domain.height / s))
    xs = (np.arange(nx) + 0.5) * s
    ys = (np.arange(ny) + 0.5) * s
    gx, gy = np.meshgrid(xs, ys, indexing="xy")
    return np.column_stack([gx.ravel(), gy.ravel()])


@dataclass
class Points:
    """Material points of one scene (numpy, float64): the MPM's initial state."""

    position: np.ndarray  # [N, 2] m
    velocity: np.ndarray  # [N, 2] m/s
    material_id: np.ndarray  # [N] index into scene.material_names
    fixed: np.ndarray  # [N] bool
    volume: float  # m^2 per point (plane strain, unit thickness)

    @property
    def particle_type(self) -> np.ndarray:
        return np.where(self.fixed, PARTICLE_TYPE_KINEMATIC, PARTICLE_TYPE_SOIL).astype(np.int64)

    def __len__(self) -> int:
        return len(self.position)


def fill_points(scene: Scene) -> Points:
    """Seed points on the lattice inside each region; a point on a shared edge goes to the
    first region that claims it."""
    lattice = lattice_points(scene.domain)
    names = scene.material_names
    claimed = np.zeros(len(lattice), dtype=bool)
    pos, vel, mid, fixed = [], [], [], []
    for r in scene.regions:
        inside = points_in_polygon(lattice, np.asarray(r.polygon)) & ~claimed
        claimed |= inside
        n = int(inside.sum())
        pos.append(lattice[inside])
        vel.append(np.tile(np.asarray(r.velocity, dtype=float), (n, 1)))
        mid.append(np.full(n, names.index(r.material), dtype=np.int64))
        fixed.append(np.full(n, r.fixed, dtype=bool))
    return Points(
        position=np.concatenate(pos),
        velocity=np.concatenate(vel),
        material_id=np.concatenate(mid),
        fixed=np.concatenate(fixed),
        volume=scene.domain.point_spacing**2,
    )
