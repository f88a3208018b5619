"""A GNS of frame stride K: windows of positions K frames apart, statistics of K-frame
differences, one rollout frame every K dataset frames, compared with the MPM at its times."""

import json
from dataclasses import replace

import numpy as np
import pytest
import torch

from runout.compare import comparison_metrics
from runout.errors import InputError
from runout.gns.checkpoint import load_simulator, read_checkpoint, save_checkpoint
from runout.gns.engine import GnsEngine
from runout.gns.rollout import rollout_trajectory, start_window
from runout.gns.schema import FeatureSchema, NetworkConfig
from runout.gns.simulator import GraphNetworkSimulator, Normalisation
from runout.gns.windows import TrainingWindows
from runout.inverse import load_inverse_spec, load_observation
from runout.inverse.forward import inverse_problem
from runout.learned.scenes import scene_at_rest
from runout.metrics import at_common_times, compare, position_mse
from runout.scene import scene_from_dict
from runout.simfiles import read_simulations, statistics, write_simulations
from runout.train import train
from runout.trajectory import first_frame_velocity, trajectory_from_features
from test_cli_exits import one_sentence, run
from test_gns_synthetic import BOUNDS, FRAME_DT, falling_block, write_dataset
from test_gns_train import config, losses

torch.set_num_threads(1)  # tiny graphs: extra threads only add OpenMP synchronisation cost


@pytest.fixture(scope="module")
def stride_two(tmp_path_factory):
    """(data folder, run folder) of a stride-2 run of 150 steps on a tiny synthetic dataset."""
    folder = tmp_path_factory.mktemp("stride")
    data = write_dataset(folder / "data")
    train(config(data, folder / "run", steps=150, lr_init=3e-3, noise=0.0, frame_stride=2))
    return data, folder / "run"


def truth(frames: int = 20):
    return trajectory_from_features(*falling_block(frames, 0.5), FRAME_DT, BOUNDS)


def test_windows_at_stride_two_start_at_every_frame(tmp_path):
    data = write_dataset(tmp_path / "data", frames=20, n_train=2)
    sims = TrainingWindows(data / "train.npz", torch.device("cpu"), rest_windows=False).with_stride(2)
    assert sims.n_windows == 2 * (20 - 6 * 2)  # starts 0..7 of each simulation
    positions = torch.from_numpy(read_simulations(data / "train.npz")[1][0])
    window, future, _, _, _ = sims._window(8 + 3)  # the second simulation, start frame 3
    torch.testing.assert_close(window, positions[3:14:2].transpose(0, 1))  # frames 3, 5, ..., 13
    torch.testing.assert_close(future[:, -1], positions[15])


def test_windows_at_rest_start_before_frame_zero_at_stride_two(tmp_path):
    data = write_dataset(tmp_path / "data", frames=20, n_train=2)
    sims = TrainingWindows(data / "train.npz", torch.device("cpu")).with_stride(2)
    assert sims.n_windows == 2 * (20 - 6 * 2 + 5 * 2)  # starts -10..7 of each simulation
    positions = torch.from_numpy(read_simulations(data / "train.npz")[1][0])
    window, future, _, _, _ = sims._window(18)  # the second simulation's first window: the scene at rest
    torch.testing.assert_close(window, positions[[0] * 6].transpose(0, 1))
    torch.testing.assert_close(future[:, -1], positions[2])
    window, future, _, _, _ = sims._window(18 + 7)  # start frame -3: frames 0, 0, 1, 3, 5, 7
    torch.testing.assert_close(window, positions[[0, 0, 1, 3, 5, 7]].transpose(0, 1))
    torch.testing.assert_close(future[:, -1], positions[9])


def test_a_thrown_block_stands_before_its_first_frame_where_its_velocity_puts_it(tmp_path):
    """Family a throws blocks at up to 15 m/s: held at frame 0, such a scene would ask the model
    for a jump from standing still to full speed in one step. Before frame 0 each point stands
    where its frame-0 velocity puts it, as a rollout's start window places it; a scene at rest
    keeps frame 0 held."""
    at_rest = falling_block(20, 0.5)
    positions, ptype, material = falling_block(20, 0.5)
    soil = ptype != 3
    thrown = positions.copy()
    thrown[:, soil, 0] += 10.0 * FRAME_DT * np.arange(20)[:, None]  # 10 m/s sideways from frame 0
    write_simulations(tmp_path / "train.npz", [at_rest, (thrown, ptype, material)])
    sims = TrainingWindows(tmp_path / "train.npz", torch.device("cpu")).with_stride(2)
    assert sims.starts_at_rest == [True, False]
    assert sims.n_windows == 2 * (20 - 6 * 2 + 5 * 2)  # starts -10..7 of each
    velocity = first_frame_velocity(thrown[0], thrown[1], ptype, FRAME_DT)  # m/s
    assert velocity[soil, 0] == pytest.approx(10.0, abs=0.2) and not velocity[~soil].any()  # m/s; the block also spreads
    window, future, _, _, held = sims._window(18 + 7)  # the thrown block's start frame -3: frames -3, -1, 1, 3, 5, 7
    expected = thrown[[0, 0, 1, 3, 5, 7]].astype(np.float64)
    expected[0] -= 3 * FRAME_DT * velocity
    expected[1] -= 1 * FRAME_DT * velocity
    torch.testing.assert_close(window, torch.from_numpy(expected.astype(np.float32)).transpose(0, 1))
    torch.testing.assert_close(future[:, -1], torch.from_numpy(thrown[9]))
    assert held == 2  # frames -3 and -1, which a rollout is given exactly
    window, _, _, _, held = sims._window(18)  # its window entirely before frame 0: the rollout's start
    start = start_window(thrown[0], velocity, 6, 2 * FRAME_DT)
    torch.testing.assert_close(window, torch.from_numpy(start).transpose(0, 1))
    assert held == 6
    torch.testing.assert_close(sims._window(0)[0], torch.from_numpy(at_rest[0][[0] * 6]).transpose(0, 1))  # at rest: held


def test_a_scene_with_a_region_velocity_starts_its_rollout_at_that_velocity():
    scene = scene_from_dict({
        "name": "throw", "domain": {"width": 100.0, "height": 60.0, "cell_size": 4.0},
        "materials": {"ground": {"model": "elastic"}, "rock": {"friction_angle": 40.0}},
        "regions": [
            {"material": "ground", "polygon": [[0, 0], [100, 0], [100, 8], [0, 8]], "fixed": True, "velocity": [3.0, 0.0]},
            {"material": "rock", "polygon": [[20, 20], [40, 20], [40, 40], [20, 40]], "velocity": [6.0, -2.0]},
        ],
    })
    start = scene_at_rest(scene)
    soil = start.soil
    np.testing.assert_array_equal(start.start_velocity()[soil], np.tile([6.0, -2.0], (int(soil.sum()), 1)))
    assert not start.start_velocity()[~soil].any()  # fixed ground does not move, whatever its region says
    window = start_window(start.positions[0], start.start_velocity(), 6, 2 * FRAME_DT)  # m
    np.testing.assert_allclose(window[-1], start.positions[0])
    np.testing.assert_allclose(window[0, soil] - window[-1, soil], np.tile([-6.0, 2.0], (int(soil.sum()), 1)) * 10 * FRAME_DT,
                               atol=1e-4)  # 5 steps of 2 frames back along the velocity
    np.testing.assert_array_equal(window[:, ~soil], np.repeat(start.positions[:1, ~soil], 6, axis=0))
    truth = replace(start, positions=np.stack([start.positions[0], start.positions[0] + [0.3, 0.0]]), initial_velocity=None)
    estimated = truth.start_velocity()  # a trajectory without a scene: its first frame's motion, as a throw under gravity
    np.testing.assert_allclose(estimated[soil], np.tile([0.3 / FRAME_DT, 0.5 * 9.81 * FRAME_DT], (int(soil.sum()), 1)), rtol=1e-5)
    assert not estimated[~soil].any()
    slow = replace(truth, positions=np.stack([start.positions[0], start.positions[0] + [0.05, 0.0]]))  # 1.3 m/s: a slope failing from rest
    assert not slow.start_velocity().any()


def test_stride_two_statistics_are_those_of_two_frame_differences(tmp_path):
    data = write_dataset(tmp_path / "data", frames=20, n_train=3)
    sims = TrainingWindows(data / "train.npz", torch.device("cpu"))
    positions = [p.astype(np.float64) for p, _, _ in read_simulations(data / "train.npz")]
    v = np.concatenate([(p[2:] - p[:-2]).reshape(-1, 2) for p in positions])
    a = np.concatenate([(p[4:] - 2 * p[2:-2] + p[:-4]).reshape(-1, 2) for p in positions])
    measured = sims.with_stride(2).moments()
    for key, by_hand in (("vel_mean", v.mean(0)), ("vel_std", v.std(0)), ("acc_mean", a.mean(0)), ("acc_std", a.std(0))):
        np.testing.assert_allclose(measured[key], by_hand, rtol=1e-9, atol=1e-12)
    at_one = sims.moments()  # stride 1: what the generator writes to metadata.json
    for key, value in statistics([(p,) for p in positions]).items():
        if key in at_one:
            np.testing.assert_allclose(at_one[key], value, rtol=1e-9, atol=1e-12)


def test_a_stride_two_run_learns_and_records_its_stride_and_statistics(stride_two, tmp_path):
    data, run_dir = stride_two
    curve = losses(run_dir)
    # medians: one window's loss spikes 10-40x (the means of the last 20 steps were 0.32 of the
    # first 20's on an AMX Xeon with a single spike of 9.2 among ~1); a run that does not learn stays near 1
    assert np.median(curve[-20:]) < 0.5 * np.median(curve[:20])
    ckpt = read_checkpoint(run_dir / "checkpoint.pt")
    assert ckpt["schema"]["frame_stride"] == 2
    measured = TrainingWindows(data / "train.npz", torch.device("cpu")).with_stride(2).moments()
    assert ckpt["stats"]["vel_std"] == pytest.approx(measured["vel_std"])
    assert ckpt["stats"]["acc_std"] == pytest.approx(measured["acc_std"])
    noisy = train(config(data, tmp_path / "noisy", steps=1, frame_stride=2, noise=0.3))
    assert noisy.stats.noise_std == pytest.approx(0.3 * np.mean(measured["vel_std"]))  # m per step of two frames


def test_a_stride_two_model_rolls_out_one_frame_every_two_over_the_asked_time(stride_two):
    simulator = load_simulator(stride_two[1] / "checkpoint.pt")
    start = truth(20)
    predicted = rollout_trajectory(simulator, start, 20, stop_speed=None, from_rest=False)
    assert predicted.frame_dt == pytest.approx(2 * FRAME_DT)
    assert predicted.n_frames == 11 and (predicted.n_frames - 1) * predicted.frame_dt >= 19 * FRAME_DT
    np.testing.assert_array_equal(predicted.positions[:6], start.positions[0:12:2])  # the window: frames 0, 2, ..., 10
    from_rest = rollout_trajectory(simulator, start, 20, stop_speed=None)  # frame 0 held before the start
    assert from_rest.n_frames == 11 and from_rest.frame_dt == pytest.approx(2 * FRAME_DT)
    np.testing.assert_array_equal(from_rest.positions[0], start.positions[0])
    assert from_rest.info["start"] == "rest"
    scene = scene_from_dict({
        "domain": {"width": 60, "height": 30},
        "materials": {"sand": {"friction_angle": 30}},
        "regions": [{"material": "sand", "polygon": [[20, 0], [36, 0], [36, 10], [20, 10]]}],
    })
    at_rest = rollout_trajectory(simulator, scene_at_rest(scene), 480, stop_speed=None)
    assert at_rest.n_frames == 241 and at_rest.frame_dt * (at_rest.n_frames - 1) == pytest.approx(18.0)


def test_a_rollout_equal_to_the_subsampled_truth_has_no_error():
    full = truth(21)
    coarse = full.every(2)  # frames 0, 2, ..., 20, as a stride-2 GNS would give them
    assert coarse.frame_dt == pytest.approx(2 * FRAME_DT) and coarse.n_frames == 11
    metrics = compare(coarse, full)
    assert metrics["frames_compared"] == 11
    assert metrics["position_mse_mean_m2"] == 0.0 and metrics["runout_error"] == 0.0
    assert (position_mse(coarse, full) == 0).all()
    compared = comparison_metrics(full, coarse, 2.0)
    assert compared["position_mse_final_m2"] == 0.0 and compared["deposit_iou"] == 1.0
    assert compared["runout_farthest_m"]["error_m"] == 0.0
    late = truth(20)  # the truth ends at frame 19; the rollout's last frame (20) has no partner
    a, b = at_common_times(coarse, late)
    assert a.n_frames == b.n_frames == 10 and np.array_equal(a.positions, b.positions)
    shifted = full.every(2)
    shifted.positions = full.positions[1::2]  # frames 1, 3, ...: the wrong times give an error
    assert compare(shifted, full)["position_mse_mean_m2"] > 0


def test_intervals_that_are_no_multiple_of_each_other_are_refused():
    a, b = truth(20), truth(20)
    b.frame_dt = 1.5 * FRAME_DT
    with pytest.raises(InputError, match="whole multiple"):
        compare(a, b)


def test_resuming_at_another_stride_is_refused_in_one_sentence(tmp_path):
    data = write_dataset(tmp_path / "data")
    train(config(data, tmp_path / "run", steps=1, frame_stride=2))
    with pytest.raises(InputError) as refused:
        train(config(data, tmp_path / "run", steps=2, resume=True, frame_stride=1))
    message = str(refused.value)
    assert "was trained at --frame-stride 2" in message and message.count(". ") == 0
    resumed = train(config(data, tmp_path / "run", steps=2, resume=True))  # no --frame-stride: the checkpoint's
    assert resumed.frame_stride == 2


def test_fine_tuning_keeps_the_base_models_stride_unless_another_is_asked(tmp_path):
    data = write_dataset(tmp_path / "data")
    base = train(config(data, tmp_path / "base", steps=1, frame_stride=2))
    tuned = train(config(data, tmp_path / "tuned", steps=1, init=tmp_path / "base" / "checkpoint.pt"))
    assert tuned.frame_stride == 2
    # --frame-stride 3 on --init: the weights carry over, the statistics become those of
    # 3-frame differences (so a 3-frame step is normalised like a 1-frame one was)
    other = train(config(data, tmp_path / "other", steps=1, lr_init=1e-12,
                         init=tmp_path / "base" / "checkpoint.pt", frame_stride=3))
    assert other.frame_stride == 3
    moments = TrainingWindows(data / "train.npz", torch.device("cpu")).with_stride(3).moments()
    np.testing.assert_allclose(other.stats.vel_std, moments["vel_std"], rtol=1e-9)
    np.testing.assert_allclose(other.stats.acc_std, moments["acc_std"], rtol=1e-9)
    assert other.vel_scale[0] > 1.3 * base.vel_scale[0]  # a 3-frame step moves points about 1.5 times as far as 2 frames
    for (name, w_base), (_, w_other) in zip(base.network.named_parameters(), other.network.named_parameters()):
        torch.testing.assert_close(w_other, w_base, atol=1e-6, rtol=0, msg=name)
    reloaded = load_simulator(tmp_path / "other" / "checkpoint.pt")
    assert reloaded.frame_stride == 3 and reloaded.stats.vel_std == other.stats.vel_std


def test_a_checkpoint_without_a_stride_loads_as_stride_one(tmp_path):
    data = write_dataset(tmp_path / "data")
    model = train(config(data, tmp_path / "run", steps=1))
    save_checkpoint(tmp_path / "new.pt", model)
    ckpt = torch.load(tmp_path / "new.pt", weights_only=True)
    del ckpt["schema"]["frame_stride"]  # as written before the option existed
    torch.save(ckpt, tmp_path / "old.pt")
    assert load_simulator(tmp_path / "old.pt").frame_stride == 1


def test_a_stride_longer_than_the_data_is_one_sentence(tmp_path):
    data = write_dataset(tmp_path / "data", frames=20)
    with pytest.raises(InputError, match="choose a smaller --frame-stride"):  # a window spans 24 frames
        train(config(data, tmp_path / "run", steps=1, frame_stride=4, rest_windows=False))
    short = write_dataset(tmp_path / "short", frames=16)
    with pytest.raises(InputError, match="choose a smaller --frame-stride"):  # from rest: no frame 16 to aim at
        train(config(short, tmp_path / "run", steps=1, frame_stride=16))


@pytest.mark.parametrize("stride", ["0", "17"])
def test_the_frame_stride_option_checks_its_range(tmp_path, capsys, stride):
    data = write_dataset(tmp_path / "data")
    code, err = run(["train", "--data", data, "--out", tmp_path / "run", "--steps", "1", "--frame-stride", stride], capsys)
    assert code == 2 and one_sentence(err)
    assert f"--frame-stride = {stride} is outside the allowed range [1, 16]." in err


def test_an_inverse_at_stride_two_observes_only_frames_the_model_predicts(tmp_path):
    from test_inverse import write_spec, write_target

    torch.manual_seed(0)
    stats = Normalisation((0.0, 0.0), (2e-2, 2e-2), (0.0, 0.0), (2e-3, 2e-3), 0.0)
    simulator = GraphNetworkSimulator(FeatureSchema(frame_stride=2), stats, 5.0, NetworkConfig(16, 16, 1, 2)).eval()
    write_target(tmp_path, simulator, steps=15)  # frames 0-15 (a stand-in for an MPM run)
    parameters = "[parameters.left]\nphi = { initial = 25.0, lower = 10.0, upper = 40.0 }"
    odd = load_inverse_spec(write_spec(tmp_path, parameters, "frames = [13]", name="odd.toml"))
    with pytest.raises(InputError, match="observed frame 13 is not one the model predicts"):
        load_observation(odd, stride=2)
    spec = load_inverse_spec(write_spec(tmp_path, parameters, name="final.toml"))
    observation = load_observation(spec, stride=2)
    assert observation.frames == (14,) and observation.model_frames == (7,)  # "final": the last even frame
    assert observation.model_steps == 7  # from rest at frame 0, step j reaches frame 2j
    problem = inverse_problem(spec, observation, GnsEngine(simulator))
    assert problem.forward(problem.features(torch.tensor([25.0], dtype=torch.float64))).shape == (1, observation.positions.shape[1], 2)
    with pytest.raises(InputError, match="frame stride 1"):
        inverse_problem(spec, load_observation(spec), GnsEngine(simulator))


def test_the_cli_trains_at_stride_two_and_rolls_out_against_the_full_rate_truth(tmp_path):
    from typer.testing import CliRunner

    from runout.cli import app
    from runout.plots import animation_name
    from runout.trajectory import load_trajectory, save_trajectory

    data = write_dataset(tmp_path / "data")
    tiny = ["--latent", "16", "--hidden", "16", "--message-passing-steps", "2", "--valid-every", "0"]
    trained = CliRunner().invoke(app, ["train", "--data", str(data), "--out", str(tmp_path / "run"), "--steps", "3",
                                       "--frame-stride", "2", *tiny])
    assert trained.exit_code == 0, trained.output
    save_trajectory(truth(14), tmp_path / "mpm", feature_width=1)
    out = tmp_path / "rollout"
    rolled = CliRunner().invoke(app, ["rollout", "--model", str(tmp_path / "run" / "checkpoint.pt"), str(tmp_path / "mpm"),
                                      "--out", str(out)])
    assert rolled.exit_code == 0, rolled.output
    predicted = load_trajectory(out)
    assert predicted.n_frames == 8 and predicted.frame_dt == pytest.approx(2 * FRAME_DT)  # frames 0, 2, ..., 14
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["frames_compared"] == 7  # frames 0, 2, ..., 12 of the truth's 0-13
    assert (out / "position_mse.png").is_file() and (out / animation_name()).is_file()
