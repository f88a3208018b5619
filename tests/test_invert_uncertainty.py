"""`runout invert --uncertainty`: Gauss-Newton intervals on back-calculated strengths.

Against absolute references: the textbook intervals of linear least squares (scipy's
linregress, numpy's lstsq) and their 90 % coverage under Gaussian noise; the Jacobian by
central differences against reverse-mode AD through the MPM (mpm-ad) and a learned engine;
the printed line; and bad --confidence values refused before anything is written.
"""

from __future__ import annotations

import json
import re

import numpy as np
import pytest
import scipy.stats
import torch
import torch.autograd.forward_ad as fwAD

from runout.errors import InputError
from runout.cli import main
from runout.inverse import invert, load_inverse_spec, load_observation, summary_lines
from runout.inverse.forward import inverse_problem
from runout.inverse.history import HISTORY_JSON
from runout.inverse.intervals import ALONE, INTERIOR, LOWER, TOGETHER, Intervals, gauss_newton, interval_lines
from runout.inverse.loss import data_loss
from runout.inverse.mpm_ad import MpmAutodiff
from runout.inverse.problem import InverseProblem
from runout.inverse.spec import FreeParameter, LossSpec
from runout.inverse.uncertainty import PROFILE_PNG, UNCERTAINTY_JSON, estimate_uncertainty, linearise
from runout.gns.engine import GnsEngine
from runout.mpm import simulate
from runout.scene import save_scene, scene_from_dict
from runout.trajectory import save_trajectory
from _scenes import COLUMN_BESIDE_BLOCK
from test_cli_exits import one_sentence, run
from test_inverse import tiny_gns, write_spec, write_target

pytestmark = pytest.mark.usefixtures("one_thread")

C = FreeParameter("m1", "c", 50.0, 10.0, 100.0)
PHI = FreeParameter("m3", "phi", 30.0, 5.0, 50.0)
NOISE = 0.05  # m, standard deviation of the noise added to the tiny scene's observed positions


# ----------------------------------------------------------------------------- the statistics


def test_one_parameter_pair_gives_linregress_intervals():
    """y = a + b x + noise: the slope's and intercept's standard errors are scipy's linregress's."""
    rng = np.random.default_rng(1)
    x = np.linspace(0.0, 10.0, 40)
    y = 2.0 + 0.7 * x + rng.normal(0.0, 0.3, x.size)
    fit = scipy.stats.linregress(x, y)
    design = np.column_stack([np.ones_like(x), x])
    estimate = np.array([fit.intercept, fit.slope])
    free = (FreeParameter("a", "c", 0.0, -100.0, 100.0), FreeParameter("b", "c", 0.0, -100.0, 100.0))
    intervals = gauss_newton(design @ estimate - y, design, free, estimate, 0.9)
    np.testing.assert_allclose(intervals.standard_error, [fit.intercept_stderr, fit.stderr], rtol=1e-10)
    t = scipy.stats.t.ppf(0.95, x.size - 2)
    np.testing.assert_allclose(intervals.upper - estimate, t * intervals.standard_error, rtol=1e-12)
    assert intervals.correlation[0, 1] == pytest.approx(-x.mean() / np.sqrt((x**2).mean()), rel=1e-10)


def test_ninety_percent_intervals_hold_the_truth_nine_times_in_ten():
    """Coverage of a linear model with Gaussian noise over 600 draws: 90 % within binomial scatter."""
    rng = np.random.default_rng(2)
    design = rng.normal(size=(30, 2))
    truth = np.array([40.0, 30.0])
    held = np.zeros(2)
    for _ in range(600):
        y = design @ truth + rng.normal(0.0, 1.5, 30)
        estimate = np.linalg.lstsq(design, y, rcond=None)[0]
        intervals = gauss_newton(design @ estimate - y, design, (C, PHI), estimate, 0.9)
        held += (intervals.lower <= truth) & (truth <= intervals.upper)
    assert np.all(np.abs(held / 600 - 0.9) < 0.04), held  # binomial sd 1.2 %


def test_an_undetermined_parameter_and_one_on_a_bound_are_said_so():
    rng = np.random.default_rng(3)
    column = rng.normal(size=50)
    r = rng.normal(0.0, 0.1, 50)
    third = FreeParameter("m4", "c", 20.0, 0.0, 40.0)
    alone = gauss_newton(r, np.column_stack([column, np.zeros(50), rng.normal(size=50)]), (C, PHI, third),
                         np.array([40.0, 30.0, 0.0]), 0.9)
    assert alone.status == [INTERIOR, ALONE, LOWER]
    assert np.isinf(alone.standard_error[1]) and np.isnan(alone.lower[1])
    assert alone.lower[2] == 0.0
    assert alone.upper[2] == pytest.approx(scipy.stats.t.ppf(0.9, 47) * alone.standard_error[2])  # one-sided
    lines = interval_lines(alone)
    assert lines[2] == "phi[m3] = 30 degrees: not determined by this observation (the deposit does not change with it)"
    assert lines[3].startswith("c[m4] = 0 kPa, at its lower bound: the interval is one-sided, 0.0")
    assert lines[3].endswith(" kPa (90 %)")
    together = gauss_newton(r, np.column_stack([column, 2.0 * column]), (C, PHI), np.array([40.0, 30.0]), 0.9)
    assert together.status == [TOGETHER, TOGETHER] and together.partners == [["phi[m3]"], ["c[m1]"]]
    assert "not determined apart from phi[m3] by this observation" in interval_lines(together)[1]


def test_the_printed_line_reads_like_the_issue():
    intervals = Intervals(
        free=(C, PHI), confidence=0.9, estimate=np.array([40.0712, 41.0]), standard_error=np.array([0.77, 0.25]),
        lower=np.array([40.0712 - 1.2845, 40.6]), upper=np.array([40.0712 + 1.2845, 41.4]),
        covariance=np.array([[0.5929, -0.05], [-0.05, 0.0625]]), correlation=np.array([[1.0, -0.26], [-0.26, 1.0]]),
        status=[INTERIOR, INTERIOR], partners=[[], []], s2=0.81, n=672, condition=1.7, t_quantile=1.647,
    )
    lines = interval_lines(intervals)
    assert lines[1] == "c[m1] = 40.1 ± 1.3 kPa (90 %)"
    assert lines[2] == "phi[m3] = 41.00 ± 0.40 degrees (90 %)"
    assert lines[3:] == ["correlation:", "  c[m1]   +1.000 -0.260", "  phi[m3] -0.260 +1.000"]
    assert "s = 0.9 m per observed value, n = 672, p = 2" in lines[0]


# ----------------------------------------------------------------------------- residuals and Jacobians


@pytest.mark.parametrize("kind", ["positions", "thickness"])
def test_the_loss_is_the_sum_of_its_squared_residuals(kind):
    rng = np.random.default_rng(4)
    target = rng.uniform(0.0, 45.0, (2, 30, 2))
    target[:, 5:, 0] = np.linspace(1.0, 44.0, 25)  # the weighted points cover the bins centred at 2.5-47.5 m
    weights = np.r_[np.zeros(5), rng.uniform(1.0, 3.0, 25)]
    loss = data_loss(LossSpec(kind, "uniform", 4.0, 5.0 if kind == "thickness" else None), target, weights, 2.0, 100.0)
    predicted = torch.tensor(target + rng.normal(0.0, 0.5, target.shape))
    r = loss.residuals(predicted)
    assert float(r.square().sum()) / loss.divisor == pytest.approx(float(loss(predicted)), rel=1e-12)
    observed = int(loss.observed(predicted).sum())
    # every coordinate of the 25 weighted points in 2 frames; or, of 20 bins 5 m wide per frame, the
    # ten that hold soil (centres 2.5-47.5 m), not the ten empty ones beyond
    assert (r.numel(), observed) == ((100, 100) if kind == "positions" else (40, 20))
    direction = torch.tensor(rng.normal(size=target.shape))  # the Jacobian's path: forward-mode AD through them
    with fwAD.dual_level():
        derivative = fwAD.unpack_dual(loss.residuals(fwAD.make_dual(predicted, direction))).tangent
    h = 1e-6  # m; both kinds are piecewise linear in the positions
    secant = (loss.residuals(predicted + h * direction) - loss.residuals(predicted - h * direction)) / (2 * h)
    np.testing.assert_allclose(derivative.numpy(), secant.numpy(), atol=1e-6)


def linear_forward(free, truth, rng, noise):
    """A forward model linear in both cohesions (positions = x0 + (c / 100 kPa) a per point) and a
    target made at `truth` with Gaussian noise of `noise` m: an InverseProblem whose answer is OLS."""
    materials = ["m1", "m3"]
    material_id = np.repeat([0, 1], 20)
    x0 = rng.uniform(0.0, 100.0, (40, 2))
    a = rng.normal(0.0, 5.0, (40, 2))

    def forward(features):
        return (torch.tensor(x0) + features[:, 1:2].double() * torch.tensor(a))[None]

    table = np.array([[30.0, 0.0], [30.0, 0.0]])
    exact = x0 + np.asarray(truth)[material_id, None] / 100.0 * a
    target = (exact + rng.normal(0.0, noise, exact.shape))[None]
    loss = data_loss(LossSpec(), target, np.ones(40), 2.0, 100.0)
    design = np.zeros((80, 2))
    for k in range(2):
        design[:, k] = ((material_id == k)[:, None] * a / 100.0).reshape(-1)
    return InverseProblem(free, materials, table, material_id, 2, forward, loss, dtype=torch.float64), target, x0, design


def test_a_linear_forward_model_gives_the_textbook_least_squares_interval(tmp_path):
    free = (FreeParameter("m1", "c", 50.0, 0.0, 100.0), FreeParameter("m3", "c", 50.0, 0.0, 100.0))
    problem, target, x0, design = linear_forward(free, [40.0, 60.0], np.random.default_rng(5), 0.3)
    y = (target[0] - x0).reshape(-1)
    estimate, rss = np.linalg.lstsq(design, y, rcond=None)[:2]
    intervals = estimate_uncertainty(problem, free, estimate, 0.9, 0.01, tmp_path)
    s2 = float(rss[0]) / (80 - 2)
    se = np.sqrt(s2 * np.diag(np.linalg.inv(design.T @ design)))
    assert intervals.n == 80 and intervals.s2 == pytest.approx(s2, rel=1e-8)
    np.testing.assert_allclose(intervals.standard_error, se, rtol=1e-6)
    half = scipy.stats.t.ppf(0.95, 78) * se
    np.testing.assert_allclose(intervals.upper, estimate + half, rtol=1e-8)
    record = json.loads((tmp_path / UNCERTAINTY_JSON).read_text())
    assert record["n"] == 80 and record["p"] == 2 and record["parameters"][0]["interval"][0] == pytest.approx(
        estimate[0] - half[0])
    profile = record["profile"][0]
    assert len(profile["values"]) == 11 and min(profile["losses"]) == pytest.approx(record["loss"])
    assert (tmp_path / PROFILE_PNG).stat().st_size > 0


def exact_projections(loss_of_values, data_loss, values, vectors):
    """Jᵀ v (exact, reverse-mode AD) of the residuals for each vector v."""
    out = []
    for v in vectors:
        theta = torch.tensor(values, dtype=torch.float64, requires_grad=True)
        r = data_loss.residuals(loss_of_values(theta))
        out.append(torch.autograd.grad(r, theta, torch.as_tensor(v, dtype=r.dtype))[0].numpy())
    return np.array(out)


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    """The 160-point column and block of test_inverse_mpm_ad, observed at frames 6 and 12 with
    Gaussian noise of NOISE m; the truth c = 5 kPa in the column, phi = 20 degrees in the block."""
    folder = tmp_path_factory.mktemp("uncertainty")
    scene = scene_from_dict(COLUMN_BESIDE_BLOCK, "ad")
    save_scene(scene, folder / "scene.toml")
    observed = simulate([scene], progress=False)[0].positions[[6, 12]].astype(np.float64)
    np.save(folder / "observed.npy", observed + np.random.default_rng(6).normal(0.0, NOISE, observed.shape))
    (folder / "spec.toml").write_text(
        'scene = "scene.toml"\n[target]\npositions = "observed.npy"\nframes = [6, 12]\n'
        "[parameters.column]\nc = { initial = 12.0, lower = 0.0, upper = 20.0 }\n"
        "[parameters.block]\nphi = { initial = 25.0, lower = 10.0, upper = 35.0 }\n[optimiser]\nmax_iterations = 15\n"
    )
    return folder


def test_the_mpm_jacobian_agrees_with_reverse_mode_ad(tiny):
    """Central differences (0.01 of the bounds) against the exact derivative of the one run,
    projected on random vectors: within 5 % of each column's scale (the MPM's fine-scale
    roughness: 2-4 % here, as for the gradient in test_inverse_mpm_ad)."""
    spec = load_inverse_spec(tiny / "spec.toml")
    engine = MpmAutodiff(spec, load_observation(spec))
    values = np.array([8.0, 22.0])
    lin = linearise(engine, spec.free, values, 0.01)
    assert lin.how.startswith("central differences")
    vectors = np.random.default_rng(7).normal(size=(3, lin.residuals.size))
    exact = exact_projections(engine._positions, engine.data_loss, values, vectors)
    assert np.all(np.abs(vectors @ lin.jacobian - exact) <= 0.05 * np.abs(exact).max(axis=0))
    gradient = engine(values).gradient  # the optimiser's: d loss / d value = 2 Jᵀ r / divisor
    np.testing.assert_allclose(2 * lin.residuals @ lin.jacobian / lin.divisor, gradient, rtol=0.05)


def test_a_learned_engines_jacobian_is_its_exact_derivative(tmp_path):
    write_target(tmp_path, tiny_gns())
    spec_path = write_spec(tmp_path, "[parameters.left]\nc = { initial = 60.0, lower = 0.0, upper = 100.0 }\n"
                                     "[parameters.right]\nphi = { initial = 35.0, lower = 5.0, upper = 45.0 }")
    spec = load_inverse_spec(spec_path)
    problem = inverse_problem(spec, load_observation(spec), GnsEngine(tiny_gns()))
    values = np.array([30.0, 25.0])
    lin = linearise(problem, spec.free, values, 0.01)
    assert lin.how.startswith("forward-mode AD")
    vectors = np.random.default_rng(8).normal(size=(3, lin.residuals.size))
    exact = exact_projections(lambda v: problem.loss(v)[1], problem.data_loss, values, vectors)
    np.testing.assert_allclose(vectors @ lin.jacobian, exact, rtol=1e-5)


# ----------------------------------------------------------------------------- the command


def test_the_command_prints_intervals_and_a_resumed_run_gives_them_without_new_evaluations(tiny, tmp_path, capsys):
    out = tmp_path / "out"
    main(["invert", str(tiny / "spec.toml"), "--engine", "mpm-ad", "--out", str(out), "--uncertainty"])
    printed = capsys.readouterr().out.splitlines()
    assert any(re.match(r"^c\[column\] = \d+\.\d+ ± \d+\.\d+ kPa \(90 %\)$", line) for line in printed), printed
    assert any(re.match(r"^phi\[block\] = \d+\.?\d* ± \d+\.?\d* degrees \(90 %\)$", line) for line in printed)
    assert "correlation:" in printed and printed[-1].endswith("uncertainty.json, profile.png")
    record = json.loads((out / UNCERTAINTY_JSON).read_text())
    (c, phi), truth = record["parameters"], (5.0, 20.0)
    assert c["interval"][0] < truth[0] < c["interval"][1] and phi["interval"][0] < truth[1] < phi["interval"][1]
    assert np.sqrt(record["s2"]) == pytest.approx(NOISE, rel=0.1)  # the noise, read back from the residuals
    assert record["n"] == 2 * 160 * 2 and (out / PROFILE_PNG).stat().st_size > 0
    evaluations = len(json.loads((out / HISTORY_JSON).read_text())["evaluations"])
    lines = []
    result = invert(tiny / "spec.toml", out, engine="mpm-ad", uncertainty=True, confidence=0.95, log=lines.append)
    assert "replaying" in lines[0] and not any(line.startswith("evaluation") for line in lines)
    assert len(json.loads((out / HISTORY_JSON).read_text())["evaluations"]) == evaluations
    assert any(re.match(r"^c\[column\] = \d+\.\d+ ± \d+\.\d+ kPa \(95 %\)$", line) for line in summary_lines(result))
    again = json.loads((out / UNCERTAINTY_JSON).read_text())
    assert again["confidence"] == 0.95 and again["parameters"][0]["estimate"] == c["estimate"]
    assert again["parameters"][0]["interval"][1] > c["interval"][1]  # 95 % is wider than 90 %


def test_with_several_starts_the_intervals_are_the_best_starts(tiny, tmp_path):
    short = tiny / "short.toml"  # three evaluations a start: the best start need not have converged
    short.write_text((tiny / "spec.toml").read_text().replace("max_iterations = 15", "max_evaluations = 3"))
    result = invert(short, tmp_path / "out", engine="mpm-ad", starts=2, uncertainty=True)
    record = json.loads((tmp_path / "out" / UNCERTAINTY_JSON).read_text())
    assert record["answer_of"] == result.best.out_dir.name
    assert [p["estimate"] for p in record["parameters"]] == result.best.values.tolist()
    assert (tmp_path / "out" / PROFILE_PNG).is_file() and not (tmp_path / "out" / "start_00" / UNCERTAINTY_JSON).exists()


@pytest.mark.parametrize("value", ["0", "1", "1.5", "-0.2", "nan"])
def test_a_bad_confidence_is_refused_and_nothing_is_written(tiny, tmp_path, capsys, value):
    out = tmp_path / "out"
    code, err = run(["invert", tiny / "spec.toml", "--engine", "mpm-ad", "--out", out, "--uncertainty",
                     "--confidence", value], capsys)
    assert code == 2 and one_sentence(err), err
    assert "--confidence" in err and "(0, 1)" in err and not out.exists()


def test_confidence_without_uncertainty_is_refused(tiny, tmp_path, capsys):
    code, err = run(["invert", tiny / "spec.toml", "--engine", "mpm-ad", "--out", tmp_path / "out",
                     "--confidence", "0.95"], capsys)
    assert code == 2 and one_sentence(err) and "--uncertainty" in err and not (tmp_path / "out").exists()


def test_the_api_refuses_a_bad_confidence_before_reading_the_spec(tmp_path):
    with pytest.raises(InputError, match=r"--confidence = 1 is outside the allowed range \(0, 1\)"):
        invert(tmp_path / "missing.toml", tmp_path / "out", engine="mpm-ad", uncertainty=True, confidence=1.0)
    assert not (tmp_path / "out").exists()
