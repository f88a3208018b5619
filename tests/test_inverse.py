"""Inverse analysis: spec checks, AD gradient against finite differences, bounds, recovery of
known parameters, resume after a kill, multiple starts, checkpoint memory, MPM finite differences.

The forward model is a randomly initialised tiny GNS (runout.gns) whose material inputs are
amplified so that the motion depends clearly on phi and c; targets are made by the same
model at known parameters, so the answer is known exactly.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from runout.errors import InputError
from runout.gns.checkpoint import save_checkpoint
from runout.gns.engine import GnsEngine
from runout.gns.rollout import rollout
from runout.gns.schema import FeatureSchema, NetworkConfig
from runout.gns.simulator import GraphNetworkSimulator, Normalisation
from runout.inverse import (
    Evaluation, invert, load_inverse_spec, load_observation, minimise, starting_points, summary_lines,
)
from runout.inverse.forward import inverse_problem
from runout.inverse.history import HISTORY_JSON, RunInfo
from runout.inverse.memory import PeakMemory
from runout.inverse.mpm_fd import MpmFiniteDifference
from runout.inverse.optimise import central_stencil, run_starts, spread
from runout.inverse.spec import FreeParameter, OptimiserSpec
from runout.scene import fill_points, save_scene, scene_from_dict
from runout.trajectory import save_trajectory, trajectory_for_scene

REPO = Path(__file__).resolve().parents[1]
STEPS = 15  # rollout steps of the tiny problems: frames 0 (at rest) to 15
TRUE = {"left": {"friction_angle": 30.0, "cohesion": 20.0}, "right": {"friction_angle": 20.0, "cohesion": 40.0}}

TOY_SCENE = {
    "domain": {"width": 60.0, "height": 40.0},
    "time": {"frames": 16},
    "materials": {
        "left": {"friction_angle": 30.0, "cohesion": 20.0},  # the truth, TRUE
        "right": {"friction_angle": 20.0, "cohesion": 40.0},
        "ground": {"model": "elastic"},
    },
    "regions": [
        {"material": "ground", "polygon": [[0, 0], [60, 0], [60, 2], [0, 2]], "fixed": True},
        {"material": "left", "polygon": [[10, 2], [26, 2], [26, 14], [10, 14]]},
        {"material": "right", "polygon": [[26, 2], [44, 2], [44, 10], [26, 10]]},
    ],
}


pytestmark = pytest.mark.usefixtures("one_thread")


def tiny_gns(seed: int = 0) -> GraphNetworkSimulator:
    torch.manual_seed(seed)
    stats = Normalisation((0.0, 0.0), (2e-2, 2e-2), (0.0, 0.0), (2e-3, 2e-3), 0.0)  # m/frame, m/frame^2
    simulator = GraphNetworkSimulator(FeatureSchema(), stats, 5.0, NetworkConfig(16, 16, 1, 2)).eval()
    simulator.data_ranges = {"point_spacing_m": 2.0}  # TOY_SCENE's 4 m cells: invert fills the scene at this spacing
    with torch.no_grad():
        simulator.network.node_encoder[0].weight[:, -2:] *= 20  # material columns: strong response
    return simulator


def write_target(folder: Path, simulator: GraphNetworkSimulator, steps: int = STEPS) -> Path:
    """Scene file toy.toml and a target trajectory made by `simulator` at its values (TRUE)."""
    true_scene = scene_from_dict(TOY_SCENE, "toy")
    save_scene(true_scene, folder / "toy.toml")
    points = fill_points(true_scene)
    table = torch.tensor([m.features() for m in true_scene.materials.values()], dtype=torch.float32)
    with torch.no_grad():
        positions = rollout(
            simulator, torch.tensor(points.position, dtype=torch.float32)[None].expand(6, -1, -1),
            torch.as_tensor(points.particle_type), table[torch.as_tensor(points.material_id)], steps,
            [[0.0, 60.0], [0.0, 40.0]],
        )[5:]  # from rest: the window's six copies of frame 0 are one frame 0
    traj = trajectory_for_scene(true_scene, positions.numpy(), points.particle_type, points.material_id)
    return save_trajectory(traj, folder / "target").parent


def write_spec(folder: Path, parameters: str, extra: str = "", name: str = "spec.toml") -> Path:
    path = folder / name
    path.write_text(f'scene = "toy.toml"\n\n[target]\ntrajectory = "target"\n{extra}\n{parameters}\n')
    return path


@pytest.fixture(scope="module")
def toy(tmp_path_factory):
    """A folder with the scene, a target made at TRUE, and the model as a checkpoint."""
    folder = tmp_path_factory.mktemp("toy")
    simulator = tiny_gns()
    write_target(folder, simulator)
    save_checkpoint(folder / "model.pt", simulator)
    return folder


def problem_for(spec_path: Path, checkpoint: bool = True):
    spec = load_inverse_spec(spec_path)
    observation = load_observation(spec)
    return spec, observation, inverse_problem(spec, observation, GnsEngine(tiny_gns()), checkpoint)


def run_info(spec, start) -> RunInfo:
    return RunInfo(spec.digest, "gns", "tiny", [float(x) for x in start])


# ----------------------------------------------------------------------------- spec


def test_dam_example_spec_reads_as_the_paper_table():
    spec = load_inverse_spec(REPO / "examples" / "dam_inverse.toml")
    bounds = {p.name: (p.lower, p.upper) for p in spec.free}
    assert bounds == {
        "c[m1_downstream_lower]": (10.0, 100.0),
        "c[m2_core]": (99.0, 101.0),
        "phi[m3_downstream_upper]": (5.0, 50.0),
    }
    materials = spec.scene.materials
    assert materials["m1_downstream_lower"].friction_angle == 0.0
    assert materials["m4_upstream_shell"].friction_angle == 42.5
    assert materials["m3_downstream_upper"].cohesion == 10.0


BAD_SPECS = {
    "unknown material": ('[parameters.sand]\nc = { lower = 1.0, upper = 2.0 }', "", "not a material"),
    "bounds reversed": ('[parameters.left]\nc = { lower = 50.0, upper = 10.0 }', "", "not below upper"),
    "initial outside": ('[parameters.left]\nphi = { initial = 50.0, lower = 5.0, upper = 45.0 }', "", "outside its bounds"),
    "nothing to optimise": ('[parameters.left]\nphi = { fixed = 30.0 }', "", "nothing to optimise"),
    "fixed material": ('[parameters.ground]\nc = { lower = 1.0, upper = 2.0 }', "", "no moving"),
    "phi beyond 60": ('[parameters.left]\nphi = { lower = 5.0, upper = 70.0 }', "", "allowed range"),
    "unknown key": ('[parameters.left]\nc = { lower = 1.0, upper = 2.0, start = 1.5 }', "", "unknown key"),
    "frames before the rollout": ('[parameters.left]\nc = { lower = 1.0, upper = 80.0 }', "frames = [0]", "the scene at rest"),
}


@pytest.mark.parametrize("case", sorted(BAD_SPECS))
def test_bad_spec_raises_one_sentence(toy, tmp_path, case):
    parameters, target_extra, phrase = BAD_SPECS[case]
    path = write_spec(toy, parameters, target_extra, name=f"bad_{case.replace(' ', '_')}.toml")
    with pytest.raises(InputError) as err:
        load_inverse_spec(path)
    message = str(err.value)
    assert phrase in message and "\n" not in message and message.rstrip().endswith(".")


@pytest.mark.parametrize("frames, rollout_table, phrase", [
    ("[10, 40]", "", "beyond the target trajectory's last frame 15"),
    ("[10, 14]", "[rollout]\nsteps = 12", "beyond the rollout, whose last frame is 12"),
])
def test_frames_beyond_the_rollout_are_refused(toy, frames, rollout_table, phrase):
    parameters = "[parameters.left]\nc = { lower = 1.0, upper = 80.0 }\n" + rollout_table
    path = write_spec(toy, parameters, f"frames = {frames}", name="frames.toml")
    with pytest.raises(InputError, match=phrase):
        load_observation(load_inverse_spec(path))


def test_bad_spec_exits_with_code_2(toy, tmp_path, monkeypatch, capsys):
    from runout.cli import main

    path = write_spec(toy, '[parameters.left]\nc = { lower = 50.0, upper = 10.0 }', name="reversed.toml")
    monkeypatch.setattr(sys, "argv", ["runout", "invert", str(path), "--out", str(tmp_path / "o")])
    with pytest.raises(SystemExit) as exit_info:
        main()
    assert exit_info.value.code == 2
    assert "not below upper" in capsys.readouterr().err


def test_cohesion_needs_a_model_that_reads_it(toy):
    spec = load_inverse_spec(write_spec(toy, '[parameters.left]\nc = { lower = 1.0, upper = 80.0 }', name="c.toml"))
    simulator = tiny_gns()
    simulator.schema = simulator.schema.with_material_features(("tan_phi",))
    with pytest.raises(InputError, match="cannot back-calculate c\\[left\\]"):
        inverse_problem(spec, load_observation(spec), GnsEngine(simulator))


def test_the_gns_fills_the_scene_at_the_models_spacing_so_the_target_must_be_made_there(toy, tmp_path):
    simulator = tiny_gns()
    simulator.data_ranges = {"point_spacing_m": 3.0}  # 6 m cells; the toy target is a run at 4 m cells
    save_checkpoint(tmp_path / "coarse.pt", simulator)
    spec = write_spec(toy, "[parameters.right]\nc = { initial = 20.0, lower = 10.0, upper = 80.0 }", name="coarse.toml")
    lines = []
    with pytest.raises(InputError, match=r"but the scene at the model's 3 m point spacing \(6 m cells\) fills \d+; "):
        invert(spec, tmp_path / "run", model=tmp_path / "coarse.pt", log=lines.append)
    assert lines == [f"filling the scene of {spec} at the model's 3 m spacing (6 m cells) instead of the scene's 4 m cells"]


def test_observed_positions_file_and_front_weighting(toy, tmp_path):
    (tmp_path / "toy.toml").write_text((toy / "toy.toml").read_text())
    final = np.load(toy / "target" / "trajectory.npz", allow_pickle=True)["simulation_0"][0][-1]
    np.save(tmp_path / "observed.npy", final)
    spec_path = tmp_path / "spec.toml"
    spec_path.write_text(
        'scene = "toy.toml"\n[target]\npositions = "observed.npy"\n[rollout]\nsteps = 15\n'
        '[loss]\nweighting = "displacement"\nfront_weight = 4.0\n'
        '[parameters.left]\nc = { lower = 1.0, upper = 80.0 }\n'
    )
    spec = load_inverse_spec(spec_path)
    observation = load_observation(spec)
    assert observation.frames == (15,) and observation.steps == 15
    weights = observation.weights(spec.loss)
    moved = np.linalg.norm(final - observation.initial, axis=1)
    soil = observation.particle_type != 3
    assert np.all(weights[~soil] == 0) and weights[soil].min() >= 1.0 and weights.max() == pytest.approx(5.0)
    assert weights[np.argmax(moved * soil)] == weights.max()
    np.save(tmp_path / "observed.npy", final[:-1])
    with pytest.raises(InputError, match="expected \\(1, 114, 2\\)"):
        load_observation(spec)


# ----------------------------------------------------------------------------- gradient and memory


def test_ad_gradient_equals_central_differences(toy):
    params = ("[parameters.left]\nphi = { lower = 5.0, upper = 45.0 }\nc = { lower = 0.0, upper = 100.0 }\n"
              "[parameters.right]\nc = { lower = 10.0, upper = 80.0 }")
    _, _, problem = problem_for(write_spec(toy, params, name="grad.toml"))
    values = np.array([22.0, 45.0, 25.0])
    ad = problem.evaluate(values).gradient
    step = np.array([0.5, 0.5, 0.5])  # degrees, kPa
    fd = np.empty(3)
    for k in range(3):
        up, down = values.copy(), values.copy()
        up[k] += step[k]
        down[k] -= step[k]
        fd[k] = (problem.evaluate(up).loss - problem.evaluate(down).loss) / (2 * step[k])
    assert np.all(np.abs(fd) > 1e-7)
    np.testing.assert_allclose(ad, fd, rtol=0.02)


def test_the_inverse_rollout_starts_a_thrown_region_at_its_velocity(tmp_path):
    """A region with an initial velocity enters the inverse's rollout at that velocity, as it
    enters `runout rollout`'s (runout.gns.rollout.start_window): a target rolled out from the
    scene is met exactly at the true strengths, and not by a start from rest."""
    from runout.gns.rollout import rollout_trajectory
    from runout.learned.scenes import scene_at_rest

    simulator = tiny_gns()
    thrown = json.loads(json.dumps(TOY_SCENE))
    thrown["regions"][1]["velocity"] = [8.0, 3.0]  # m/s, the "left" block
    scene = scene_from_dict(thrown, "toy")
    save_scene(scene, tmp_path / "toy.toml")
    target = rollout_trajectory(simulator, scene_at_rest(scene), STEPS + 1, stop_speed=None)
    from_rest = rollout_trajectory(simulator, scene_at_rest(scene_from_dict(TOY_SCENE, "toy")), STEPS + 1, stop_speed=None)
    assert np.abs(target.positions[-1] - from_rest.positions[-1]).max() > 0.1  # m: the velocity matters
    save_trajectory(target, tmp_path / "target")
    spec, observation, problem = problem_for(write_spec(tmp_path, "[parameters.left]\nc = { lower = 0.0, upper = 100.0 }"))
    np.testing.assert_array_equal(observation.initial_velocity[observation.material_id == 0], [[8.0, 3.0]] * int((observation.material_id == 0).sum()))
    assert problem.evaluate(np.array([20.0])).loss < 1e-10  # m^2: the truth, c = 20 kPa
    assert problem.evaluate(np.array([60.0])).loss > 1e-6


def test_checkpointing_keeps_memory_nearly_flat_in_rollout_length(toy):
    """CPU measure: peak bytes held for the backward pass (saved-tensor hooks, runout.inverse.memory)."""
    simulator = tiny_gns()
    simulator.requires_grad_(False)
    points = fill_points(scene_from_dict(TOY_SCENE, "toy"))
    window = torch.tensor(points.position, dtype=torch.float32)[None].expand(6, -1, -1)
    ptype = torch.as_tensor(points.particle_type)

    def peak(steps: int, checkpoint: bool) -> int:
        material = torch.full((len(points), 2), 0.5, requires_grad=True)
        with PeakMemory("cpu") as memory:
            positions = rollout(simulator, window, ptype, material, steps, [[0, 60], [0, 40]], checkpoint=checkpoint)
            positions[-1].square().sum().backward()
        return memory.peak_bytes

    plain = {n: peak(n, False) for n in (50, 100)}
    ckpt = {n: peak(n, True) for n in (50, 100)}
    plain_growth, ckpt_growth = plain[100] - plain[50], ckpt[100] - ckpt[50]
    assert plain_growth > 0.4 * plain[100]  # without: memory roughly proportional to the steps
    assert ckpt_growth < plain_growth / 10
    assert ckpt[100] < plain[50] / 5


# ----------------------------------------------------------------------------- optimiser


@pytest.fixture(scope="module")
def two_parameter_run(toy, tmp_path_factory):
    params = ("[parameters.left]\nc = { initial = 60.0, lower = 0.0, upper = 100.0 }\n"
              "[parameters.right]\nphi = { initial = 35.0, lower = 5.0, upper = 45.0 }")
    spec, observation, problem = problem_for(write_spec(toy, params, name="two.toml"))
    start = np.array(spec.initial_normalised())
    out = tmp_path_factory.mktemp("two")
    result = minimise(problem.evaluate, spec.free, start, out, run_info(spec, start), spec.optimiser,
                      "test", observation.true_values)
    return spec, problem, result


def test_recovers_two_parameters(two_parameter_run):
    _, _, result = two_parameter_run
    np.testing.assert_allclose(result.values, [TRUE["left"]["cohesion"], TRUE["right"]["friction_angle"]], rtol=0.01)


def test_recovers_three_parameters(toy, tmp_path):
    params = ("[parameters.left]\nphi = { initial = 20.0, lower = 5.0, upper = 45.0 }\n"
              "c = { initial = 50.0, lower = 0.0, upper = 100.0 }\n"
              "[parameters.right]\nc = { initial = 20.0, lower = 10.0, upper = 80.0 }")
    spec, observation, problem = problem_for(write_spec(toy, params, name="three.toml"))
    start = np.array(spec.initial_normalised())
    result = minimise(problem.evaluate, spec.free, start, tmp_path, run_info(spec, start), spec.optimiser,
                      "test", observation.true_values)
    truth = [TRUE["left"]["friction_angle"], TRUE["left"]["cohesion"], TRUE["right"]["cohesion"]]
    np.testing.assert_allclose(result.values, truth, rtol=0.01)
    assert result.history.model_loss(result.history.iterations[-1]) < 1e-6


def rosenbrock(values: np.ndarray) -> Evaluation:
    """A cheap evaluator with a curved valley (minimum at 1, 1): many L-BFGS-B steps."""
    x, y = values
    loss = (1 - x) ** 2 + 100 * (y - x * x) ** 2
    gradient = np.array([-2 * (1 - x) - 400 * x * (y - x * x), 200 * (y - x * x)])
    return Evaluation(values, float(loss), gradient, 0.0, 0.0, 0, np.zeros((1, 2), dtype=np.float32))


def test_killed_run_resumes_on_the_same_path(tmp_path):
    free = (FreeParameter("a", "c", 0.2, -0.5, 2.0), FreeParameter("b", "c", 2.5, 0.0, 3.0))
    start = np.array([p.normalise(p.initial) for p in free])
    info = RunInfo("d", "test", "", start.tolist())
    finished = minimise(rosenbrock, free, start, tmp_path / "whole", info, OptimiserSpec(), "test")
    assert len(finished.history.records) > 15 and np.allclose(finished.values, 1.0, atol=1e-3)
    calls = []

    def killed_after_ten(values):
        if len(calls) == 10:
            raise KeyboardInterrupt
        calls.append(values)
        return rosenbrock(values)

    with pytest.raises(KeyboardInterrupt):
        minimise(killed_after_ten, free, start, tmp_path / "killed", info, OptimiserSpec(), "test")
    assert len(json.loads((tmp_path / "killed" / HISTORY_JSON).read_text())["evaluations"]) == 10

    recomputed = []

    def counting(values):
        recomputed.append(values)
        return rosenbrock(values)

    resumed = minimise(counting, free, start, tmp_path / "killed", info, OptimiserSpec(), "test")
    assert len(recomputed) == len(finished.history.records) - 10  # recorded evaluations were replayed
    assert [r.normalised for r in resumed.history.records] == [r.normalised for r in finished.history.records]
    assert [r.iteration for r in resumed.history.records] == [r.iteration for r in finished.history.records]
    np.testing.assert_array_equal(resumed.values, finished.values)


def test_a_stopped_run_continues_with_more_iterations(toy, tmp_path):
    free = (FreeParameter("a", "c", 0.2, -0.5, 2.0), FreeParameter("b", "c", 2.5, 0.0, 3.0))
    start = np.array([p.normalise(p.initial) for p in free])
    info = RunInfo("d", "test", "", start.tolist())
    whole = minimise(rosenbrock, free, start, tmp_path / "whole", info, OptimiserSpec(), "test")
    short = minimise(rosenbrock, free, start, tmp_path / "run", info, OptimiserSpec(max_iterations=5), "test")
    assert short.iterations == 5
    longer = minimise(rosenbrock, free, start, tmp_path / "run", info, OptimiserSpec(), "test")
    np.testing.assert_array_equal(longer.values, whole.values)
    parameters = "[parameters.left]\nc = { lower = 1.0, upper = 80.0 }\n"
    digest = {text: load_inverse_spec(write_spec(toy, text, name="d.toml")).digest for text in (
        parameters, parameters + "[optimiser]\nmax_iterations = 99", parameters.replace("80.0", "90.0"))}
    assert len(set(digest.values())) == 2 and digest[parameters] != digest[parameters.replace("80.0", "90.0")]


def test_history_from_another_spec_is_refused(two_parameter_run, tmp_path):
    spec, problem, _ = two_parameter_run
    start = np.array(spec.initial_normalised())
    minimise(problem.evaluate, spec.free, start, tmp_path, run_info(spec, start),
             OptimiserSpec(max_iterations=1, max_evaluations=2), "test")
    other = RunInfo("another digest", "gns", "tiny", [float(x) for x in start])
    with pytest.raises(InputError, match="different spec"):
        minimise(problem.evaluate, spec.free, start, tmp_path, other, spec.optimiser, "test")


def quadratic(target: np.ndarray):
    """A cheap evaluator: loss = |values - target|^2."""
    def evaluate(values: np.ndarray) -> Evaluation:
        return Evaluation(values, float(np.sum((values - target) ** 2)), 2 * (values - target), 0.0, 0.0, 0,
                          np.zeros((1, 2), dtype=np.float32))
    return evaluate


def test_starts_are_deterministic_and_report_the_spread(tmp_path):
    free = (FreeParameter("a", "c", 50.0, 10.0, 100.0), FreeParameter("b", "phi", 30.0, 5.0, 50.0))
    points = starting_points(free, 4)
    np.testing.assert_array_equal(points, starting_points(free, 4))
    assert np.allclose(points[0], [40 / 90, 25 / 45]) and len({tuple(p) for p in points}) == 4
    assert points.min() >= 0 and points.max() <= 1
    info = RunInfo("d", "test", "", [])
    results = run_starts(quadratic(np.array([40.0, 20.0])), free, 4, tmp_path, info, OptimiserSpec(), "test")
    assert [r.out_dir.name for r in results] == ["start_00", "start_01", "start_02", "start_03"]
    rows = spread(results, free)
    assert rows[0]["min"] == pytest.approx(40.0, abs=1e-4) and rows[0]["range_of_bounds"] < 1e-5


def test_tight_and_active_bounds_are_never_left_by_the_command(toy, tmp_path, capsys, monkeypatch):
    """c[right] in [39.5, 40.5] kPa around its true 40 (the paper's c in [99, 101] pattern), and
    c[left] in [25, 60] kPa, which excludes its true 20 kPa, so that bound must end active."""
    from runout.cli import main

    params = ("[parameters.left]\nphi = { initial = 20.0, lower = 5.0, upper = 45.0 }\n"
              "c = { initial = 55.0, lower = 25.0, upper = 60.0 }\n"
              "[parameters.right]\nc = { initial = 40.4, lower = 39.5, upper = 40.5 }\n"
              "[optimiser]\nmax_iterations = 8\n[rollout]\nsteps = 8")
    spec_path = write_spec(toy, params, name="bounds.toml")
    out = tmp_path / "run"
    argv = ["runout", "invert", str(spec_path), "--model", str(toy / "model.pt"), "--out", str(out)]
    monkeypatch.setattr(sys, "argv", argv)
    main()
    history = json.loads((out / HISTORY_JSON).read_text())
    values = np.array([e["values"] for e in history["evaluations"]])
    lower = np.array([p["lower"] for p in history["parameters"]])
    upper = np.array([p["upper"] for p in history["parameters"]])
    assert np.all(values >= lower) and np.all(values <= upper)
    assert history["result"]["values"][1] == 25.0  # the active bound
    printed = capsys.readouterr().out
    assert "c[right]" in printed and "bounds [39.5, 40.5]" in printed
    for name in ("history.csv", "loss.png", "parameters.png", "deposit.png"):
        assert (out / name).stat().st_size > 0
    rows = (out / "history.csv").read_text().splitlines()
    assert len(rows) == len(history["evaluations"]) + 1


def test_public_invert_runs_several_starts(toy, tmp_path):
    params = ("[parameters.right]\nc = { initial = 20.0, lower = 10.0, upper = 80.0 }\n"
              "[optimiser]\nmax_iterations = 6\n[rollout]\nsteps = 8")
    result = invert(write_spec(toy, params, name="starts.toml"), tmp_path, model=toy / "model.pt", starts=2)
    assert len(result.starts) == 2 and (tmp_path / "starts.json").is_file() and (tmp_path / "starts.png").is_file()
    assert result.best.values[0] == pytest.approx(40.0, rel=0.01)
    starts = json.loads((tmp_path / "starts.json").read_text())
    assert starts["true"] == [40.0]  # the target's own value, drawn in starts.png
    assert starts["data_loss_at_true_m2"] == result.loss_at_truth < 1e-10  # m²: the target is this model's run at 40


TRUTH_PARAMS = ("[parameters.right]\nc = { initial = 70.0, lower = 10.0, upper = 80.0 }\n"
                "[optimiser]\nmax_iterations = 1\n[rollout]\nsteps = 8")


def test_invert_gives_the_data_loss_at_the_true_values_through_its_own_engine(toy, tmp_path):
    """The target names its materials, so one more forward run gives the loss at the true values, an
    evaluation's loss there: on another model's target (a stand-in for a wrong engine) measured
    4.2e-3 m², on the model's own target 0 (its answer after one iteration: 6.0e-5 m²)."""
    write_target(tmp_path, tiny_gns(seed=1))
    at_truth = {}
    for folder in (tmp_path, toy):
        spec_path = write_spec(folder, TRUTH_PARAMS, name="truth.toml")
        result = invert(spec_path, tmp_path / f"run_{folder.name}", model=toy / "model.pt")
        _, _, problem = problem_for(spec_path)
        assert result.loss_at_truth == pytest.approx(problem.evaluate(np.array([40.0])).loss, rel=1e-6, abs=1e-14)
        assert (f"at the true values (c[right] = 40 kPa): loss {result.loss_at_truth:.4g} m^2 "
                f"(at the answer: {result.best.loss:.4g} m^2)") in summary_lines(result)
        at_truth[folder] = result.loss_at_truth
        written = json.loads((tmp_path / f"run_{folder.name}" / HISTORY_JSON).read_text())["result"]
        assert written["data_loss_at_true_m2"] == result.loss_at_truth and written["values"] == list(result.best.values)
    assert at_truth[tmp_path] > 1e-3 and at_truth[toy] < 1e-10 < result.best.loss  # m²


def test_a_target_that_names_no_true_values_gives_no_loss_at_them(toy, tmp_path):
    (tmp_path / "toy.toml").write_text((toy / "toy.toml").read_text())
    np.save(tmp_path / "observed.npy", np.load(toy / "target" / "trajectory.npz", allow_pickle=True)["simulation_0"][0][8])
    (tmp_path / "spec.toml").write_text(f'scene = "toy.toml"\n[target]\npositions = "observed.npy"\n{TRUTH_PARAMS}\n')
    result = invert(tmp_path / "spec.toml", tmp_path / "run", model=toy / "model.pt")
    assert result.loss_at_truth is None and not any("true values" in line for line in summary_lines(result))
    assert "data_loss_at_true_m2" not in json.loads((tmp_path / "run" / HISTORY_JSON).read_text())["result"]


# ----------------------------------------------------------------------------- MPM finite differences


def test_mpm_fd_runs_the_stencil_as_one_batch(toy, monkeypatch):
    import runout.mpm

    params = ("[parameters.left]\nc = { lower = 0.0, upper = 100.0 }\n"
              "[parameters.right]\nphi = { lower = 5.0, upper = 45.0 }\n"
              "[target]\ntrajectory = \"target\"\nframes = [8]")
    spec_path = toy / "fd.toml"
    spec_path.write_text(f'scene = "toy.toml"\n{params}\n')
    spec = load_inverse_spec(spec_path)
    engine = MpmFiniteDifference(spec, load_observation(spec), step=0.05)
    stencil, spacing = central_stencil(spec.free, np.array([100.0, 20.0]), engine.step)  # c at its upper bound
    assert stencil[:, 0].max() == 100.0 and spacing[0] == pytest.approx(0.05)

    batches = []
    real = runout.mpm.simulate

    def counted(scenes, **kwargs):
        batches.append(len(scenes))
        return real(scenes, **kwargs)

    monkeypatch.setattr(runout.mpm, "simulate", counted)
    values = np.array([50.0, 20.0])
    ev = engine(values)
    assert batches == [5]
    alone = [float(engine.data_loss(torch.from_numpy(real([spec.scene_at(v)], progress=False, frames=9)[0].positions[[8]])))
             for v in (values, values + [5.0, 0.0], values - [5.0, 0.0])]
    assert ev.loss == pytest.approx(alone[0], rel=1e-6)
    assert ev.gradient[0] == pytest.approx((alone[1] - alone[2]) / 10.0, rel=1e-4, abs=1e-9)


def test_a_run_does_not_resume_on_a_replaced_model_file(tmp_path):
    """The history names the model by its bytes, not only its path: a file replaced at the same
    path (a newly shipped model) gets one sentence instead of the old file's evaluations."""
    from runout.inverse.run import model_identity

    model = tmp_path / "model.pt"
    model.write_bytes(b"the first file's weights")
    free = (FreeParameter("a", "c", 0.2, -0.5, 2.0), FreeParameter("b", "c", 2.5, 0.0, 3.0))
    start = np.array([p.normalise(p.initial) for p in free])
    first = RunInfo("d", "neural-mpm", model_identity(model), start.tolist())
    minimise(rosenbrock, free, start, tmp_path / "run", first, OptimiserSpec(max_iterations=3), "test")
    again = minimise(rosenbrock, free, start, tmp_path / "run", RunInfo("d", "neural-mpm", model_identity(model),
                                                                         start.tolist()), OptimiserSpec(), "test")
    assert again.iterations > 3  # the same file resumes and goes on
    model.write_bytes(b"the second file's weights")
    with pytest.raises(InputError, match="different spec, engine, model"):
        minimise(rosenbrock, free, start, tmp_path / "run", RunInfo("d", "neural-mpm", model_identity(model),
                                                                     start.tolist()), OptimiserSpec(), "test")
