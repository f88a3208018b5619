"""The inverse's thickness-profile loss (runout.inverse.loss): area conserved, the thickness of
a uniform block, exact gradients, no need of point-by-point correspondence, spec checks, and an
inverse that recovers a known cohesion from the profile alone."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from runout.errors import InputError
from runout.inverse import invert, load_inverse_spec, load_observation
from runout.gns.engine import GnsEngine
from runout.inverse.forward import inverse_problem
from runout.inverse.loss import data_loss, thickness_profile
from test_inverse import problem_for, tiny_gns, toy, write_spec  # noqa: F401  (toy: the module fixture)

pytestmark = pytest.mark.usefixtures("one_thread")


def block(x0: float, x1: float, y0: float, y1: float, spacing: float) -> torch.Tensor:
    """[N, 2] lattice points (m) filling the rectangle, `spacing` m apart, half a spacing from its edges."""
    xs = torch.arange(x0 + spacing / 2, x1, spacing, dtype=torch.float64)
    ys = torch.arange(y0 + spacing / 2, y1, spacing, dtype=torch.float64)
    return torch.cartesian_prod(xs, ys)


def test_a_uniform_block_is_as_thick_as_it_is_high_and_its_area_is_kept():
    points = block(0.0, 10.0, 0.0, 5.0, 1.0)  # 10 x 5 m of soil, 1 m² per point
    profile = thickness_profile(points[None, :, 0], torch.ones(len(points), dtype=torch.float64), 0.0, 2.0, 5)
    np.testing.assert_allclose(profile.numpy(), [[5.0] * 5], atol=1e-12)  # m: every bin, edges included
    shifted = points[:, 0] + 13.7  # the block moved into bins 6-12 of 20 (width 2 m)
    profile = thickness_profile(shifted[None], torch.ones(len(points), dtype=torch.float64), 0.0, 2.0, 20)
    assert float(profile.sum() * 2.0) == pytest.approx(50.0)  # m²: the soil's area, wherever it lies
    assert float(profile.max()) <= 5.0 + 1e-9 and float(profile[0, :6].sum()) == 0.0


def test_the_thickness_gradient_is_exact():
    torch.manual_seed(0)
    x = (torch.rand(2, 40, dtype=torch.float64) * 30.0 + 1.0).requires_grad_()  # m, away from the bin centres' kinks
    area = torch.rand(40, dtype=torch.float64)
    weights = torch.rand(8, dtype=torch.float64)
    assert torch.autograd.gradcheck(lambda x: (thickness_profile(x, area, 0.0, 4.0, 8) * weights).sum(), (x,))


def test_the_thickness_loss_needs_no_correspondence_but_the_positions_loss_does():
    from runout.inverse.spec import LossSpec

    target = block(0.0, 12.0, 0.0, 4.0, 1.0).numpy()[None]  # [1, N, 2]
    weights = np.ones(target.shape[1])
    shuffled = torch.tensor(target[:, np.random.default_rng(0).permutation(target.shape[1])])
    thickness = data_loss(LossSpec(kind="thickness"), target, weights, 1.0, 40.0)
    positions = data_loss(LossSpec(), target, weights, 1.0, 40.0)
    assert float(thickness(shuffled)) == pytest.approx(0.0, abs=1e-20)  # the same soil, points relabelled
    assert float(positions(shuffled)) > 1.0  # m²
    spread = torch.tensor(target) * torch.tensor([2.0, 0.5])  # twice as long, half as thick: the same area
    assert float(thickness(spread)) > 0.5  # m²: (4 - 2)² on half the bins it covers and more


@pytest.mark.parametrize("table, message", [
    ('kind = "profile"', "loss.kind = 'profile' must be one of positions, thickness."),
    ('kind = "thickness"\nweighting = "displacement"', "loss.weighting = 'displacement' weights points"),
    ("bin_width = 4.0", "loss.bin_width sets the bins of loss.kind = \"thickness\""),
    ('kind = "thickness"\nbin_width = 0.0', "loss.bin_width = 0 m is outside the allowed range (0, 1000] m."),
    ('kind = "thickness"\nbin_width = "4 m"', "loss.bin_width = '4 m' must be a finite number."),
])
def test_bad_loss_tables_are_one_sentence(toy, table, message):  # noqa: F811
    path = write_spec(toy, "[parameters.left]\nc = { lower = 1.0, upper = 80.0 }", f"\n[loss]\n{table}", name="loss.toml")
    with pytest.raises(InputError) as error:
        load_inverse_spec(path)
    assert str(error.value).startswith(f"{path}: ") and message in str(error.value)


def test_the_thickness_loss_gradient_equals_central_differences(toy):  # noqa: F811
    params = "[parameters.left]\nc = { lower = 0.0, upper = 100.0 }"
    _, _, problem = problem_for(write_spec(toy, params, '\n[loss]\nkind = "thickness"\nbin_width = 4.0', name="tgrad.toml"))
    value, step = np.array([12.0]), 0.5  # kPa; the truth is 20 (the float32 rollout limits the differences to ~1 %)
    ad = problem.evaluate(value).gradient[0]
    fd = (problem.evaluate(value + step).loss - problem.evaluate(value - step).loss) / (2 * step)
    assert abs(fd) > 1e-7
    assert ad == pytest.approx(fd, rel=0.03)


def test_an_inverse_on_the_thickness_profile_recovers_the_cohesion(toy, tmp_path):  # noqa: F811
    params = ("[parameters.right]\nc = { initial = 20.0, lower = 10.0, upper = 80.0 }\n"
              "[optimiser]\nmax_iterations = 10\n[rollout]\nsteps = 15")
    spec = write_spec(toy, params, '\n[loss]\nkind = "thickness"', name="thick.toml")
    result = invert(spec, tmp_path, model=toy / "model.pt")
    assert result.best.values[0] == pytest.approx(40.0, rel=0.02)  # kPa, TRUE["right"]
    observation = load_observation(load_inverse_spec(spec))
    problem = inverse_problem(load_inverse_spec(spec), observation, GnsEngine(tiny_gns()))
    assert problem.data_loss.kind == "thickness" and problem.data_loss.width == pytest.approx(4.0)  # two 2 m spacings


def test_the_mpm_engines_take_the_thickness_loss_too(tmp_path):
    """The MPM's exact gradient of the thickness loss agrees with its finite differences, and
    mpm-ad recovers the column's cohesion from the thickness profiles alone."""
    from runout.inverse.mpm_ad import MpmAutodiff
    from runout.inverse.mpm_fd import MpmFiniteDifference
    from runout.mpm import simulate
    from runout.scene import save_scene, scene_from_dict
    from runout.trajectory import save_trajectory
    from _scenes import COLUMN_BESIDE_BLOCK

    scene = scene_from_dict(COLUMN_BESIDE_BLOCK, "ad")  # the truth: c = 5 kPa in the column
    save_scene(scene, tmp_path / "scene.toml")
    save_trajectory(simulate([scene], progress=False)[0], tmp_path / "target")
    (tmp_path / "spec.toml").write_text(
        'scene = "scene.toml"\n[target]\ntrajectory = "target"\nframes = [6, 12]\n'
        "[parameters.column]\nc = { initial = 12.0, lower = 0.0, upper = 20.0 }\n"
        '[loss]\nkind = "thickness"\n[optimiser]\nmax_iterations = 8\n'
    )
    spec = load_inverse_spec(tmp_path / "spec.toml")
    observation = load_observation(spec)
    ad = MpmAutodiff(spec, observation)(np.array([12.0]))
    fd = MpmFiniteDifference(spec, observation, step=0.008)(np.array([12.0]))
    assert ad.loss == pytest.approx(fd.loss, rel=1e-5) and abs(fd.gradient[0]) > 1e-5
    assert ad.gradient[0] == pytest.approx(fd.gradient[0], rel=0.03)
    result = invert(tmp_path / "spec.toml", tmp_path / "out", engine="mpm-ad")
    assert result.best.values[0] == pytest.approx(5.0, rel=0.03)  # kPa
