"""Scene families: every sample lies in the paper's ranges and tiles its layers exactly."""

from collections import Counter

import numpy as np
import pytest
from typer.testing import CliRunner

from runout.cli.app import app
from runout.defaults import PARTICLE_TYPE_KINEMATIC
from runout.families import (
    BLOCK_COUNT, BLOCK_SIDE, BLOCK_SPEED, COLUMN_STUDY_CLEARANCE, COLUMN_STUDY_GEOMETRIES, DOMAIN_HEIGHT, GROUND_TOP,
    STAGES, family_sequence, sample, sample_for_index, vertex_ranges,
)
from runout.scene import (
    edges_cross, fill_points, points_in_polygon, polygon_area, polygon_self_intersects, polygons_overlap,
    check_scene,
)

N_SAMPLES = 200
CASES = [(stage, family) for stage in STAGES for family in STAGES[stage].mix]


def _samples(stage, family, n=N_SAMPLES, seed=7):
    rng = np.random.default_rng(seed)
    return [sample(STAGES[stage], family, rng) for _ in range(n)]


def _assert_in(value, lo_hi, what):
    lo, hi = lo_hi
    assert lo - 1e-9 <= value <= hi + 1e-9, f"{what} = {value} outside [{lo}, {hi}]"


def _assert_disjoint(polys, width):
    """No two polygons share interior: no proper edge crossings, and no point of a fine
    lattice lies inside two of them."""
    for a in range(len(polys)):
        for b in range(a + 1, len(polys)):
            assert not edges_cross(polys[a], polys[b], 1e-6), f"regions {a} and {b} cross"
    gx, gy = np.meshgrid(np.arange(0.31, width, 2.1), np.arange(0.17, DOMAIN_HEIGHT, 2.1))
    lattice = np.column_stack([gx.ravel(), gy.ravel()])
    cover = sum(points_in_polygon(lattice, p).astype(int) for p in polys)
    assert cover.max() <= 1, "two regions overlap"


def _outline(s):
    """The polygon the soil regions should tile exactly, from the table vertices."""
    v = s.vertices
    if s.family == "b":
        return [(0, GROUND_TOP), v["[3]"], v["[9]"], v["[8]"]]
    if s.family == "c":
        return [(0, GROUND_TOP), v["[3]"], v["[7]"], v["[6]"]]
    found = np.array([v[k] for k in ("[4]", "[5]", "[6]", "[7]")])
    lift = lambda k: (v[k][0], float(np.interp(v[k][0], found[:, 0], found[:, 1])) + v[k][1])  # noqa: E731
    x0, x3 = v["[0]"][0], v["[3]"][0]
    base = [lift("[0]")] + [tuple(p) for p in found if x0 < p[0] < x3] + [lift("[3]")]
    return base + [lift("[11]"), lift("[10]")]


@pytest.mark.parametrize("stage,family", CASES)
def test_samples_stay_in_ranges_and_tile_without_gaps(stage, family):
    st = STAGES[stage]
    table = vertex_ranges(family, st.width)
    for s in _samples(stage, family):
        scene = s.scene
        assert scene.domain.width == st.width and scene.domain.height == st.height
        for label, (x, y) in s.vertices.items() if st.column_base is None else ():
            _assert_in(x, table[label][0], f"{family}{label}.x")
            _assert_in(y, table[label][1], f"{family}{label}.y")
        for m in scene.materials.values():
            if m.model == "elastic":
                assert m.youngs_modulus == 50.0
                continue
            _assert_in(m.friction_angle, st.friction_range, "phi")
            _assert_in(m.cohesion, st.cohesion_range or (0.0, 0.0), "c")
            assert (m.youngs_modulus, m.poisson_ratio, m.density) == (40.0, 0.3, 1800.0)
        polys = [np.asarray(r.polygon) for r in scene.regions]
        for p in polys:
            assert polygon_area(p) > 0 and not polygon_self_intersects(p)
            assert p[:, 0].min() >= 0 and p[:, 0].max() <= st.width
            assert p[:, 1].min() >= 0 and p[:, 1].max() <= st.height
        _assert_disjoint(polys, st.width)
        soil = [r for r in scene.regions if not r.fixed]
        assert len({r.material for r in soil}) == len(soil), "each soil region has its own material"
        if family in ("b", "c", "d"):
            tiled = sum(polygon_area(np.asarray(r.polygon)) for r in soil)
            assert tiled == pytest.approx(polygon_area(np.asarray(_outline(s), dtype=float)), rel=1e-9)


@pytest.mark.parametrize("stage,family", CASES)
def test_every_region_holds_points_at_the_paper_spacing(stage, family):
    for s in _samples(stage, family, n=20, seed=11):
        pts = fill_points(s.scene)
        ids = [s.scene.material_names.index(r.material) for r in s.scene.regions]
        for r, mid in zip(s.scene.regions, ids):
            assert (pts.material_id == mid).sum() >= 10, f"{r.material} is a sliver"
        fixed_types = pts.particle_type[pts.fixed]
        assert (fixed_types == PARTICLE_TYPE_KINEMATIC).all()


def test_blocks_are_squares_above_the_ground_with_bounded_velocities():
    for s in _samples("base", "a"):
        blocks = [r for r in s.scene.regions if not r.fixed]
        assert BLOCK_COUNT[0] <= len(blocks) <= BLOCK_COUNT[1]
        ground = np.array([s.vertices[k] for k in ("[0]", "[1]", "[2]", "[3]", "[4]")])
        assert np.all(np.diff(ground[:, 0]) >= 0)
        for b in blocks:
            p = np.asarray(b.polygon)
            w, h = np.ptp(p[:, 0]), np.ptp(p[:, 1])
            assert w == pytest.approx(h)
            _assert_in(w, BLOCK_SIDE, "block side")
            for v in b.velocity:
                _assert_in(v, BLOCK_SPEED, "block velocity")
            xs = np.linspace(p[:, 0].min(), p[:, 0].max(), 50)
            assert p[:, 1].min() > np.interp(xs, ground[:, 0], ground[:, 1]).max()


def test_columns_stand_against_the_left_wall_on_the_base():
    for s in _samples("finetune", "column", n=50):
        (region,) = s.scene.regions
        p = np.asarray(region.polygon)
        assert p[:, 0].min() == 0 and p[:, 1].min() == 0
        _assert_in(np.ptp(p[:, 0]), (50, 100), "column width")
        _assert_in(np.ptp(p[:, 1]), (50, 100), "column height")


def test_the_columns_stage_spans_the_column_study_but_leaves_its_cases_out():
    """The `columns` stage covers the paper's column grid (phi 0-45 deg, c 10-70 kPa, a 0.5-2,
    its 1000 x 208 m domain) and never draws one of the study's three geometries."""
    st = STAGES["columns"]
    assert (st.width, st.height) == (1000.0, 208.0) and st.friction_range == (0.0, 45.0) and st.cohesion_range == (5.0, 75.0)
    sizes, phis, cs = [], [], []
    for s in _samples("columns", "column", n=400):
        (region,) = s.scene.regions
        p = np.asarray(region.polygon)
        assert p[:, 0].min() == 0 and p[:, 1].min() == 0
        base, height = np.ptp(p[:, 0]), np.ptp(p[:, 1])
        _assert_in(base, st.column_base, "column base")
        _assert_in(height / base, st.column_aspect, "column aspect")
        assert height <= st.height - 8.0
        for b, h in COLUMN_STUDY_GEOMETRIES:
            assert abs(base - b) > COLUMN_STUDY_CLEARANCE or abs(height - h) > COLUMN_STUDY_CLEARANCE
        (m,) = s.scene.materials.values()
        sizes.append((base, height)), phis.append(m.friction_angle), cs.append(m.cohesion)
    aspects = np.array([h / b for b, h in sizes])
    assert aspects.min() < 0.5 and aspects.max() > 2.0  # the study's a = 0.5 and 2 lie inside the drawn range
    assert min(phis) < 2.0 and max(phis) > 43.0 and min(cs) < 10.0 and max(cs) > 70.0


@pytest.mark.parametrize("stage,family", CASES)
def test_samples_pass_check_scene(stage, family):
    for s in _samples(stage, family, n=3, seed=3):
        check_scene(s.scene, f"{stage}/{family}")


def test_family_mix_follows_the_paper_in_every_prefix():
    assert Counter(family_sequence(STAGES["base"], 2000)) == {"a": 500, "b": 500, "c": 500, "d": 500}
    assert Counter(family_sequence(STAGES["finetune"], 1027)) == {"b": 250, "c": 250, "d": 500, "column": 27}
    seq = family_sequence(STAGES["finetune"], 1027)
    assert seq[:100] == family_sequence(STAGES["finetune"], 100)
    shares = Counter(seq[:100])
    assert abs(shares["d"] - 100 * 500 / 1027) <= 1 and shares["column"] in (2, 3)


def test_scene_k_depends_only_on_seed_stage_and_k():
    a = sample_for_index(STAGES["finetune"], 5, 42, "d").scene
    b = sample_for_index(STAGES["finetune"], 5, 42, "d").scene
    c = sample_for_index(STAGES["finetune"], 5, 43, "d").scene
    d = sample_for_index(STAGES["base"], 5, 42, "d").scene
    assert a == b and a != c and a.regions != d.regions


def test_families_command_draws_a_grid(tmp_path):
    out = tmp_path / "grid.png"
    result = CliRunner().invoke(app, ["families", "--family", "d", "--count", "4", "--out", str(out),
                                      "--scenes", str(tmp_path / "scenes")])
    assert result.exit_code == 0, result.output
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert len(list((tmp_path / "scenes").glob("*.toml"))) == 4
    bad = CliRunner().invoke(app, ["families", "--family", "a", "--stage", "finetune", "--out", str(out)])
    assert bad.exit_code != 0
