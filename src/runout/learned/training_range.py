"""What a learned engine was trained on, recorded in its checkpoint, and warnings when it is
used outside that: friction angle, cohesion, domain size, point spacing, materials per scene.

`measure` runs at training time over the training split (soil points only) and the
dataset's metadata; the result is stored as the checkpoint's `data_ranges`:

    friction_angle_deg  [lo, hi]        from the tan(phi) feature
    cohesion_kpa        [lo, hi] | None from the c / 100 kPa feature (None: no cohesion input)
    domain_m            [width, height] the largest training domain
    point_spacing_m     float           the lattice spacing of the training scenes (the spacing
                                        every learned-engine command fills a scene at, the engine's point_spacing)
    materials_per_scene [lo, hi]        distinct soil materials in one simulation
    source              str             where the numbers come from

`range_warnings(engine, trajectory)` names each value outside them, with the range; any
engine with `data_ranges` and `material_width` (runout.learned.engine) is checked alike.
"""

from __future__ import annotations

import math

import numpy as np

from runout.contract import decode_materials, spacing_for_cells, spacing_for_radius
from runout.defaults import PARTICLE_TYPE_KINEMATIC, POINTS_PER_CELL
from runout.trajectory import Trajectory

SPACING_TOLERANCE = 0.1  # relative difference of point spacing that is still "the same graph"


def measure(materials, particle_types, meta: dict, radius: float, source: str) -> dict:
    """Ranges of the training simulations: materials [N, k] and particle_types [N] per simulation."""
    phi, c, counts = [], [], []
    for material, ptype in zip(materials, particle_types):
        soil = np.asarray(material)[np.asarray(ptype) != PARTICLE_TYPE_KINEMATIC]
        if len(soil) == 0 or soil.shape[1] == 0:
            continue
        soil_phi, soil_c = decode_materials(soil)
        phi.append(soil_phi)
        if soil_c is not None:
            c.append(soil_c)
        counts.append(len(np.unique(soil, axis=0)))
    bounds = np.asarray(meta["bounds"], dtype=float)
    # the dataset's own spacing (2 x 2 points per cell), not the model's radius, which --radius may set apart
    data_radius = float(meta.get("default_connectivity_radius", radius))  # m
    spacing = spacing_for_cells(float(meta["cell_size"])) if "cell_size" in meta else spacing_for_radius(data_radius)
    span = lambda parts: [float(min(p.min() for p in parts)), float(max(p.max() for p in parts))]  # noqa: E731
    return {
        "friction_angle_deg": span(phi) if phi else None,
        "cohesion_kpa": span(c) if c else None,
        "domain_m": [float(bounds[0, 1] - bounds[0, 0]), float(bounds[1, 1] - bounds[1, 0])],
        "point_spacing_m": spacing,
        "materials_per_scene": [min(counts), max(counts)] if counts else None,
        "source": source,
    }


def union(parts: list[dict]) -> dict:
    """The ranges of several datasets trained together (`measure` of each): each range's
    extremes, the largest domain side by side, one point spacing (they must share it)."""
    if len(parts) == 1:
        return parts[0]
    spacings = {p["point_spacing_m"] for p in parts}
    if len(spacings) > 1:
        raise ValueError(f"datasets trained together must share their point spacing, not {sorted(spacings)} m")

    def span(key):
        known = [p[key] for p in parts if p[key] is not None]
        return [min(k[0] for k in known), max(k[1] for k in known)] if known else None

    return {
        "friction_angle_deg": span("friction_angle_deg"),
        "cohesion_kpa": span("cohesion_kpa"),
        "domain_m": [max(p["domain_m"][0] for p in parts), max(p["domain_m"][1] for p in parts)],
        "point_spacing_m": spacings.pop(),
        "materials_per_scene": span("materials_per_scene"),
        "source": " + ".join(p["source"] for p in parts),
    }


def point_spacing(traj: Trajectory) -> float | None:
    """The lattice spacing of a trajectory's first frame (m): the median gap between
    distinct point x coordinates."""
    x = np.unique(np.round(traj.positions[0, :, 0].astype(np.float64), 3))
    gaps = np.diff(x)
    gaps = gaps[gaps > 1e-6]
    return float(np.median(gaps)) if len(gaps) else None


def range_warnings(engine, traj: Trajectory, what: str = "the scene") -> list[str]:
    """One sentence per value of `traj` outside the model's recorded training ranges."""
    ranges = getattr(engine, "data_ranges", None)
    if not ranges:
        return ["the model records no training ranges, so its use outside them cannot be checked."]
    out = []
    soil_ids = np.unique(traj.material_id[traj.soil])
    for k in soil_ids:
        m = traj.materials[k]
        out += _outside(f"phi = {m.friction_angle:.4g} degrees of material {m.name}", m.friction_angle,
                        ranges.get("friction_angle_deg"), "degrees")
        if engine.material_width > 1:
            out += _outside(f"c = {m.cohesion:.4g} kPa of material {m.name}", m.cohesion,
                            ranges.get("cohesion_kpa"), "kPa")
    out += _domain(traj, ranges.get("domain_m"), what)
    out += _spacing(traj, ranges.get("point_spacing_m"), what)
    count = ranges.get("materials_per_scene")
    if count and len(soil_ids) > count[1]:
        out.append(f"{what} has {len(soil_ids)} soil materials but the model was trained on at most {count[1]}.")
    return out


def bound_warnings(engine, name: str, unit: str, lower: float, upper: float) -> list[str]:
    """A free parameter's search bounds against the trained range of its property."""
    ranges = getattr(engine, "data_ranges", None) or {}
    key = "friction_angle_deg" if unit == "degrees" else "cohesion_kpa"
    trained = ranges.get(key)
    if not trained or (trained[0] <= lower and upper <= trained[1]):
        return []
    return [f"the bounds [{lower:g}, {upper:g}] {unit} of {name} reach outside the model's training range "
            f"{trained[0]:.4g}-{trained[1]:.4g} {unit}."]


def _outside(label: str, value: float, trained, unit: str) -> list[str]:
    if not trained or trained[0] - 1e-6 <= value <= trained[1] + 1e-6:
        return []
    return [f"{label} is outside the model's training range {trained[0]:.4g}-{trained[1]:.4g} {unit}."]


def _domain(traj: Trajectory, trained, what: str) -> list[str]:
    if not trained:
        return []
    width = float(traj.bounds[0][1] - traj.bounds[0][0])
    height = float(traj.bounds[1][1] - traj.bounds[1][0])
    if width <= trained[0] + 1e-6 and height <= trained[1] + 1e-6:
        return []
    return [f"the domain of {what}, {width:g} x {height:g} m, is larger than the model's training domain "
            f"{trained[0]:g} x {trained[1]:g} m."]


def _spacing(traj: Trajectory, trained, what: str) -> list[str]:
    spacing = point_spacing(traj)
    if not trained or spacing is None or math.isclose(spacing, trained, rel_tol=SPACING_TOLERANCE):
        return []
    return [f"the point spacing of {what}, {spacing:.3g} m, differs from the model's training spacing "
            f"{trained:.3g} m (fill the scene with cell_size = {POINTS_PER_CELL * trained:g} m)."]
