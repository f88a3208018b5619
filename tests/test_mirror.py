"""Left-right mirroring: training windows reflected about the domain's centre (--mirror) and
held-out scenes scored reflected (evaluate_heldout mirrored=True). The physics has no side: the
MPM's run of a mirrored scene is the mirror of its run of the scene, which is what makes a
reflected window a true training sample."""

import numpy as np
import pytest
import torch

from runout.gns.windows import TrainingBatch, mirrored
from runout.mpm import simulate
from runout.simfiles import read_simulations, write_simulations
from runout.train import TrainConfig, train
from runout.trajectory import trajectory_from_features
from test_gns_synthetic import BOUNDS, FRAME_DT, falling_block, write_dataset
from test_gns_train import config, losses
from test_mpm_physics import make_scene


def batch_of(graphs: int, points: int = 5) -> TrainingBatch:
    g = torch.Generator().manual_seed(1)
    n = graphs * points
    return TrainingBatch(
        window=60.0 * torch.rand(n, 6, 2, generator=g), future=60.0 * torch.rand(n, 3, 2, generator=g),
        particle_type=torch.full((n,), 6), material=torch.rand(n, 2, generator=g),
        graph=torch.arange(graphs).repeat_interleave(points),
    )


def test_a_mirrored_window_is_reflected_about_the_domain_centre_whole_graphs_at_a_time():
    batch = batch_of(200)
    assert mirrored(batch, (0.0, 60.0), 0.0, torch.Generator()) is batch
    every = mirrored(batch, torch.tensor([0.0, 60.0]), 1.0, torch.Generator().manual_seed(0))
    for name in ("window", "future"):
        before, after = getattr(batch, name), getattr(every, name)
        assert torch.allclose(after[..., 0], 60.0 - before[..., 0]) and torch.equal(after[..., 1], before[..., 1])
    assert torch.equal(every.material, batch.material) and torch.equal(every.particle_type, batch.particle_type)
    half = mirrored(batch, (0.0, 60.0), 0.5, torch.Generator().manual_seed(0))
    flipped = ~torch.isclose(half.window[:, 0, 0], batch.window[:, 0, 0])
    per_graph = flipped.view(200, 5)
    assert (per_graph.all(dim=1) | ~per_graph.any(dim=1)).all(), "a graph is reflected whole or not at all"
    assert 70 <= int(per_graph[:, 0].sum()) <= 130, "about half of the graphs are reflected"


def test_the_mpm_run_of_a_mirrored_slope_is_the_mirror_of_its_run():
    """A right-facing slope and the same slope facing left: the reference for --mirror. Their
    MPM deposits are each other's reflections to within 0.5 m, while the slope moves tens of m."""
    mats = {"soil": {"friction_angle": 20.0, "cohesion": 5.0}}
    right = [(0, 0), (121, 0), (61, 41), (0, 41)]  # faces miss the point lattice
    left = [(200.0 - x, y) for x, y in reversed(right)]
    a, b = simulate([make_scene([("soil", right)], mats, frames=200), make_scene([("soil", left)], mats, frames=200)],
                    progress=False)
    reflected = a.mirrored()
    key = {(round(x, 3), round(y, 3)): k for k, (x, y) in enumerate(b.positions[0])}
    partner = np.array([key[(round(x, 3), round(y, 3))] for x, y in reflected.positions[0]])
    gap = np.abs(reflected.positions[-1] - b.positions[-1, partner]).max()
    travel = np.abs(a.positions[-1, :, 0] - a.positions[0, :, 0]).max()
    assert travel > 20.0, "the slope must fail for the test to mean something"
    assert gap < 0.5, f"the mirrored slope's deposit is {gap:.2f} m from the mirror of the slope's"


def test_a_trajectory_mirrored_twice_is_itself_and_its_start_velocity_turns():
    t = trajectory_from_features(*falling_block(10, 0.3), FRAME_DT, BOUNDS)
    t.initial_velocity = np.tile([[2.0, -1.0]], (t.n_points, 1))
    m = t.mirrored()
    assert np.allclose(m.positions[..., 0], 60.0 - t.positions[..., 0]) and np.array_equal(m.positions[..., 1], t.positions[..., 1])
    assert np.array_equal(m.start_velocity(), np.tile([[-2.0, -1.0]], (t.n_points, 1)))
    assert np.allclose(m.mirrored().positions, t.positions) and np.array_equal(m.mirrored().start_velocity(), t.start_velocity())


def test_training_with_every_window_mirrored_is_training_on_the_mirrored_data(tmp_path):
    """--mirror 1 on a dataset takes the same steps as --mirror 0 on the dataset reflected in
    its file: the reflection reaches the network's inputs and targets, nothing else."""
    data = write_dataset(tmp_path / "data")
    flipped = write_dataset(tmp_path / "flipped")
    sims = read_simulations(data / "train.npz")
    reflect = lambda p: np.stack([np.float32(60.0) - p[..., 0], p[..., 1]], axis=-1)  # noqa: E731
    write_simulations(flipped / "train.npz", [(reflect(p), t, m) for p, t, m in sims])
    train(config(data, tmp_path / "mirror", steps=8, mirror=1.0))
    train(config(flipped, tmp_path / "plain", steps=8))
    assert losses(tmp_path / "mirror") == pytest.approx(losses(tmp_path / "plain"), rel=1e-5)
    train(config(data, tmp_path / "unmirrored", steps=8))
    assert losses(tmp_path / "unmirrored") != pytest.approx(losses(tmp_path / "mirror"), rel=1e-5)


def test_mirror_share_outside_zero_to_one_is_refused_in_one_sentence(tmp_path):
    from runout.errors import InputError
    from runout.train import check_settings

    with pytest.raises(InputError, match="mirror"):
        check_settings(TrainConfig(data=tmp_path, out=tmp_path / "run", mirror=1.5))


def test_held_out_scenes_are_scored_mirrored_on_request(tmp_path):
    """Standing still scores a scene and its mirror alike (the score has no side); the scenes
    rolled out and scored are the reflected ones."""
    from runout.evaluate.heldout import evaluate_heldout
    from runout.gns.engine import GnsEngine

    data = write_dataset(tmp_path / "data", n_valid=2)
    model = GnsEngine(train(config(data, tmp_path / "run", steps=1)))
    plain = evaluate_heldout(model, data, "valid", count=2)
    reflected = evaluate_heldout(model, data, "valid", count=2, mirrored=True)
    assert reflected["standing_still"]["position_error_m"] == pytest.approx(plain["standing_still"]["position_error_m"], rel=1e-5)
    assert reflected["model"]["displacement_mpm_m"] == pytest.approx(plain["model"]["displacement_mpm_m"], rel=1e-5)
    assert all(s["name"].endswith("mirrored") for s in reflected["model"]["per_scene"])
