"""The Mohr-Coulomb / tension cut-off return of src/runout/mpm/mohr_coulomb.py, point by point.

Plane strain, E 40 MPa, nu 0.3 (lambda / (lambda + 2G) = nu / (1 - nu) = 0.4286). Stresses in
Pa, tension positive. Each check is a closed-form property of the return, not a rerun of it."""

from __future__ import annotations

import math

import pytest
import torch

from runout.mpm.mohr_coulomb import MaterialArrays, return_map

E, NU = 40e6, 0.3
LAM = E * NU / ((1 + NU) * (1 - 2 * NU))
G = E / (2 * (1 + NU))


def material(phi: float, c: float, cut: float, n: int) -> MaterialArrays:
    full = lambda v: torch.full((n,), float(v), dtype=torch.float64)  # noqa: E731
    r = math.radians(phi)
    return MaterialArrays(full(LAM), full(G), full(math.sin(r)), full(math.cos(r)), full(c), full(cut),
                          torch.ones(n, dtype=torch.bool))


def principal(stress: torch.Tensor):
    s = 0.5 * (stress[:, 0] + stress[:, 1])
    t = torch.sqrt((0.5 * (stress[:, 0] - stress[:, 1])) ** 2 + stress[:, 2] ** 2)
    return s + t, s - t, s, t


def test_tension_cut_off_is_an_opening_across_the_major_direction():
    """Trial sigma_h = +5 kPa against sigma_v = -300 kPa (far inside the shear surface): the
    return puts sigma_h at T and lowers sigma_v and sigma_zz by nu/(1-nu) of the drop, the
    elastic response to a pure horizontal opening. Keeping sigma_v (the old return) hides a
    vertical plastic shortening through which gravity made cut faces creep."""
    cut = 100.0
    trial = torch.tensor([[5e3, -300e3, 0.0, -90e3]], dtype=torch.float64)
    out = return_map(trial, material(0.0, 800e3, cut, 1))[0]
    drop = 5e3 - cut
    ratio = NU / (1 - NU)
    assert out[0].item() == pytest.approx(cut, abs=1e-6)
    assert out[1].item() == pytest.approx(-300e3 - ratio * drop, rel=1e-9)
    assert out[3].item() == pytest.approx(-90e3 - ratio * drop, rel=1e-9)


def test_shear_return_keeps_the_in_plane_mean_stress():
    trial = torch.tensor([[-10e3, -300e3, 50e3, -100e3]], dtype=torch.float64)
    mat = material(30.0, 0.0, 0.0, 1)
    out = return_map(trial, mat)
    _, _, s_in, _ = principal(trial)
    s1, s3, s, t = principal(out)
    assert s.item() == pytest.approx(s_in.item(), rel=1e-12)
    assert t.item() == pytest.approx(-s.item() * 0.5, rel=1e-9)  # on the surface t = -s sin 30


@pytest.mark.parametrize("phi,c,cut", [(0.0, 800e3, 100.0), (20.0, 400e3, 100.0), (30.0, 0.0, 0.0), (35.0, 20e3, 10e3)])
def test_every_return_is_admissible_and_stays_put_when_inside(phi, c, cut):
    """Random trial states: after the return the state is on or inside both surfaces; a second
    return changes nothing (the result is a fixed point); states inside are untouched."""
    gen = torch.Generator().manual_seed(3)
    n = 4000
    trial = (torch.rand(n, 4, generator=gen, dtype=torch.float64) - 0.7) * 2e6
    trial[:, 3] = 0.5 * (trial[:, 0] + trial[:, 1])
    mat = material(phi, c, min(cut, c / math.tan(math.radians(phi))) if phi > 0 else cut, n)
    out = return_map(trial, mat)
    s1, s3, s, t = principal(out)
    sin, cos = math.sin(math.radians(phi)), math.cos(math.radians(phi))
    tol = 1e-6 * (1e3 + c)
    assert torch.all(t + s * sin - c * cos <= tol)
    assert torch.all(s1 <= mat.tension + tol)
    assert torch.all((out[:, 3] <= s1 + tol) & (out[:, 3] >= s3 - tol))
    again = return_map(out, mat)
    assert torch.allclose(again, out, atol=tol)
    t1, t3, ts, tt = principal(trial)
    inside = (tt + ts * sin - c * cos < 0) & (t1 < mat.tension) & (trial[:, 3] <= t1) & (trial[:, 3] >= t3)
    assert inside.any()
    assert torch.allclose(out[inside], trial[inside])


def test_corner_of_shear_and_tension():
    """Tresca (phi = 0, c = 100 kPa, T = 0.1 kPa): a trial far beyond both surfaces in the
    opening direction lands on their corner, s1 = T and s3 = T - 2c."""
    c, cut = 100e3, 100.0
    trial = torch.tensor([[400e3, -100e3, 0.0, 0.0]], dtype=torch.float64)
    out = return_map(trial, material(0.0, c, cut, 1))
    s1, s3, _, _ = principal(out)
    assert s1.item() == pytest.approx(cut, abs=1e-6)
    assert s3.item() == pytest.approx(cut - 2 * c, rel=1e-9)


def test_dilute_points_carry_no_stress_and_take_it_again_when_packed():
    """A point spread over more than twice its packed area has lost its contacts: after a
    substep it carries no stress (a cohesive column on a rough base otherwise grew points to
    20,000 times their area, with stress, and blew up); packed points keep theirs."""
    from runout.mpm.setup import build_batch
    from runout.mpm.solver import substep
    from runout.scene import scene_from_dict

    scene = scene_from_dict({"domain": {"width": 40.0, "height": 40.0}, "time": {"frames": 2},
                             "materials": {"s": {"friction_angle": 30.0, "cohesion": 50.0}},
                             "regions": [{"material": "s", "polygon": [[0, 0], [20, 0], [20, 20], [0, 20]]}]})
    batch = build_batch([scene], torch.device("cpu"), torch.float64)
    pts = batch.pts
    spread = torch.arange(len(pts.x)) % 3 == 0
    pts.volume = torch.where(spread, 2.5 * pts.rest_volume, pts.volume)
    substep(pts, batch.grid, batch.dt)
    assert torch.all(pts.stress[spread] == 0)
    assert torch.all(pts.stress[~spread, 1] < 0)
    pts.volume = pts.rest_volume.clone()
    substep(pts, batch.grid, batch.dt)
    assert torch.any(pts.stress[spread] != 0)
