"""Random scene families for training data (paper section "Datasets", Table A.1).

Families: (a) square blocks thrown over uneven ground, (b) steep three-layer slopes,
(c) gentle three-layer slopes, (d) zoned dams on a foundation, granular column collapses,
layered mounds and four-zone dams on the rough base. Six stages: `base` (phi 10-40 deg,
c = 0, 300 x 152 m, families a-d), `finetune` (phi 3-35 deg, c 10-60 kPa, 400 x 152 m,
families b-d and columns), `columns` (columns alone over the range of the paper's column
study, section 5.1.1: phi 0-45 deg, c 5-75 kPa, 1000 x 208 m like its cases, base 60-220 m,
aspect H0 / L0 0.3-2.5 drawn log-uniformly; the study's own 75 cases stay out, see
COLUMN_STUDY_GEOMETRIES), `tall-columns` (the same with base 40-120 m and aspect 1.2-2.5:
the `columns` stage draws few tall columns, 12 of its 160 training scenes at a >= 1.5, and
the learned engines' toes run furthest there), `mounds` (mounds alone, around the paper's four-layer slope,
section 5.1.2: phi 0-45 deg, c 0-75 kPa per layer, 1000 x 200 m like it; the slope's own
geometry stays out, see FOUR_LAYER_SLOPE) and `dams` (four-zone dams alone, around the
paper's dam of the inverse analysis, section 5.2: phi 0-45 deg, c 0-110 kPa per zone, a
quarter of the zones undrained, 800 x 100 m like it; the dam's own geometry stays out, see
DAM_EXAMPLE).

A mound is a trapezoid on the rough base (no ground strip, as in the example) cut into 2-4
horizontal layers. Each range holds the slope's value (in brackets) with room on both sides,
so a learned engine interpolates there: base width 150-500 m (300), height 60-180 m (150),
crest 0-40 % of the base (20 %), the left face's share of the horizontal run base - crest
0.25-0.75 (0.5; else the crest sits off centre and the faces differ), each face 20-75 deg (51:
flatter faces barely move, steeper ones are the columns'), the base's centre at x 400-600 m
(500), so each toe is at least 150 m from a wall (the slope's MPM run spreads about 165 m past
its toes); layer boundaries uniform in the height, every layer at least MOUND_MIN_LAYER thick.

A zoned dam is a trapezoid on the rough base (no foundation, as in examples/dam.toml) cut into
an upstream shell (left), a core and a downstream shell split at some height into a lower and
an upper layer. Ranges (the example's value in brackets): base width 160-400 m (260), height
30-96 m (60; 96 is the 100 m domain less HEADROOM), crest 10-40 m (20), the upstream face's
share of the run base - crest 0.3-0.7 (0.5), each face 15-40 deg (26.6), the base's centre at
x 350-450 m (400), so each toe is at least 150 m from a wall (the example's outermost points
move 47-62 m downstream in its 400 frames, at 8 and 4 m cells); the core 16-80 m wide at the base
(40) and 25-75 % of the crest wide at the crest (50 %), its top centred on the crest, its
centre line leaning -15 to 15 deg from the vertical (0); the downstream shell split at
0.15-0.6 of the height (1/3).
Every zone at least DAM_MIN_ZONE thick. Each zone has its own material; with probability
DAM_UNDRAINED it is undrained clay (phi = 0 exactly, c = s_u from the c range), the
total-stress case of the example's lower downstream shell, which a uniform phi almost never
draws (and phi = 0 is where the learned engines fall shortest in the column study).

Every vertex, size, velocity and property is drawn uniformly from its range
(`vertex_ranges`), but for the undrained zones' phi = 0. A draw whose layers would cross, overhang or be thinner than
MIN_THICKNESS is redrawn whole (rejection sampling), so the accepted scenes are uniform
over the valid part of the ranges and every value stays inside its range. Geometry reading
(the paper's figure is missing) is explained in docs/datasets.md. Units: m, m/s, degrees, kPa.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from runout.errors import InputError
from runout.outputs import check_folder, check_picture, claim
from runout.scene import Domain, Material, Region, Scene, TimeSpec, polygon_area, polygon_self_intersects, save_scene

DOMAIN_HEIGHT = 152.0  # m, the base and finetune stages
COLUMN_DOMAIN = (1000.0, 208.0)  # m, the paper's column study (examples/column_a*.toml)
COLUMN_STUDY_GEOMETRIES = ((200.0, 100.0), (150.0, 150.0), (100.0, 200.0))  # (L0, H0) m of its a = 0.5, 1, 2
TALL_COLUMN_BASE = (40.0, 120.0)  # m: L0 of a `tall-columns` draw
TALL_COLUMN_ASPECT = (1.2, 2.5)  # H0 / L0 of a `tall-columns` draw, log-uniform (the study's a = 2 inside)
COLUMN_STUDY_CLEARANCE = 5.0  # m: a `columns` draw within this of a study geometry in both sides is redrawn
GROUND_TOP = 4.0  # m, top of the fixed ground strip under the layered slopes (b, c)
MIN_THICKNESS = 4.0  # m, thinnest layer or gap allowed (two point spacings at 4 m cells)
MOUND_DOMAIN = (1000.0, 200.0)  # m, the paper's four-layer slope (examples/four_layer_slope.toml)
MOUND_BASE = (150.0, 500.0)  # m, base width
MOUND_HEIGHT = (60.0, 180.0)  # m
MOUND_CREST = (0.0, 0.4)  # crest width / base width
MOUND_LEFT_RUN = (0.25, 0.75)  # the left face's share of the horizontal run (base - crest); 0.5: symmetric
MOUND_FACE = (20.0, 75.0)  # degrees from the horizontal, each side face
MOUND_CENTRE = (400.0, 600.0)  # m, x of the base's centre: every toe 150 m or more from a wall
MOUND_LAYERS = (2, 4)  # horizontal layers (drawn alike; thin draws redrawn, so 2 come most: 45, 34, 20 %)
MOUND_MIN_LAYER = 8.0  # m, thinnest layer and narrowest crest (two point spacings at the stage's 8 m cells)
FOUR_LAYER_SLOPE = (300.0, 150.0, 60.0)  # (base, height, crest) m of the paper's four-layer slope
FOUR_LAYER_CLEARANCE = 10.0  # m: a `mounds` draw within this of FOUR_LAYER_SLOPE in all three is redrawn
DAM_DOMAIN = (800.0, 100.0)  # m, the paper's dam of the inverse analysis (examples/dam.toml)
DAM_BASE = (160.0, 400.0)  # m, base width (260)
DAM_HEIGHT = (30.0, 96.0)  # m (60); 96 = the domain's 100 m less HEADROOM
DAM_CREST = (10.0, 40.0)  # m, crest width (20)
DAM_UPSTREAM_RUN = (0.3, 0.7)  # the upstream (left) face's share of the horizontal run base - crest (0.5)
DAM_FACE = (15.0, 40.0)  # degrees from the horizontal, each outer face (26.6)
DAM_CENTRE = (350.0, 450.0)  # m, x of the base's centre (400): every toe 150 m or more from a wall
DAM_CORE_BASE = (16.0, 80.0)  # m, the core's width at the base (40)
DAM_CORE_CREST = (0.25, 0.75)  # the core's width at the crest / crest width (0.5), centred on the crest
DAM_CORE_LEAN = (-15.0, 15.0)  # degrees from the vertical of the core's centre line, + leaning downstream (0)
DAM_SPLIT = (0.15, 0.6)  # height of the downstream shell's split / dam height (1/3)
# m, thinnest zone: the example's shells are 5 m wide at the crest (4.85 m from corner to core),
# so the 8 m of the mounds would leave its shape out; 4 m is one point spacing at 8 m cells
DAM_MIN_ZONE = 4.0
DAM_UNDRAINED = 0.25  # chance that a zone is undrained clay: phi = 0, c = s_u from the stage's c range
DAM_EXAMPLE = (260.0, 60.0, 20.0)  # (base, height, crest) m of the paper's dam
DAM_CLEARANCE = 10.0  # m: a `dams` draw within this of DAM_EXAMPLE in all three is redrawn
HEADROOM = 4.0  # m, free space kept under the domain's top wall
BLOCK_CLEARANCE = 2.0  # m, gap between a block and the ground or another block
MAX_DRAWS = 10_000  # rejection-sampling attempts before giving up (never reached in practice)

SOIL_E = 40.0  # MPa (paper Table 1)
GROUND_E = 50.0  # MPa, linear-elastic ground and foundation
POISSON = 0.3
DENSITY = 1800.0  # kg/m^3

FAMILIES = ("a", "b", "c", "d", "column", "mound", "zoned_dam")
FAMILY_TITLES = {
    "a": "blocks over uneven ground",
    "b": "steep three-layer slope",
    "c": "gentle three-layer slope",
    "d": "zoned dam on a foundation",
    "column": "column collapse",
    "mound": "layered mound",
    "zoned_dam": "four-zone dam on the rough base",
}


@dataclass(frozen=True)
class Stage:
    name: str
    stage_id: int  # part of every scene's random seed
    width: float  # m, domain width
    friction_range: tuple[float, float]  # degrees
    cohesion_range: tuple[float, float] | None  # kPa; None = cohesionless
    mix: dict[str, int]  # family -> relative share of the dataset
    feature_width: int  # GNS material features: 1 = [tan phi], 2 = [tan phi, c / 100 kPa]
    height: float = DOMAIN_HEIGHT  # m, domain height
    column_base: Range | None = None  # m: L0 of a column; None: Table A.1's column sizes
    column_aspect: Range | None = None  # H0 / L0, drawn log-uniformly
    undrained_share: float = 0.0  # chance that a soil region is undrained: phi = 0, c from cohesion_range


STAGES = {
    "base": Stage("base", 0, 300.0, (10.0, 40.0), None, {"a": 500, "b": 500, "c": 500, "d": 500}, 1),
    "finetune": Stage(
        "finetune", 1, 400.0, (3.0, 35.0), (10.0, 60.0), {"b": 250, "c": 250, "d": 500, "column": 27}, 2
    ),
    "columns": Stage(
        "columns", 2, COLUMN_DOMAIN[0], (0.0, 45.0), (5.0, 75.0), {"column": 1}, 2, height=COLUMN_DOMAIN[1],
        column_base=(60.0, 220.0), column_aspect=(0.3, 2.5),
    ),
    "tall-columns": Stage(
        "tall-columns", 5, COLUMN_DOMAIN[0], (0.0, 45.0), (5.0, 75.0), {"column": 1}, 2, height=COLUMN_DOMAIN[1],
        column_base=TALL_COLUMN_BASE, column_aspect=TALL_COLUMN_ASPECT,
    ),
    "mounds": Stage(
        "mounds", 3, MOUND_DOMAIN[0], (0.0, 45.0), (0.0, 75.0), {"mound": 1}, 2, height=MOUND_DOMAIN[1],
    ),
    "dams": Stage(
        "dams", 4, DAM_DOMAIN[0], (0.0, 45.0), (0.0, 110.0), {"zoned_dam": 1}, 2, height=DAM_DOMAIN[1],
        undrained_share=DAM_UNDRAINED,
    ),
}

Range = tuple[float, float]


def vertex_ranges(family: str, width: float) -> dict[str, tuple[Range, Range]]:
    """Table A.1 as {vertex label: ((x_lo, x_hi), (y_lo, y_hi))} in metres for a domain of
    `width`. For the dam (d) the y of vertices [8]-[11] is the height above the foundation
    surface at that x, and [0]-[3] lie on the foundation surface."""
    w = width
    tables = {
        "a": {"[0]": ((0, 0), (4, 40)), "[1]": ((10, 290), (4, 40)), "[2]": ((10, 290), (4, 40)),
              "[3]": ((10, 290), (4, 40)), "[4]": ((w, w), (4, 40))},
        "b": {"[0]": ((0, 0), (4, 4)), "[1]": ((125, 193), (4, 4)), "[2]": ((137.5, 225), (4, 4)),
              "[3]": ((150, 225), (4, 4)), "[4]": ((0, 0), (12.5, 50)), "[5]": ((100, 100), (12.5, 50)),
              "[6]": ((0, 0), (25, 75)), "[7]": ((100, 100), (25, 37.5)), "[8]": ((0, 0), (50, 100)),
              "[9]": ((100, 100), (50, 100))},
        "c": {"[0]": ((0, 0), (4, 50)), "[1]": ((60, 100), (4, 4)), "[2]": ((90, 140), (4, 4)),
              "[3]": ((90, 150), (4, 4)), "[4]": ((0, 0), (30, 100)), "[5]": ((10, 80), (70, 100)),
              "[6]": ((0, 0), (120, 140)), "[7]": ((10, 80), (80, 120))},
        "d": {"[0]": ((0, 110), (0, 0)), "[1]": ((0, 120), (0, 0)), "[2]": ((180, w), (0, 0)),
              "[3]": ((210, w), (0, 0)), "[4]": ((0, 0), (4, 40)), "[5]": ((10, w - 10), (4, 40)),
              "[6]": ((10, w - 10), (4, 40)), "[7]": ((w, w), (4, 40)), "[8]": ((40, 170), (30, 60)),
              "[9]": ((130, 260), (30, 60)), "[10]": ((30, 160), (50, 190)), "[11]": ((140, 270), (50, 90))},
        "column": {"size": ((50, 100), (50, 100))},  # (width, height) of the column
    }
    return {k: ((float(x[0]), float(x[1])), (float(y[0]), float(y[1]))) for k, (x, y) in tables[family].items()}


BLOCK_SIDE = (40.0, 90.0)  # m
BLOCK_SPEED = (-15.0, 15.0)  # m/s, each velocity component
BLOCK_COUNT = (1, 3)


@dataclass(frozen=True)
class FamilySample:
    """A sampled scene with the table vertices it was built from (for checks and pictures)."""

    family: str
    scene: Scene
    vertices: dict[str, tuple[float, float]]  # label -> (x, y) in the frame of vertex_ranges


# ----------------------------------------------------------------------------- sampling


def sample(stage: Stage, family: str, rng: np.random.Generator, name: str = "scene") -> FamilySample:
    """Draw one scene of `family` for `stage`."""
    if family not in stage.mix:
        raise ValueError(f"family {family!r} is not part of stage {stage.name!r}")
    draw = {"a": _blocks, "b": _steep_slope, "c": _gentle_slope, "d": _dam, "column": _column, "mound": _mound,
            "zoned_dam": _zoned_dam}[family]
    for _ in range(MAX_DRAWS):
        drawn = draw(stage, rng)
        if drawn is not None:
            vertices, soil, fixed = drawn
            return FamilySample(family, _scene(stage, soil, fixed, rng, name), vertices)
    raise RuntimeError(f"family {family}: no valid draw in {MAX_DRAWS} attempts")


def sample_for_index(stage: Stage, seed: int, k: int, family: str) -> FamilySample:
    """Scene k of a dataset: its random numbers depend only on (seed, stage, k)."""
    rng = np.random.default_rng([seed, stage.stage_id, k])
    return sample(stage, family, rng, name=f"scene_{k:05d}")


def family_sequence(stage: Stage, count: int) -> list[str]:
    """Families of scenes 0..count-1: smooth weighted round-robin over stage.mix, so every
    prefix holds each family in proportion to its share (base: a b c d a b c d ...)."""
    credit = {f: 0 for f in stage.mix}
    total = sum(stage.mix.values())
    out = []
    for _ in range(count):
        for f, w in stage.mix.items():
            credit[f] += w
        best = max(stage.mix, key=lambda f: credit[f])
        credit[best] -= total
        out.append(best)
    return out


def _uniform(rng: np.random.Generator, r: Range) -> float:
    return float(rng.uniform(r[0], r[1]))


def _draw_vertices(rng, family: str, width: float, labels=None) -> dict[str, tuple[float, float]]:
    table = vertex_ranges(family, width)
    return {k: (_uniform(rng, xr), _uniform(rng, yr)) for k, (xr, yr) in table.items() if labels is None or k in labels}


def _scene(stage: Stage, soil: list[Region], fixed: list[Region], rng, name: str) -> Scene:
    """Give each soil region its own random material; fixed regions share the elastic ground.
    A stage with an undrained share makes a region undrained (phi = 0) with that chance; the
    others draw no number for it, so their scenes stay as they were."""
    materials = {}
    regions = []
    if fixed:
        materials["ground"] = Material(
            "ground", model="elastic", friction_angle=0.0, cohesion=0.0, youngs_modulus=GROUND_E,
            poisson_ratio=POISSON, density=DENSITY, k0=POISSON / (1 - POISSON),
        )
        regions += [replace(r, material="ground", fixed=True) for r in fixed]
    for k, r in enumerate(soil, start=1):
        name_k = f"soil_{k}"
        undrained = stage.undrained_share > 0 and rng.uniform() < stage.undrained_share
        phi = 0.0 if undrained else _uniform(rng, stage.friction_range)
        c = _uniform(rng, stage.cohesion_range) if stage.cohesion_range else 0.0
        materials[name_k] = Material(
            name_k, friction_angle=phi, cohesion=c, youngs_modulus=SOIL_E, poisson_ratio=POISSON, density=DENSITY
        )
        regions.append(replace(r, material=name_k))
    domain = Domain(width=stage.width, height=stage.height)
    return Scene(domain, materials, tuple(regions), TimeSpec(), name)


def _region(points) -> Region:
    return Region(material="", polygon=tuple((float(x), float(y)) for x, y in points))


# ----------------------------------------------------------------------------- (a) blocks


def _blocks(stage: Stage, rng):
    v = _draw_vertices(rng, "a", stage.width)
    xs = sorted(v[k][0] for k in ("[1]", "[2]", "[3]"))
    for k, x in zip(("[1]", "[2]", "[3]"), xs):
        v[k] = (x, v[k][1])
    ground = [v[k] for k in ("[0]", "[1]", "[2]", "[3]", "[4]")]
    boxes = []
    for _ in range(int(rng.integers(BLOCK_COUNT[0], BLOCK_COUNT[1] + 1))):
        box = _place_block(stage.width, ground, boxes, rng)
        if box is None:
            return None
        boxes.append(box)
    blocks = [
        replace(_region([(x, y), (x + s, y), (x + s, y + s), (x, y + s)]), velocity=vel)
        for x, y, s, vel in boxes
    ]
    ground_poly = [(0.0, 0.0), (stage.width, 0.0)] + ground[::-1]
    return v, blocks, [_region(ground_poly)]


def _place_block(width: float, ground, boxes, rng):
    """One square block (x, y, side, velocity) above the ground, clear of the other blocks."""
    side = _uniform(rng, BLOCK_SIDE)
    vel = (_uniform(rng, BLOCK_SPEED), _uniform(rng, BLOCK_SPEED))
    x = _uniform(rng, (0.0, width - side))
    floor = _ground_max(ground, x, x + side) + BLOCK_CLEARANCE
    top = DOMAIN_HEIGHT - HEADROOM - side
    if floor > top:
        return None
    y = _uniform(rng, (floor, top))
    for bx, by, bs, _ in boxes:
        apart_x = x >= bx + bs + BLOCK_CLEARANCE or bx >= x + side + BLOCK_CLEARANCE
        apart_y = y >= by + bs + BLOCK_CLEARANCE or by >= y + side + BLOCK_CLEARANCE
        if not (apart_x or apart_y):
            return None
    return x, y, side, vel


def _ground_max(polyline, x0: float, x1: float) -> float:
    """Highest ground elevation (m) over [x0, x1] of an x-sorted polyline."""
    p = np.asarray(polyline)
    inner = p[(p[:, 0] > x0) & (p[:, 0] < x1), 1]
    ends = np.interp([x0, x1], p[:, 0], p[:, 1])
    return float(max(ends.max(), inner.max(initial=-np.inf)))


# ----------------------------------------------------------------------------- (b), (c) layers


def _steep_slope(stage: Stage, rng):
    v = _draw_vertices(rng, "b", stage.width)
    surfaces = [[v["[4]"], v["[5]"], v["[1]"]], [v["[6]"], v["[7]"], v["[2]"]], [v["[8]"], v["[9]"], v["[3]"]]]
    return _layered(v, surfaces, stage.width)


def _gentle_slope(stage: Stage, rng):
    v = _draw_vertices(rng, "c", stage.width)
    surfaces = [[v["[0]"], v["[1]"]], [v["[4]"], v["[5]"], v["[2]"]], [v["[6]"], v["[7]"], v["[3]"]]]
    return _layered(v, surfaces, stage.width)


def _layered(v, surfaces, width: float):
    """Stack layers on a fixed ground strip: layer k lies between surface k-1 (or the base) and
    surface k; each surface runs from the left wall to its own toe on the base, further out
    than the toe below, so every layer drapes over the one beneath it."""
    if not _rests_on_base(surfaces[0]):
        return None
    for lower, upper in zip(surfaces, surfaces[1:]):
        if not _drapes_over(lower, upper):
            return None
    layers = [_region([(0.0, GROUND_TOP)] + surfaces[0][::-1])]
    layers += [_region(lower + upper[::-1]) for lower, upper in zip(surfaces, surfaces[1:])]
    ground = _region([(0.0, 0.0), (width, 0.0), (width, GROUND_TOP), (0.0, GROUND_TOP)])
    return v, layers, [ground]


def _rests_on_base(surface) -> bool:
    """The bottom layer: an x-monotone surface at least MIN_THICKNESS above the ground strip
    everywhere but at its toe, where it tapers onto the base."""
    s = np.asarray(surface)
    return bool(np.all(np.diff(s[:, 0]) > 0) and s[:-1, 1].min() - GROUND_TOP >= MIN_THICKNESS)


def _drapes_over(lower, upper) -> bool:
    """upper is x-monotone, ends on the base past lower's toe, stays above lower everywhere
    and at least MIN_THICKNESS away from it."""
    lo, up = np.asarray(lower), np.asarray(upper)
    if np.any(np.diff(up[:, 0]) <= 0) or up[-1, 0] < lo[-1, 0] + MIN_THICKNESS:
        return False
    xs = np.union1d(lo[:, 0], up[:, 0])
    xs = xs[xs <= lo[-1, 0]]
    if np.any(np.interp(xs, up[:, 0], up[:, 1]) <= np.interp(xs, lo[:, 0], lo[:, 1])):
        return False
    return min(_chain_distance(up, lo), _chain_distance(lo, up)) >= MIN_THICKNESS


def _chain_distance(points: np.ndarray, chain: np.ndarray) -> float:
    """Smallest distance (m) from any of `points` to the polyline `chain`."""
    a, b = chain[:-1], chain[1:]
    ab = b - a
    rel = points[:, None, :] - a[None, :, :]
    t = np.clip(np.einsum("psd,sd->ps", rel, ab) / np.einsum("sd,sd->s", ab, ab), 0.0, 1.0)
    nearest = a[None] + t[..., None] * ab[None]
    return float(np.linalg.norm(points[:, None, :] - nearest, axis=2).min())


# ----------------------------------------------------------------------------- (d) dam


def _dam(stage: Stage, rng):
    """A zoned dam sitting on a fixed foundation. Base points [0] < [1] < [2] < [3] lie on the
    foundation surface; [8], [9] are the core's mid-height corners, [10], [11] the crest
    corners (heights above the foundation). Zones: upstream shell [0,1,8,10], lower core
    [1,2,9,8], upper core [8,9,11,10], downstream shell [2,3,11,9]."""
    w = stage.width
    v = _draw_vertices(rng, "d", w)
    fx = sorted([v["[5]"][0], v["[6]"][0]])
    v["[5]"], v["[6]"] = (fx[0], v["[5]"][1]), (fx[1], v["[6]"][1])
    found = np.array([v["[4]"], v["[5]"], v["[6]"], v["[7]"]])
    x0, x1, x2, x3 = (v[k][0] for k in ("[0]", "[1]", "[2]", "[3]"))
    x8, x9, x10, x11 = (v[k][0] for k in ("[8]", "[9]", "[10]", "[11]"))
    ordered = (
        x1 - x0 >= MIN_THICKNESS and x2 - x1 >= MIN_THICKNESS and x3 - x2 >= MIN_THICKNESS
        and x0 <= x10 < x11 <= x3 and x8 < x9
    )
    if not ordered:
        return None

    def lift(label):  # table (x, height above foundation) -> absolute (x, y)
        x, h = v[label]
        return (x, float(np.interp(x, found[:, 0], found[:, 1])) + h)

    p8, p9, p10, p11 = (lift(k) for k in ("[8]", "[9]", "[10]", "[11]"))
    if max(p10[1], p11[1]) > stage.height - HEADROOM:
        return None
    b0, b1, b2, b3 = (lift(k) for k in ("[0]", "[1]", "[2]", "[3]"))
    zones = [
        (_along(found, b0, b1) + [p8, p10], [b0, b1, p8, p10]),
        (_along(found, b1, b2) + [p9, p8], [b1, b2, p9, p8]),
        ([p8, p9, p11, p10], [p8, p9, p11, p10]),
        (_along(found, b2, b3) + [p11, p9], [b2, b3, p11, p9]),
    ]
    outline = (_along(found, b0, b3) + [p11, p10], [b0, b3, p11, p10])
    for poly, quad in zones + [outline]:
        p = np.asarray(poly)
        if polygon_area(p) <= 0 or polygon_self_intersects(p) or _thinnest(np.asarray(quad)) < MIN_THICKNESS:
            return None
    inner = found[(found[:, 0] > x0) & (found[:, 0] < x3)]
    edges = [(b0, p10), (b1, p8), (p8, p10), (p8, p9), (b2, p9), (p9, p11), (p10, p11), (b3, p11)]
    if len(inner) and min(_chain_distance(inner, np.array(e)) for e in edges) < MIN_THICKNESS:
        return None
    foundation = [(0.0, 0.0), (w, 0.0)] + [tuple(p) for p in found[::-1]]
    return v, [_region(poly) for poly, _ in zones], [_region(foundation)]


def _along(found: np.ndarray, a, b) -> list[tuple[float, float]]:
    """The foundation surface from point a to point b (both on it), with its vertices between."""
    between = found[(found[:, 0] > a[0]) & (found[:, 0] < b[0])]
    return [a] + [(float(x), float(y)) for x, y in between] + [b]


def _thinnest(quad: np.ndarray) -> float:
    """Smallest distance (m) from a vertex to an edge not touching it: how thin the polygon gets."""
    n = len(quad)
    best = np.inf
    for i in range(n):
        for j in range(n):
            if j != i and (j + 1) % n != i:
                best = min(best, _chain_distance(quad[i : i + 1], quad[[j, (j + 1) % n]]))
    return best


# ----------------------------------------------------------------------------- column


def _column(stage: Stage, rng):
    if stage.column_base is None:
        v = _draw_vertices(rng, "column", stage.width)
    else:
        base = _uniform(rng, stage.column_base)
        aspect = float(np.exp(rng.uniform(*np.log(stage.column_aspect))))
        v = {"size": (base, aspect * base)}
        if not _column_allowed(stage, *v["size"]):
            return None
    w, h = v["size"]
    return v, [_region([(0.0, 0.0), (w, 0.0), (w, h), (0.0, h)])], []


def _column_allowed(stage: Stage, base: float, height: float) -> bool:
    """A `columns` draw fits under the top wall and is none of the column study's own
    geometries (within COLUMN_STUDY_CLEARANCE m in both sides)."""
    if height > stage.height - HEADROOM - MIN_THICKNESS:
        return False
    return all(abs(base - b) > COLUMN_STUDY_CLEARANCE or abs(height - h) > COLUMN_STUDY_CLEARANCE
               for b, h in COLUMN_STUDY_GEOMETRIES)


# ----------------------------------------------------------------------------- mound


def _mound(stage: Stage, rng):
    """A trapezoid mound on the base cut into horizontal layers (the bottom one first). Its
    corners: toes [0] (left), [1] (right) on the base, crest corners [2] (right), [3] (left)."""
    base, height = _uniform(rng, MOUND_BASE), _uniform(rng, MOUND_HEIGHT)
    crest = _uniform(rng, MOUND_CREST) * base
    left_run = _uniform(rng, MOUND_LEFT_RUN) * (base - crest)
    right_run = base - crest - left_run
    x0 = _uniform(rng, MOUND_CENTRE) - base / 2
    count = int(rng.integers(MOUND_LAYERS[0], MOUND_LAYERS[1] + 1))
    levels = np.concatenate([[0.0], np.sort(rng.uniform(0.0, height, count - 1)), [height]])
    faces = np.degrees(np.arctan2(height, [left_run, right_run]))
    if _near_four_layer_slope(base, height, crest) or faces.min() < MOUND_FACE[0] or faces.max() > MOUND_FACE[1]:
        return None
    if np.diff(levels).min() < MOUND_MIN_LAYER:
        return None

    def across(y):  # the left and right faces at height y
        return [(x0 + left_run * y / height, y), (x0 + base - right_run * y / height, y)]

    layers = [across(lo) + across(hi)[::-1] for lo, hi in zip(levels, levels[1:])]
    if min(_thinnest(np.array(q)) for q in layers) < MOUND_MIN_LAYER:
        return None
    corners = across(0.0) + across(height)[::-1]
    v = {f"[{k}]": (float(x), float(y)) for k, (x, y) in enumerate(corners)}
    return v, [_region(q) for q in layers], []


def _near_four_layer_slope(base: float, height: float, crest: float) -> bool:
    """Whether a mound is the paper's four-layer slope: within FOUR_LAYER_CLEARANCE m of it in
    base, height and crest at once (at any offset, layering or strength)."""
    return all(abs(value - slope) <= FOUR_LAYER_CLEARANCE for value, slope in zip((base, height, crest), FOUR_LAYER_SLOPE))


# ----------------------------------------------------------------------------- zoned dam


def _zoned_dam(stage: Stage, rng):
    """A trapezoid dam on the base cut into four zones: upstream shell, core, downstream shell
    below and above its split. Corners: toes [0] (upstream, left), [1] on the base, crest corners
    [2] (right), [3]; the core's corners [4], [5] on the base, [6], [7] at the crest (right one
    first); [8] on the core's right side and [9] on the downstream face at the split's height."""
    base, height, crest = _uniform(rng, DAM_BASE), _uniform(rng, DAM_HEIGHT), _uniform(rng, DAM_CREST)
    up_run = _uniform(rng, DAM_UPSTREAM_RUN) * (base - crest)
    down_run = base - crest - up_run
    x0 = _uniform(rng, DAM_CENTRE) - base / 2
    core_base, core_crest = _uniform(rng, DAM_CORE_BASE), _uniform(rng, DAM_CORE_CREST) * crest
    lean, split = np.radians(_uniform(rng, DAM_CORE_LEAN)), _uniform(rng, DAM_SPLIT) * height
    faces = np.degrees(np.arctan2(height, [up_run, down_run]))
    if _near_example_dam(base, height, crest) or faces.min() < DAM_FACE[0] or faces.max() > DAM_FACE[1]:
        return None
    top = x0 + up_run + crest / 2  # the core's centre at the crest
    bottom = top - height * np.tan(lean)  # and at the base

    def core_right(y):  # the core's right (downstream) side at height y
        return bottom + core_base / 2 + (top + core_crest / 2 - bottom - core_base / 2) * y / height

    corners = [(x0, 0.0), (x0 + base, 0.0), (x0 + up_run + crest, height), (x0 + up_run, height),
               (bottom - core_base / 2, 0.0), (bottom + core_base / 2, 0.0),
               (top + core_crest / 2, height), (top - core_crest / 2, height),
               (core_right(split), split), (x0 + base - down_run * split / height, split)]
    p = [(float(x), float(y)) for x, y in corners]
    # upstream shell, core, downstream shell below and above the split: examples/dam.toml's order
    zones = [[p[0], p[4], p[7], p[3]], [p[4], p[5], p[6], p[7]], [p[5], p[1], p[9], p[8]], [p[8], p[9], p[2], p[6]]]
    # the core's sides run from the base between the toes to the crest between its corners
    inside = p[0][0] < p[4][0] < p[5][0] < p[1][0] and p[3][0] < p[7][0] < p[6][0] < p[2][0]
    if not inside or not all(_whole_zone(np.array(q)) for q in zones):
        return None
    return {f"[{k}]": q for k, q in enumerate(p)}, [_region(q) for q in zones], []


def _whole_zone(quad: np.ndarray) -> bool:
    """A zone is a simple polygon, counter-clockwise, at least DAM_MIN_ZONE thick everywhere."""
    return polygon_area(quad) > 0 and not polygon_self_intersects(quad) and _thinnest(quad) >= DAM_MIN_ZONE


def _near_example_dam(base: float, height: float, crest: float) -> bool:
    """Whether a dam is the paper's (examples/dam.toml): within DAM_CLEARANCE m of it in base,
    height and crest at once (at any offset, zoning or strength)."""
    return all(abs(value - dam) <= DAM_CLEARANCE for value, dam in zip((base, height, crest), DAM_EXAMPLE))


def draw_family(
    family: str, out: Path, count: int = 12, stage: str | None = None, seed: int = 0,
    scenes: Path | None = None, force: bool = False,
) -> None:
    """Draw `count` random scenes of a family (stage: base, finetune for columns, mounds for
    mounds, dams for zoned dams) into the picture OUT, and write each as TOML into SCENES when
    given (`runout families`)."""
    if family not in FAMILIES:
        raise InputError(f"--family {family!r} must be one of {', '.join(FAMILIES)}.")
    stage = stage or {"column": "finetune", "mound": "mounds", "zoned_dam": "dams"}.get(family, "base")
    if stage not in STAGES:
        raise InputError(f"--stage {stage!r} must be one of {', '.join(STAGES)}.")
    if family not in STAGES[stage].mix:
        raise InputError(f"--family {family} is not part of the {stage} stage (it has {', '.join(STAGES[stage].mix)}).")
    if not 1 <= count <= 200:
        raise InputError(f"--count {count} is outside the allowed range [1, 200].")
    check_picture(out)
    names = [f"{family}_{k:03d}" for k in range(count)]
    folder = check_folder(scenes, "families", [f"{n}.toml" for n in names], force=force, option="--scenes") if scenes else None
    rng = np.random.default_rng([seed, STAGES[stage].stage_id, FAMILIES.index(family)])
    samples = [sample(STAGES[stage], family, rng, name=name) for name in names]
    from runout.plots.families import draw_grid  # Matplotlib only when a picture is drawn

    out.parent.mkdir(parents=True, exist_ok=True)
    draw_grid([(s.scene, s.family) for s in samples], out)
    if folder is not None:
        claim(folder)
        for s in samples:
            save_scene(s.scene, scenes / f"{s.scene.name}.toml")
