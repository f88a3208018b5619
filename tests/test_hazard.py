"""`runout hazard`: Monte Carlo runout over uncertain strengths. A 12 x 20 m cohesive column
(60 points, 4 m cells, 150 frames = 5.6 s) collapsing to the right runs in a few hundredths
of a second, so every study here is real MPM physics at a size that runs in seconds."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

import runout.mpm
from runout.cli import main
from runout.hazard import load_spec, merge_study, run_hazard
from runout.hazard.deposit import bin_count, front_runouts, thickness_profile
from runout.hazard.sampling import draw_inputs
from runout.hazard.statistics import exceedance

COLUMN = """name = "tiny_column"
[domain]
width = 80.0
height = 30.0
cell_size = 4.0
[time]
frames = 150
[materials.soil]
friction_angle = 30.0   # degrees
cohesion = 2.0          # kPa
[[regions]]
material = "soil"
polygon = [[0, 0], [12, 0], [12, 20], [0, 20]]
"""
THRESHOLDS = "thresholds = [0.5, 2.0]  # m\n"


def write_spec(folder: Path, soil: str, realisations: int = 8, extra: str = "") -> Path:
    """A spec over the tiny column, with `soil` the body of [materials.soil]."""
    (folder / "column.toml").write_text(COLUMN)
    spec = folder / "spec.toml"
    spec.write_text(f'scene = "column.toml"\nrealisations = {realisations}\nbatch = 3\nseed = 7\n{THRESHOLDS}{extra}'
                    f"[materials.soil]\n{soil}\n")
    return spec


def deterministic(spec_path: Path, phi: float, c: float):
    """The column's one MPM run at φ (degrees) and c (kPa)."""
    scene = load_spec(spec_path).scene.with_materials(soil={"friction_angle": phi, "cohesion": c})
    return runout.mpm.simulate([scene], progress=False)[0]


def read_csv(path: Path) -> np.ndarray:
    return np.loadtxt(path, delimiter=",", skiprows=1, ndmin=2)


def test_zero_variance_gives_the_deterministic_deposit(tmp_path):
    spec_path = write_spec(tmp_path, 'phi = { distribution = "normal", mean = 30, std = 0 }\n'
                                     'c = { distribution = "lognormal", mean = 2, std = 0 }', realisations=5)
    spec = load_spec(spec_path)
    run_hazard(spec, tmp_path / "out", progress=False)
    table = read_csv(tmp_path / "out" / "exceedance.csv")
    traj = deterministic(spec_path, 30.0, 2.0)
    bins = bin_count(spec.scene.domain.width, spec.bin_width)
    truth = thickness_profile(traj, spec.scene.domain.point_spacing, spec.bin_width, bins)
    assert set(np.unique(table[:, 1:])) <= {0.0, 1.0}
    assert np.array_equal(table[:, 1:].T, exceedance(truth[None], spec.thresholds))
    assert table[:, 1].sum() > 0  # the deposit exceeds 0.5 m somewhere
    fronts = read_csv(tmp_path / "out" / "realisations.csv")[:, -2:]
    assert np.allclose(fronts, front_runouts(traj), rtol=1e-9, atol=1e-12)  # the CSV keeps 10 digits


def test_median_front_matches_the_run_at_median_strengths(tmp_path):
    """Runout falls monotonically with φ here, so the median runout is the runout at the median φ."""
    spec_path = write_spec(tmp_path, 'phi = { distribution = "normal", mean = 30, std = 3, lower = 20, upper = 40 }',
                           realisations=15)
    summary = run_hazard(load_spec(spec_path), tmp_path / "out", progress=False)
    at_median = front_runouts(deterministic(spec_path, 30.0, 2.0))[1]
    assert summary["fronts"]["right"]["p50_m"] == pytest.approx(at_median, rel=0.05)
    assert summary["fronts"]["right"]["p5_m"] < summary["fronts"]["right"]["p50_m"] < summary["fronts"]["right"]["p95_m"]
    assert summary["spearman"]["phi[soil]_degrees"]["right"] < -0.9  # stronger soil, shorter runout


def test_weaker_soil_moves_the_exceedance_outward(tmp_path):
    probabilities, medians = {}, {}
    for name, mean in (("strong", 36), ("weak", 24)):
        folder = tmp_path / name
        folder.mkdir()
        spec = write_spec(folder, f'phi = {{ distribution = "uniform", lower = {mean - 3}, upper = {mean + 3} }}')
        medians[name] = run_hazard(load_spec(spec), folder / "out", progress=False)["fronts"]["right"]["p50_m"]
        probabilities[name] = read_csv(folder / "out" / "exceedance.csv")
    x = probabilities["weak"][:, 0]
    for h in (1, 2):  # each threshold's column
        weak, strong = probabilities["weak"][:, h], probabilities["strong"][:, h]
        assert x[weak > 0].max() > x[strong > 0].max()  # reaches farther
        assert np.all(weak[x > 16] >= strong[x > 16])  # beyond the column's foot, never less likely
    assert medians["weak"] > medians["strong"]


def test_inputs_follow_their_truncated_distributions_and_correlation(tmp_path):
    spec = load_spec(write_spec(tmp_path, 'phi = { distribution = "normal", mean = 30, std = 8, lower = 25, upper = 40 }\n'
                                          'c = { distribution = "lognormal", mean = 5, std = 2 }\ncorrelation = -0.8',
                                realisations=400, extra='sampler = "sobol"\n'))
    values = draw_inputs(spec)
    phi, c = values[:, 0], values[:, 1]
    assert phi.min() >= 25 and phi.max() <= 40 and c.min() > 0
    assert np.mean(c) == pytest.approx(5.0, rel=0.05)
    assert np.corrcoef(phi, np.log(c))[0, 1] < -0.6
    assert np.array_equal(values, draw_inputs(spec))  # seeded


class Killed(Exception):
    pass


def test_a_killed_run_resumes_without_recomputing_and_gives_identical_results(tmp_path):
    spec = load_spec(write_spec(tmp_path, 'phi = { distribution = "normal", mean = 30, std = 4, lower = 20, upper = 40 }'))
    calls = []

    def dies_on_second_batch(scenes, **kw):
        calls.append([s.name for s in scenes])
        if len(calls) == 2:
            raise Killed
        return runout.mpm.simulate(scenes, **kw)

    with pytest.raises(Killed):
        run_hazard(spec, tmp_path / "resumed", simulate=dies_on_second_batch, progress=False)
    calls.clear()
    run_hazard(spec, tmp_path / "resumed", simulate=lambda s, **kw: calls.append(len(s)) or runout.mpm.simulate(s, **kw),
               progress=False)
    assert calls == [3, 2]  # batches 1 and 2 of 3, batch 0 kept
    run_hazard(spec, tmp_path / "whole", progress=False)
    for name in ("realisations.csv", "exceedance.csv", "summary.json"):
        assert (tmp_path / "resumed" / name).read_bytes() == (tmp_path / "whole" / name).read_bytes()


def test_shards_merge_into_the_unsharded_results(tmp_path):
    spec = load_spec(write_spec(tmp_path, 'phi = { distribution = "normal", mean = 30, std = 4, lower = 20, upper = 40 }'))
    assert run_hazard(spec, tmp_path / "s0", shard=(0, 2), progress=False) is None
    run_hazard(spec, tmp_path / "s1", shard=(1, 2), progress=False)
    merge_study(spec, [tmp_path / "s0", tmp_path / "s1"], tmp_path / "merged")
    run_hazard(spec, tmp_path / "whole", progress=False)
    for name in ("realisations.csv", "exceedance.csv", "summary.json"):
        assert (tmp_path / "merged" / name).read_bytes() == (tmp_path / "whole" / name).read_bytes()


def test_the_command_writes_its_results(tmp_path, capsys):
    spec = write_spec(tmp_path, 'phi = { distribution = "normal", mean = 30, std = 3 }', realisations=4)
    main(["hazard", str(spec), "--out", str(tmp_path / "out")])
    said = capsys.readouterr().out
    assert "right front runout: P5" in said
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert summary["realisations"] == 4
    for name in ("exceedance.png", "runouts.png", "realisations.json", "runout_cdf.csv"):
        assert (tmp_path / "out" / name).stat().st_size > 0


BAD = [
    ('phi = { distribution = "normal", mean = 30, std = -2 }', "", "materials.soil.phi.std = -2"),
    ('phi = { distribution = "uniform", lower = 35, upper = 25 }', "", "materials.soil.phi.upper = 25"),
    ('phi = { distribution = "normal", mean = 30, std = 2 }\nc = { distribution = "normal", mean = 2, std = 1 }\n'
     "correlation = 1.5", "", "materials.soil.correlation = 1.5"),
    ('phi = { distribution = "normal", mean = 30, std = 2 }', "realisations0", "realisations = 0"),
    ('phi = { distribution = "normal", mean = 70, std = 2 }', "", "materials.soil.phi.mean = 70"),
    ('phi = { distribution = "weibull", mean = 30, std = 2 }', "", "materials.soil.phi.distribution = 'weibull'"),
    ('phi = { distribution = "normal", mean = 30, std = 2 }\n[materials.clay]\nc = { distribution = "normal", mean = 5, std = 1 }',
     "", "materials.clay is not a material of the scene"),
]


@pytest.mark.parametrize("soil, mode, words", BAD)
def test_bad_spec_is_one_sentence_exit_2_and_writes_nothing(tmp_path, capsys, soil, mode, words):
    spec = write_spec(tmp_path, soil, realisations=0 if mode == "realisations0" else 4)
    try:
        main(["hazard", str(spec), "--out", str(tmp_path / "out")])
        code = 0
    except SystemExit as done:
        code = done.code
    err = capsys.readouterr().err
    assert code == 2
    assert str(spec) in err and words in err
    assert len(err.strip().splitlines()) == 1
    assert not (tmp_path / "out").exists()
