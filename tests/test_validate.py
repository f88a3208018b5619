"""The fast cases of `runout validate`, against absolute references (limit theorems, Griffiths &
Lane, Coulomb sliding), and the report they write. About a minute on the 2-core CPU."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from runout.cli import main
from runout.mpm import simulate
from runout.mpm.geostatic import GRAVITY
from runout.scene import scene_from_dict
from runout.validate import case_cuts, case_griffiths_lane, run_validation


@pytest.fixture(scope="module")
def cuts():
    return case_cuts(4.0, 300)


def test_vertical_cuts_stand_below_the_lower_bound_and_fail_above_the_upper_bound(cuts):
    """phi = 0 and 20: H = 40 m stands when c puts it at 0.8 of 2c/gamma tan(45+phi/2) (the
    corrected tension cut-off: before it a cut at 0.44 of that bound crept 46 m) and fails at
    1.3 of the upper bound 3.83 c/gamma tan(45+phi/2)."""
    for res, _, _ in cuts:
        assert res.met, f"{res.case}: {res.quantity} = {res.measured:.3f}, allowed [{res.low}, {res.high}]"
    stands = [r.measured for r, _, _ in cuts if r.case.endswith("stands")]
    assert len(stands) == 2 and max(stands) < 1.0


def test_standing_cuts_start_in_equilibrium(cuts):
    """The geostatic start of a cut that stands is in equilibrium, so nothing moves on release
    but the settling of the discrete equilibrium: less than 0.25 m in 300 frames (11 s). With
    the viscous relaxation of solver 4 the face was still opening at the tension cut-off when
    released and coasted on (0.93 m at phi 0, 0.40 m at phi 20); solver 5 relaxes with local
    damping 0.8 (0.11 m and 0.03 m)."""
    stands = {r.case: r.measured for r, _, _ in cuts if r.case.endswith("stands")}
    assert len(stands) == 2
    for case, moved in stands.items():
        assert moved < 0.25, f"{case}: a cut that stands moved {moved:.3f} m after release"


def test_griffiths_lane_slope_stands_at_fs_1_4_and_fails_at_fs_0_875():
    for res, _, _ in case_griffiths_lane(4.0, 200):
        assert res.met, f"{res.case}: {res.quantity} = {res.measured:.3f}, allowed [{res.low}, {res.high}]"


@pytest.mark.parametrize("cell", [4.0, 8.0])
def test_block_slides_on_thick_fixed_ground_as_coulomb_says(cell):
    """An elastic block at 15 m/s on 12 m of fixed ground (mu 0.38) stops after v^2 / (2 mu g)
    = 30.2 m. Before the contact normals reached into the ground, nodes one cell down were held
    still (or, for a strip on the base, pointed down) and the block stopped after 3 m."""
    ground = 12.0
    scene = scene_from_dict({
        "domain": {"width": 300.0, "height": ground + 40, "base_friction": 0.38, "cell_size": cell},
        "time": {"frames": 120},
        "materials": {"b": {"model": "elastic"}, "g": {"model": "elastic"}},
        "regions": [
            {"material": "b", "polygon": [[10, ground], [50, ground], [50, ground + 8], [10, ground + 8]],
             "velocity": [15.0, 0.0]},
            {"material": "g", "polygon": [[0, 0], [300, 0], [300, ground], [0, ground]], "fixed": True},
        ],
    })
    traj = simulate([scene], progress=False)[0]
    travel = traj.positions[-1, traj.soil, 0].mean() - traj.positions[0, traj.soil, 0].mean()
    expected = 15.0**2 / (2 * 0.38 * GRAVITY)
    assert abs(travel - expected) < 0.03 * expected, f"travel {travel:.2f} m, Coulomb {expected:.2f} m"


def test_dry_column_runs_out_inside_the_experimental_band():
    """A dry a = 1 column (100 m, phi 25, c = 0) at 8 m cells against the 2D experiments and DEM
    (L^n 1.2 ... 1.67, +-25 %). In solver 3 the column's top corner glided on as a thin sheet of
    stress-free points that kept the shear profile they carried over the base (their affine
    velocity) and ended at L^n 2.18; as loose clods without affine velocity they stop near 1.2."""
    from runout.validate import case_dry_columns

    res = case_dry_columns(8.0, 600, aspects=(1.0,))[0][0]
    assert res.met, f"L^n = {res.measured:.3f}, allowed [{res.low:.2f}, {res.high:.2f}]"


def test_report_lists_every_check_with_its_figure(tmp_path):
    results = run_validation(tmp_path, cases=["cuts"], command="runout validate --case cuts", progress=lambda s: None)
    text = (tmp_path / "validation.md").read_text()
    assert "runout validate --case cuts" in text
    for r in results:
        assert r.case in text
        assert (tmp_path / f"{r.case}.png").stat().st_size > 1000
    data = json.loads((tmp_path / "results.json").read_text())
    assert [d["case"] for d in data] == [r.case for r in results]
    assert all(isinstance(d["met"], bool) for d in data)


def test_unknown_case_is_one_sentence_and_exit_2(tmp_path, capsys):
    with pytest.raises(SystemExit) as exc:
        main(["validate", "--case", "nope", "--out", str(tmp_path / "v")])
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "'nope'" in err[0] and "cuts" in err[0]
    assert not (tmp_path / "v").exists()


def test_dry_envelope_is_the_experimental_law():
    from runout.validate import dry_envelope

    assert dry_envelope(1.0) == pytest.approx((1.2, 1.67))
    lo, hi = dry_envelope(4.0)
    assert lo == pytest.approx(1.9 * 4 ** (2 / 3)) and hi == pytest.approx(2.7 * 4 ** (2 / 3))
    assert math.isclose(np.float64(dry_envelope(2.3)[0]), 2.76)


def test_block_on_an_incline_follows_coulomb():
    """An elastic block on fixed ground inclined at 30 degrees, mu 0.3: s = g (sin - mu cos) t^2 / 2
    within 3 % after 4.5 s (normals from the smoothed staircase of fixed points leaned 1 degree
    and gave +5 %)."""
    from runout.validate import case_incline

    res = case_incline(4.0, 120)[0][0]
    assert res.met, f"s / s_theory = {res.measured:.4f}"
