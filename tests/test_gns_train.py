import json
import os
import socket
from dataclasses import replace

import numpy as np
import pytest
import torch
import torch.multiprocessing as mp

from runout.errors import InputError
from runout.gns.checkpoint import load_last_step, load_simulator, read_checkpoint
from runout.gns.rollout import rollout_trajectory
from runout.gns.schema import NetworkConfig
from runout.metrics import compare, final_displacement
from runout.train import TrainConfig, learning_rate, train
from runout.trajectory import trajectory_from_features
from test_gns_synthetic import BOUNDS, FRAME_DT, falling_block, write_dataset

torch.set_num_threads(1)  # tiny graphs: extra threads only add OpenMP synchronisation cost

TINY = NetworkConfig(latent=16, hidden=16, hidden_layers=2, message_passing_steps=2)


# The plain training of these tests (not the recipe, TrainConfig's defaults): one-step, noisy
# windows at rest, no onset draws, no weight average, no mirror, no overburden input, a fast
# learning rate; each test adds what it tests.
PLAIN = dict(lr_init=1e-3, lr_decay_steps=5e6, noise=0.1, exact_rest=False, onset_schedule=(), pushforward=0, ema=0.0,
             overburden=False, mirror=0.0, checkpoint_layers=False)


def config(data, out, **kw) -> TrainConfig:
    settings = dict(network=TINY, log_every=1, save_every=10, valid_every=0, **PLAIN)
    return TrainConfig(data=data, out=out, **{**settings, **kw})


def losses(run) -> list[float]:
    lines = [json.loads(ln) for ln in (run / "log.jsonl").read_text().splitlines()]
    return [r["loss"] for r in lines if "loss" in r]


def test_loss_falls_on_a_tiny_dataset(tmp_path):
    data = write_dataset(tmp_path / "data")
    train(config(data, tmp_path / "run", steps=150, lr_init=3e-3, noise=0.0, rest_windows=False))  # noise sets a floor; the onset windows take longer
    curve = losses(tmp_path / "run")
    assert np.mean(curve[-20:]) < 0.3 * np.mean(curve[:20])


def test_a_stopped_run_resumes_exactly_as_if_never_stopped(tmp_path):
    data = write_dataset(tmp_path / "data")
    whole = train(config(data, tmp_path / "whole", steps=30, checkpoint_layers=True))
    train(config(data, tmp_path / "broken", steps=20, checkpoint_layers=True))
    with open(tmp_path / "broken" / "log.jsonl", "a") as log:  # lines a killed run wrote after its checkpoint
        log.write(json.dumps({"step": 21, "loss": -1.0}) + "\n")
    resumed = train(config(data, tmp_path / "broken", steps=30, resume=True, checkpoint_layers=True))
    assert losses(tmp_path / "broken") == losses(tmp_path / "whole")
    for a, b in zip(whole.state_dict().values(), resumed.state_dict().values()):
        assert torch.equal(a, b)


def test_a_chunk_out_of_time_saves_its_last_step_and_resumes_exactly(tmp_path):
    data = write_dataset(tmp_path / "data")
    whole = train(config(data, tmp_path / "whole", steps=12))
    train(config(data, tmp_path / "chunk", steps=12, max_hours=1e-9))  # the limit passes during step 1
    from runout.gns.checkpoint import read_checkpoint

    assert read_checkpoint(tmp_path / "chunk" / "checkpoint.pt")["step"] == 1
    resumed = train(config(data, tmp_path / "chunk", steps=12, resume=True))
    assert losses(tmp_path / "chunk") == losses(tmp_path / "whole")
    walls = [json.loads(ln)["wall_s"] for ln in (tmp_path / "chunk" / "log.jsonl").read_text().splitlines()]
    assert walls == sorted(walls)  # wall time counts on across chunks (CPU-hours of a campaign)
    for a, b in zip(whole.state_dict().values(), resumed.state_dict().values()):
        assert torch.equal(a, b)


def test_the_weight_average_is_the_saved_model_and_resumes_exactly(tmp_path):
    """--ema d: the checkpoint's model is avg <- d avg + (1 - d) w over the steps, the training
    itself is that of a run without it, and a broken run resumes both exactly."""
    data = write_dataset(tmp_path / "data")
    start = train(config(data, tmp_path / "start", steps=1, lr_init=1e-12))  # the initial weights, to 1e-11
    one = train(config(data, tmp_path / "one", steps=1))
    averaged = train(config(data, tmp_path / "avg1", steps=1, ema=0.75))
    for name, w in averaged.named_parameters():
        expected = 0.75 * dict(start.named_parameters())[name] + 0.25 * dict(one.named_parameters())[name]
        assert torch.allclose(w, expected, atol=1e-7), name
    plain = train(config(data, tmp_path / "plain", steps=12))
    whole = train(config(data, tmp_path / "whole", steps=12, ema=0.9))
    train(config(data, tmp_path / "broken", steps=5, ema=0.9))
    resumed = train(config(data, tmp_path / "broken", steps=12, ema=0.9, resume=True))
    ckpt = read_checkpoint(tmp_path / "whole" / "checkpoint.pt")
    assert losses(tmp_path / "whole") == losses(tmp_path / "plain") == losses(tmp_path / "broken")
    for (name, w), a, r, last in zip(plain.state_dict().items(), whole.state_dict().values(),
                                     resumed.state_dict().values(), ckpt["train_model"].values()):
        assert torch.equal(w, last), name  # the average does not change the training
        assert torch.equal(a, r), name  # resumed exactly
        assert torch.equal(a, ckpt["model"][name]) and torch.equal(a, load_simulator(tmp_path / "whole" / "checkpoint.pt").state_dict()[name])
    assert any(not torch.equal(a, w) for a, w in zip(whole.parameters(), plain.parameters()))


def test_snapshots_keep_the_checkpoint_of_every_nth_step_also_across_a_resume(tmp_path):
    """--keep-every N: snapshots/step-K.pt is the checkpoint as saved at step K, for K = N, 2N, ..."""
    data = write_dataset(tmp_path / "data")
    run = tmp_path / "run"
    train(config(data, run, steps=5, save_every=3, keep_every=4))  # a snapshot also saves the checkpoint
    train(config(data, run, steps=9, save_every=3, keep_every=4, resume=True))
    assert sorted(p.name for p in (run / "snapshots").iterdir()) == ["step-4.pt", "step-8.pt"]
    whole = tmp_path / "whole"
    train(config(data, whole, steps=8, save_every=4))
    kept, last = read_checkpoint(run / "snapshots" / "step-8.pt"), read_checkpoint(whole / "checkpoint.pt")
    assert kept["step"] == 8 and read_checkpoint(run / "snapshots" / "step-4.pt")["step"] == 4
    for name, w in last["model"].items():
        assert torch.equal(kept["model"][name], w), name  # the resumed run's step 8 is the unbroken run's
    assert read_checkpoint(run / "checkpoint.pt")["step"] == 9


def test_a_compiled_network_trains_as_the_eager_one_and_saves_the_same_checkpoint(tmp_path):
    data = write_dataset(tmp_path / "data")
    eager = train(config(data, tmp_path / "eager", steps=3))
    train(config(data, tmp_path / "compiled", steps=3, compile=True))
    assert np.allclose(losses(tmp_path / "compiled"), losses(tmp_path / "eager"), rtol=1e-4)
    saved = read_checkpoint(tmp_path / "compiled" / "checkpoint.pt")["model"]
    assert list(saved) == list(eager.state_dict())  # no _orig_mod: any command loads it
    for name, w in eager.state_dict().items():
        assert torch.allclose(saved[name], w, atol=1e-6), name


def test_the_last_step_weights_load_beside_the_average(tmp_path):
    data = write_dataset(tmp_path / "data")
    train(config(data, tmp_path / "avg", steps=3, ema=0.9))
    train(config(data, tmp_path / "plain", steps=3))
    last = load_last_step(tmp_path / "avg" / "checkpoint.pt")
    saved = read_checkpoint(tmp_path / "avg" / "checkpoint.pt")["train_model"]
    assert all(torch.equal(w, saved[name]) for name, w in last.state_dict().items())
    assert load_last_step(tmp_path / "plain" / "checkpoint.pt") is None


def test_resuming_last_step_weights_of_another_shape_is_refused_in_one_sentence(tmp_path):
    data = write_dataset(tmp_path / "data")
    train(config(data, tmp_path / "run", steps=2, ema=0.9))
    path = tmp_path / "run" / "checkpoint.pt"
    ckpt = torch.load(path, weights_only=True)
    name = next(iter(ckpt["train_model"]))
    ckpt["train_model"][name] = torch.zeros(3, 3, 3)
    torch.save(ckpt, path)
    with pytest.raises(InputError, match=rf"train_model\['{name}'\] is a float32 tensor of shape \(3, 3, 3\)"):
        train(config(data, tmp_path / "run", steps=4, ema=0.9, resume=True))


def test_a_hook_sees_every_step_and_can_end_the_run_saved_and_resumable(tmp_path):
    data = write_dataset(tmp_path / "data")
    seen = []

    def hook(trainer):
        seen.append((trainer.done, trainer.lr))
        if trainer.done == 4:
            trainer.stop_reason = "the test's hook stopped it"

    cfg = config(data, tmp_path / "cut", steps=7, save_every=100)
    train(cfg, hooks=(hook,))
    assert [done for done, _ in seen] == [1, 2, 3, 4]
    assert [lr for _, lr in seen] == [learning_rate(step, cfg) for step in range(4)]
    assert read_checkpoint(tmp_path / "cut" / "checkpoint.pt")["step"] == 4
    resumed = train(replace(cfg, resume=True))
    whole = train(config(data, tmp_path / "whole", steps=7, save_every=100))
    assert losses(tmp_path / "cut") == losses(tmp_path / "whole")
    assert all(torch.equal(a, b) for a, b in zip(whole.state_dict().values(), resumed.state_dict().values()))


def test_fine_tuning_trains_with_the_noise_asked_for_in_units_of_the_datas_velocity_std(tmp_path):
    data = write_dataset(tmp_path / "data")
    train(config(data, tmp_path / "base", steps=2, noise=0.1))
    train(config(data, tmp_path / "tuned", steps=1, noise=0.5, init=tmp_path / "base" / "checkpoint.pt"))
    base, tuned = (read_checkpoint(tmp_path / run / "checkpoint.pt") for run in ("base", "tuned"))
    assert tuned["stats"]["noise_std"] == pytest.approx(5 * base["stats"]["noise_std"])
    # the scales follow the new noise (the weights absorb the change: tests/test_gns_model.py)
    acc_std = torch.tensor(tuned["stats"]["acc_std"], dtype=torch.float64)
    expected = (acc_std.square() + tuned["stats"]["noise_std"] ** 2).sqrt()
    torch.testing.assert_close(tuned["model"]["acc_scale"].double(), expected, rtol=1e-6, atol=0)
    assert not torch.allclose(tuned["model"]["acc_scale"], base["model"]["acc_scale"])


def test_the_connectivity_radius_can_be_chosen_for_a_new_run(tmp_path):
    data = write_dataset(tmp_path / "data")
    model = train(config(data, tmp_path / "run", steps=1, radius=0.123))
    assert model.radius == pytest.approx(0.123)
    assert load_simulator(tmp_path / "run" / "checkpoint.pt").radius == pytest.approx(0.123)


def test_a_new_run_refuses_to_overwrite_a_checkpoint(tmp_path):
    data = write_dataset(tmp_path / "data")
    train(config(data, tmp_path / "run", steps=2, save_every=1))
    with pytest.raises(InputError, match="pass --resume"):
        train(config(data, tmp_path / "run", steps=4))


def test_resuming_against_data_of_another_schema_names_the_difference(tmp_path):
    train(config(write_dataset(tmp_path / "friction"), tmp_path / "run", steps=2))
    cohesive = write_dataset(tmp_path / "cohesive", width=2)
    with pytest.raises(InputError, match=r"material_features is \[tan_phi\] in the model but \[tan_phi, c_over_100kPa\]"):
        train(config(cohesive, tmp_path / "run", steps=4, resume=True))


def test_a_run_resumed_on_other_data_measures_its_training_ranges_again(tmp_path, capsys):
    first = write_dataset(tmp_path / "first")
    train(config(first, tmp_path / "run", steps=2))
    train(config(first, tmp_path / "run", steps=3, resume=True))
    assert "measured again" not in capsys.readouterr().err  # the same data: the record stands
    assert "first" in read_checkpoint(tmp_path / "run" / "checkpoint.pt")["data_ranges"]["source"]
    other = write_dataset(tmp_path / "other", n_train=2)
    train(config(other, tmp_path / "run", steps=4, resume=True))
    assert f"was trained on {first}; its training ranges are measured again over --data {other}" in capsys.readouterr().err
    assert "other" in read_checkpoint(tmp_path / "run" / "checkpoint.pt")["data_ranges"]["source"]


def test_fine_tuning_on_cohesive_data_starts_from_the_base_predictions(tmp_path):
    base_run = tmp_path / "base"
    train(config(write_dataset(tmp_path / "friction"), base_run, steps=20))
    cohesive = write_dataset(tmp_path / "cohesive", width=2)
    tuned = train(config(cohesive, tmp_path / "tuned", steps=1, init=base_run / "checkpoint.pt", lr_init=0.0, lr_final=0.0))
    base = load_simulator(base_run / "checkpoint.pt")
    assert tuned.schema.material_features == ("tan_phi", "c_over_100kPa")
    positions, ptype, material = falling_block(12, 0.4, cohesion=0.5)
    window = torch.from_numpy(positions[:6]).transpose(0, 1)
    bounds = torch.tensor(BOUNDS)
    with torch.no_grad():
        expected = base.next_positions(window, torch.from_numpy(ptype), torch.from_numpy(material[:, :1]), bounds)
        got = tuned.next_positions(window, torch.from_numpy(ptype), torch.from_numpy(material), bounds)
    assert torch.equal(expected, got)
    assert load_simulator(tmp_path / "tuned" / "checkpoint.pt").schema.material_width == 2


def test_a_tiny_model_overfits_one_trajectory_and_rolls_it_out_from_its_first_frames(tmp_path):
    data = write_dataset(tmp_path / "data", frames=24, n_train=1)
    model = train(config(data, tmp_path / "run", steps=500, noise=0.0, lr_init=3e-3, rest_windows=False))
    positions, ptype, material = falling_block(24, *_only_material(data))
    truth = trajectory_from_features(positions, ptype, material, FRAME_DT, BOUNDS)
    fitted = compare(rollout_trajectory(model, truth, 24, stop_speed=None, from_rest=False), truth)
    untrained = train(config(data, tmp_path / "untrained", steps=1, lr_init=0.0, lr_final=0.0))
    baseline = compare(rollout_trajectory(untrained, truth, 24, stop_speed=None, from_rest=False), truth)
    assert fitted["position_mse_mean_m2"] < 0.02 * baseline["position_mse_mean_m2"]
    assert fitted["position_mse_final_m2"] < 0.05  # m^2, for a 3 m fall
    assert abs(fitted["runout_error"]) < 0.02


def _only_material(data):
    from runout.simfiles import read_simulations

    (_, _, material), = read_simulations(data / "train.npz")
    return (float(material[0, 0]),)


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def ddp_worker(rank: int, world: int, port: int, data, out, result_dir, settings=None):
    """One of `world` gloo processes training 6 steps (extra TrainConfig `settings`); its
    final weights go to result_dir/rank{rank}.pt. Shared with tests/test_pushforward.py."""
    os.environ.update(MASTER_ADDR="127.0.0.1", MASTER_PORT=str(port), RANK=str(rank), LOCAL_RANK=str(rank), WORLD_SIZE=str(world))
    torch.set_num_threads(1)
    model = train(config(data, out, steps=6, device="cpu", **(settings or {})))
    torch.save(model.state_dict(), result_dir / f"rank{rank}.pt")


def test_two_gloo_processes_keep_identical_parameters(tmp_path):
    data = write_dataset(tmp_path / "data", n_train=4)
    mp.spawn(ddp_worker, args=(2, free_port(), data, tmp_path / "run", tmp_path), nprocs=2, join=True)
    a, b = (torch.load(tmp_path / f"rank{r}.pt") for r in (0, 1))
    assert all(torch.equal(a[k], b[k]) for k in a)
    saved = load_simulator(tmp_path / "run" / "checkpoint.pt").state_dict()
    assert all(torch.equal(a[k], saved[k]) for k in a)


def test_bf16_on_a_cpu_without_native_bfloat16_trains_in_float32_and_says_so(tmp_path, monkeypatch, capsys):
    """On an AVX2-only CPU bfloat16 matrix products run in a generic kernel, 14x slower than
    float32: --bf16 there would slow training, so it falls back, with one warning."""
    import runout.train as train_module

    data = write_dataset(tmp_path / "data")
    monkeypatch.setattr(train_module, "cpu_has_native_bf16", lambda: False)
    train(config(data, tmp_path / "plain", steps=1, bf16=True))
    assert "no native bfloat16" in "".join(capsys.readouterr())
    assert read_checkpoint(tmp_path / "plain" / "checkpoint.pt")["train"]["bf16"] is False
    monkeypatch.setattr(train_module, "cpu_has_native_bf16", lambda: True)
    train(config(data, tmp_path / "native", steps=1, bf16=True))
    assert "no native bfloat16" not in "".join(capsys.readouterr())
    assert read_checkpoint(tmp_path / "native" / "checkpoint.pt")["train"]["bf16"] is True


def test_a_tiny_model_learns_to_start_from_rest_and_beats_standing_still(tmp_path):
    """The way users run it: the window is frame 0 repeated (the scene at rest). A model that
    never saw such windows, or learns nothing, stays put here (issue: the GNS must learn what
    users ask of it)."""
    data = write_dataset(tmp_path / "data", frames=24, n_train=1)
    model = train(config(data, tmp_path / "run", steps=800, noise=0.05, lr_init=3e-3, lr_final=3e-4, lr_decay_steps=800))
    positions, ptype, material = falling_block(24, *_only_material(data))
    truth = trajectory_from_features(positions, ptype, material, FRAME_DT, BOUNDS)
    predicted = rollout_trajectory(model, truth, 24, stop_speed=None)  # from rest, the default
    assert predicted.n_frames == 24 and np.array_equal(predicted.positions[0], truth.positions[0])
    still = replace(truth, positions=np.repeat(truth.positions[:1], 24, axis=0))
    moved, fell = final_displacement(predicted).mean(), final_displacement(truth).mean()  # m; the truth falls 3 m
    assert 0.8 * fell < moved < 1.2 * fell
    assert compare(predicted, truth)["position_mse_mean_m2"] < 0.1 * compare(still, truth)["position_mse_mean_m2"]


def test_the_overburden_input_is_chosen_by_new_runs_only(tmp_path):
    """--overburden (a new run's default) makes the new model's node encoder one column wider
    and the checkpoint says so; a run resumed or fine-tuned from it keeps it, and asking to drop
    (or add) it there is a one-sentence InputError."""
    data = write_dataset(tmp_path / "data")
    deep = train(config(data, tmp_path / "deep", steps=2, overburden=None))
    assert deep.schema.overburden and read_checkpoint(tmp_path / "deep" / "checkpoint.pt")["schema"]["overburden"]
    assert train(config(data, tmp_path / "deep", steps=3, resume=True, overburden=None)).schema.overburden
    with pytest.raises(InputError, match=r"deep/checkpoint.pt has the overburden input, so it trains only with it"):
        train(config(data, tmp_path / "deep", steps=4, resume=True, overburden=False))
    plain = train(config(data, tmp_path / "plain", steps=2))
    assert not plain.schema.overburden
    with pytest.raises(InputError, match=r"plain/checkpoint.pt has no overburden input, so it trains only without it"):
        train(config(data, tmp_path / "tuned", steps=2, init=tmp_path / "plain" / "checkpoint.pt", overburden=True))


def test_the_best_validated_weights_carry_the_runs_settings_and_start_a_fine_tune_at_their_step(tmp_path):
    data = write_dataset(tmp_path / "friction")
    train(config(data, tmp_path / "base", steps=12, valid_every=6, lr_decay_steps=100.0))
    best = read_checkpoint(tmp_path / "base" / "best.pt")
    assert best["step"] in (6, 12)
    assert best["train"]["lr_decay_steps"] == 100.0 and best["train"]["steps"] == 12  # the run's settings, for provenance
    assert "optimizer" not in best  # weights only: a start for --init, not a run to resume
    train(config(write_dataset(tmp_path / "cohesive", width=2), tmp_path / "tuned", steps=1,
                 init=tmp_path / "base" / "best.pt", lr_decay_steps=100.0))
    tuned = read_checkpoint(tmp_path / "tuned" / "checkpoint.pt")
    assert tuned["train"]["lr_step_offset"] == best["step"]  # the learning rate goes on from the best step's
