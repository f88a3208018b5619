"""Pushforward (multi-step) training: each step rolls the model out n ~ U{0..N} steps from a
true window without gradient and trains on the window it made against the true frame."""

import json

import numpy as np
import pytest
import torch
import torch.multiprocessing as mp

from runout.errors import InputError
from runout.gns.checkpoint import read_checkpoint
from runout.gns.features import Constraints
from runout.gns.schema import FeatureSchema
from runout.gns.simulator import GraphNetworkSimulator, Normalisation
from runout.gns.training import masked_loss, pushforward, training_inputs
from runout.gns.windows import TrainingWindows
from runout.simfiles import read_metadata, read_simulations
from runout.train import Context, _generators, _train_step, train, unrolled_steps
from runout.train_settings import onset_at, parse_onset_schedule
from test_cli_exits import one_sentence, run
from test_gns_synthetic import write_dataset
from test_gns_train import TINY, config, ddp_worker, free_port, losses

torch.set_num_threads(1)  # tiny graphs: extra threads only add OpenMP synchronisation cost


def log_lines(run_dir) -> list[dict]:
    """log.jsonl without the wall times."""
    lines = [json.loads(ln) for ln in (run_dir / "log.jsonl").read_text().splitlines()]
    return [{k: v for k, v in r.items() if k != "wall_s"} for r in lines]


def same_weights(a, b) -> bool:
    return all(torch.equal(x, y) for x, y in zip(a.state_dict().values(), b.state_dict().values()))


def test_pushforward_zero_is_one_step_training(tmp_path):
    data = write_dataset(tmp_path / "data")
    default = train(config(data, tmp_path / "default", steps=12))
    zero = train(config(data, tmp_path / "zero", steps=12, pushforward=0))
    assert same_weights(default, zero) and log_lines(tmp_path / "default") == log_lines(tmp_path / "zero")
    assert read_checkpoint(tmp_path / "zero" / "checkpoint.pt")["train"]["pushforward"] == 0


def test_steps_that_draw_no_pushforward_are_one_step_steps(tmp_path):
    data = write_dataset(tmp_path / "data")
    assert [unrolled_steps(13, s, 2) for s in range(3)] == [0, 0, 1]  # seed 13: the first unrolled step is step 2
    train(config(data, tmp_path / "one", steps=3, seed=13))
    train(config(data, tmp_path / "push", steps=3, seed=13, pushforward=2))
    one, push = losses(tmp_path / "one"), losses(tmp_path / "push")
    assert one[:2] == push[:2] and one[2] != push[2]


def test_the_unrolled_steps_are_uniform_and_depend_on_seed_and_step_only():
    draws = [unrolled_steps(0, s, 2) for s in range(600)]
    assert draws == [unrolled_steps(0, s, 2) for s in range(600)]  # no rank, no state: every process agrees
    assert all(150 < draws.count(n) < 250 for n in (0, 1, 2))
    assert draws != [unrolled_steps(1, s, 2) for s in range(600)]
    assert {unrolled_steps(0, s, 0) for s in range(100)} == {0}


@pytest.mark.parametrize("stride", [1, 2])
def test_windows_for_two_pushforward_steps_leave_room_for_the_true_frames(tmp_path, stride):
    data = write_dataset(tmp_path / "data", frames=20, n_train=2)
    sims = TrainingWindows(data / "train.npz", torch.device("cpu"), rest_windows=False).with_stride(stride)
    starts = 20 - 8 * stride  # a window and its target 2 steps on span (6 + 2) x stride + 1 frames
    assert sims.n_windows_for(2) == 2 * starts and sims.n_windows == 2 * (20 - 6 * stride)
    positions = torch.from_numpy(read_simulations(data / "train.npz")[1][0])
    last = 2 * starts - 1  # the second simulation's last start frame, starts - 1
    t = starts - 1
    window, future, _, _, _ = sims._window(last, 2)
    torch.testing.assert_close(window, positions[t : t + 6 * stride : stride].transpose(0, 1), rtol=0, atol=0)
    torch.testing.assert_close(future, positions[t + 6 * stride :: stride].transpose(0, 1), rtol=0, atol=0)
    assert t + 8 * stride == 19  # the target is the simulation's last frame
    batch = sims.sample(4, torch.Generator().manual_seed(0), unroll=2)
    assert batch.unroll == 2 and batch.future.shape == (len(batch.window), 3, 2)
    every = [p for p, _, _ in read_simulations(data / "train.npz")]
    for g in range(4):  # each sample's frames are those of one true start, t to t + 8 stride
        frames = torch.cat([batch.window, batch.future], 1)[batch.graph == g].transpose(0, 1).numpy()
        assert any(np.array_equal(frames, p[s : s + 8 * stride + 1 : stride]) for p in every for s in range(starts))


def tiny_simulator(noise: float = 0.0) -> GraphNetworkSimulator:
    torch.manual_seed(0)
    stats = Normalisation((0.0, -0.05), (0.1, 0.1), (0.0, 0.0), (0.02, 0.02), noise)
    return GraphNetworkSimulator(FeatureSchema(material_features=("tan_phi",)), stats, 4.6, TINY)


def test_an_unrolled_window_is_the_models_rollout_and_its_target_the_acceleration_to_the_true_frame(tmp_path):
    data = write_dataset(tmp_path / "data")
    sims = TrainingWindows(data / "train.npz", torch.device("cpu"))
    window, future, ptype, material, _ = sims._window(5, 2)
    constraints = Constraints.of(ptype, torch.tensor(read_metadata(data)["bounds"]))
    simulator = tiny_simulator()
    produced = pushforward(simulator, window, 2, ptype, material, constraints)
    assert not produced.requires_grad
    with torch.no_grad():  # by hand: two rollout steps, each appended and the oldest dropped
        first = simulator.step(window, ptype, material, constraints)
        second = simulator.step(torch.cat([window[:, 1:], first[:, None]], 1), ptype, material, constraints)
    torch.testing.assert_close(produced, torch.cat([window[:, 2:], first[:, None], second[:, None]], 1), rtol=0, atol=0)
    kinematic = ~constraints.movable
    assert torch.equal(produced[kinematic, -1], window[kinematic, -1])  # held, as in a rollout
    noisy, target = training_inputs(simulator, produced, future[:, -1], constraints, torch.Generator().manual_seed(0))
    x, v = produced[:, -1], produced[:, -1] - produced[:, -2]
    expected = (future[:, -1] - x) - v  # the acceleration from the produced window to the true frame
    assert torch.equal(noisy, produced)  # no noise in this simulator
    torch.testing.assert_close(target * simulator.acc_scale + simulator.acc_mean, expected)


def test_a_training_step_with_two_unrolled_steps_takes_its_loss_on_the_produced_window(tmp_path):
    data = write_dataset(tmp_path / "data")
    sims = TrainingWindows(data / "train.npz", torch.device("cpu"))
    bounds = torch.tensor(read_metadata(data)["bounds"])
    cfg = config(data, tmp_path / "run", pushforward=2, seed=0)
    ctx = Context(torch.device("cpu"))
    step = 0
    assert unrolled_steps(cfg.seed, step, 2) == 2
    simulator = tiny_simulator(noise=2.5e-3)
    sampler, noise_gen = _generators(cfg.seed, step, ctx)
    batch = sims.sample(cfg.batch_size, sampler, 2)
    constraints = Constraints.of(batch.particle_type, bounds)
    with torch.no_grad():
        window = batch.window
        for _ in range(2):
            window = torch.cat([window[:, 1:], simulator.step(window, batch.particle_type, batch.material, constraints, batch.graph)[:, None]], 1)
        noisy, target = training_inputs(simulator, window, batch.future[:, -1], constraints, noise_gen)
    predicted = simulator(noisy, batch.particle_type, batch.material, bounds, batch.graph)
    expected = masked_loss(predicted, target, constraints).detach()
    optimizer = torch.optim.Adam(simulator.parameters(), lr=0.0)
    loss = _train_step(simulator, simulator, optimizer, sims, bounds, cfg, step, ctx)
    torch.testing.assert_close(loss.detach(), expected, rtol=0, atol=0)


def test_a_stopped_pushforward_run_resumes_exactly_as_if_never_stopped(tmp_path):
    data = write_dataset(tmp_path / "data")
    whole = train(config(data, tmp_path / "whole", steps=30, pushforward=2))
    train(config(data, tmp_path / "broken", steps=20, pushforward=2))
    resumed = train(config(data, tmp_path / "broken", steps=30, resume=True, pushforward=2))
    assert log_lines(tmp_path / "broken") == log_lines(tmp_path / "whole")
    assert same_weights(whole, resumed)
    assert read_checkpoint(tmp_path / "broken" / "checkpoint.pt")["train"]["pushforward"] == 2


def test_two_gloo_processes_with_pushforward_keep_identical_parameters(tmp_path):
    data = write_dataset(tmp_path / "data", n_train=4)
    mp.spawn(ddp_worker, args=(2, free_port(), data, tmp_path / "run", tmp_path, {"pushforward": 2}), nprocs=2, join=True)
    a, b = (torch.load(tmp_path / f"rank{r}.pt") for r in (0, 1))
    assert all(torch.equal(a[k], b[k]) for k in a)


@pytest.mark.parametrize("stride", [1, 2])
def test_loss_falls_with_two_pushforward_steps(tmp_path, stride):
    data = write_dataset(tmp_path / "data")
    model = train(config(data, tmp_path / "run", steps=150, lr_init=3e-3, noise=0.0,
                         pushforward=2, frame_stride=stride, rest_windows=False))
    assert model.frame_stride == stride
    curve = losses(tmp_path / "run")
    assert np.mean(curve[-20:]) < 0.3 * np.mean(curve[:20])


def test_data_too_short_for_the_pushforward_steps_is_one_sentence(tmp_path):
    data = write_dataset(tmp_path / "data", frames=20)
    train(config(data, tmp_path / "fits", steps=1, frame_stride=2, pushforward=3, rest_windows=False))  # spans (6 + 3) x 2 + 1 = 19 frames
    with pytest.raises(InputError, match=r"frame stride 2 and 4 pushforward steps spans; choose a smaller --frame-stride or --pushforward\.$"):
        train(config(data, tmp_path / "long", steps=1, frame_stride=2, pushforward=4, rest_windows=False))
    with pytest.raises(InputError, match=r"from rest at frame stride 4 and 4 pushforward steps spans"):  # frame 20 is missing
        train(config(data, tmp_path / "rest", steps=1, frame_stride=4, pushforward=4))


def test_the_library_refuses_a_pushforward_outside_its_range(tmp_path):
    data = write_dataset(tmp_path / "data")
    for bad in (-1, 11, 1.5):
        with pytest.raises(InputError, match=r"--pushforward = .* (is outside the allowed range|must be a whole number in) \[0, 10\]\."):
            train(config(data, tmp_path / "run", steps=1, pushforward=bad))


@pytest.mark.parametrize("value", ["-1", "11"])
def test_the_pushforward_option_checks_its_range(tmp_path, capsys, value):
    data = write_dataset(tmp_path / "data")
    code, err = run(["train", "--data", data, "--out", tmp_path / "run", "--steps", "1", "--pushforward", value], capsys)
    assert code == 2 and one_sentence(err)
    assert f"--pushforward = {value} is outside the allowed range [0, 10]." in err


def test_onset_share_draws_windows_from_the_first_frames_of_every_simulation(tmp_path):
    """An onset share of 1: every window starts in its simulation's first onset frames
    (counted from the earliest start, the windows at rest); 0 draws exactly as before; 0.5 about
    half of them."""
    data = write_dataset(tmp_path / "data", frames=40, n_train=3)
    sims = TrainingWindows(data / "train.npz", torch.device("cpu"))  # windows at rest: starts from frame -5
    first = sims._windows(0)
    uniform = sims.sample(8, torch.Generator().manual_seed(3))
    same = sims.sample(8, torch.Generator().manual_seed(3), onset_share=0.0)
    assert torch.equal(uniform.window, same.window)

    def start_frames(share: float, seed: int) -> list[int]:
        gen = torch.Generator().manual_seed(seed)
        batch = sims.sample(16, gen, onset_share=share, onset_frames=4)
        every = [p for p, _, _ in read_simulations(data / "train.npz")]

        def start(window) -> int:  # the window's frames are frames t..t+5 (frame 0 held before it) of one simulation
            return next(t for p in every if p.shape[1] == window.shape[1] for t in range(sims.first_start, len(p) - 6)
                        if np.array_equal(window, p[np.clip(np.arange(t, t + 6), 0, None)]))

        return [start(batch.window[batch.graph == g].transpose(0, 1).numpy()) for g in range(16)]

    onset = start_frames(1.0, 0)
    assert len(onset) == 16 and all(sims.first_start <= t < sims.first_start + 4 for t in onset)
    mixed = [t < sims.first_start + 4 for seed in range(4) for t in start_frames(0.5, seed)]
    assert 16 <= sum(mixed) <= 56  # about 32 of 64 (the uniform draws seldom land there: 4 of 35 starts)
    assert len(first) == 4


def test_an_onset_schedule_is_the_phases_run_one_after_another(tmp_path):
    """--onset-schedule "0:0.4:4,6:0.1:2" trains exactly as 6 steps of "0:0.4:4" and then a
    --resume to step 12 with "0:0.1:2": the recipe's phases (docs/training.md) in one resumable
    command."""
    data = write_dataset(tmp_path / "data", frames=40, n_train=3)
    scheduled = train(config(data, tmp_path / "scheduled", steps=12, pushforward=1,
                             onset_schedule=parse_onset_schedule("0:0.4:4,6:0.1:2")))
    train(config(data, tmp_path / "phases", steps=6, pushforward=1, onset_schedule=((0, 0.4, 4),)))
    phases = train(config(data, tmp_path / "phases", steps=12, pushforward=1, onset_schedule=((0, 0.1, 2),), resume=True))
    assert same_weights(scheduled, phases) and log_lines(tmp_path / "scheduled") == log_lines(tmp_path / "phases")
    uniform = train(config(data, tmp_path / "uniform", steps=12, pushforward=1))
    assert not same_weights(scheduled, uniform)  # the schedule did draw other windows


def test_onset_at_follows_the_last_entry_begun():
    cfg = config("d", "o", onset_schedule=parse_onset_schedule("10:0.4:4, 20:0:2"))
    assert [onset_at(cfg, s) for s in (0, 9, 10, 19, 20, 10**6)] == [(0.0, 1), (0.0, 1), (0.4, 4), (0.4, 4), (0.0, 2), (0.0, 2)]
    assert parse_onset_schedule("") == () and onset_at(config("d", "o", onset_schedule=()), 5) == (0.0, 1)


@pytest.mark.parametrize("value, words", [
    ("0:0.4", "--onset-schedule: the entry '0:0.4' is not STEP:SHARE:FRAMES"),
    ("0:1.5:4", "--onset-schedule share = 1.5 is outside the allowed range [0, 1]"),
    ("0:0.4:4,0:0.1:4", "--onset-schedule: the step 0 of '0:0.1:4' must be after the step 0"),
    ("0:0.4:0", "--onset-schedule frames = 0 is outside the allowed range [1, 1e+06] frames"),
])
def test_a_bad_onset_schedule_is_exit_2_before_any_work(tmp_path, capsys, value, words):
    code, err = run(["train", "--data", tmp_path / "none", "--out", tmp_path / "run", "--onset-schedule", value], capsys)
    assert code == 2 and words in err and one_sentence(err)
    assert not (tmp_path / "run").exists()


def test_the_recipe_is_the_default_and_its_options_give_it(tmp_path, capsys, monkeypatch):
    """`runout train` without options trains with the recipe (TrainConfig's defaults), and with
    recipe_options() (as the campaign's scripts pass it) with exactly the same settings."""
    import runout.train
    from runout.train_settings import RECIPE, TrainConfig, recipe_options, recipe_settings

    seen = []
    monkeypatch.setattr(runout.train, "train", lambda cfg: seen.append(cfg))
    data = write_dataset(tmp_path / "data")
    for options in ([], recipe_options()):
        code, err = run(["train", "--data", data, "--out", tmp_path / "run", *options], capsys)
        assert code == 0, err
    default, explicit = ({name: getattr(cfg, name) for name in RECIPE} for cfg in seen)
    assert explicit == recipe_settings() and default == {**recipe_settings(), "overburden": None}  # None: on for a new run
    assert recipe_settings()["onset_schedule"] == TrainConfig.onset_schedule == ((0, 0.4, 4), (12_000, 0.5, 2), (20_000, 0.1, 4))
    assert (TrainConfig.noise, TrainConfig.pushforward, TrainConfig.ema, TrainConfig.mirror) == (0.01, 2, 0.999, 0.5)
