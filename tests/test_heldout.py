"""The held-out score that judges pilots and chunks: a perfect prediction scores 0 and
standing still scores each travelling front as its whole travel."""

import numpy as np
import pytest

from runout.evaluate.heldout import score, standing_still
from runout.trajectory import trajectory_from_features
from test_gns_synthetic import BOUNDS, FRAME_DT, falling_block


def truth():
    return trajectory_from_features(*falling_block(30, 0.2), FRAME_DT, BOUNDS)


def test_the_truth_scores_zero_and_standing_still_scores_the_whole_travel():
    t = truth()
    perfect = score([t], [t], spacing=0.5)
    assert perfect["position_error_m"] == 0.0 and perfect["front_error"] == 0.0 and perfect["runout_error"] == 0.0
    still = score([standing_still(t)], [t], spacing=0.5)
    assert still["fronts_scored"] == 2 and still["front_error"] == pytest.approx(1.0)
    assert still["displacement_m"] == 0.0 and still["displacement_mpm_m"] > 2.0  # the block falls about 3 m
    soil = t.soil
    expected = np.linalg.norm(t.positions[:, soil] - t.positions[:1, soil], axis=-1).mean()
    assert still["position_error_m"] == pytest.approx(expected, rel=1e-6)


def test_fronts_that_barely_move_are_not_scored():
    t = truth()
    assert score([standing_still(t)], [t], spacing=10.0)["fronts_scored"] == 0  # the sides spread < 10 m


def test_the_scores_are_also_averaged_by_family_and_by_start(tmp_path):
    from runout.dataset import read_metadata
    from runout.evaluate.heldout import evaluate_heldout
    from runout.gns.engine import GnsEngine
    from runout.simfiles import read_simulations, write_metadata, write_simulations
    from runout.train import TrainConfig, train
    from test_gns_train import TINY
    from test_gns_synthetic import write_dataset

    data = write_dataset(tmp_path / "data", n_valid=3)
    sims = read_simulations(data / "valid.npz")
    positions, ptype, material = sims[2]
    thrown = positions.copy()
    thrown[:, ptype == 6, 0] += 0.5 * np.arange(len(positions))[:, None]  # 0.5 m per frame: soil thrown sideways at frame 0
    write_simulations(data / "valid.npz", [sims[0], sims[1], (thrown, ptype, material)])
    meta = read_metadata(data)
    meta.update(scene_families=["b", "c", "c", "a", "a", "d", "c"], splits={"train": [0, 1, 3], "valid": [4, 2, 6]})
    write_metadata(data / "metadata.json", meta)
    model = train(TrainConfig(data=data, out=tmp_path / "run", steps=1, network=TINY, valid_every=0, checkpoint_layers=False))

    result = evaluate_heldout(GnsEngine(model), data, "valid", count=3)
    kinds = result["by_kind"]
    assert set(kinds) == {"family a", "family c", "starts at rest", "starts thrown"}
    assert kinds["family c"]["model"]["scenes"] == 2 and kinds["family a"]["model"]["scenes"] == 1
    assert kinds["starts thrown"]["model"]["scenes"] == 1 and kinds["starts at rest"]["model"]["scenes"] == 2
    scenes = result["model"]["per_scene"]
    assert kinds["family a"]["model"]["position_error_m"] == pytest.approx(scenes[0]["position_error_m"])
    assert kinds["starts thrown"]["standing_still"]["position_error_m"] == pytest.approx(result["standing_still"]["per_scene"][2]["position_error_m"])
    assert kinds["family c"]["model"]["displacement_mpm_m"] == pytest.approx(
        (scenes[1]["displacement_mpm_m"] + scenes[2]["displacement_mpm_m"]) / 2)


def test_the_command_scores_any_learned_engines_file_and_writes_metrics(tmp_path, capsys):
    import json

    from runout.cli import main
    from runout.train import TrainConfig, train
    from test_cli_exits import run
    from test_gns_train import TINY
    from test_gns_synthetic import write_dataset

    data = write_dataset(tmp_path / "data", n_valid=2)
    train(TrainConfig(data=data, out=tmp_path / "run", steps=2, network=TINY, valid_every=0, log_every=1,
                      checkpoint_layers=False, progress=False))
    out = tmp_path / "eval"
    main([str(a) for a in ["evaluate", "heldout", tmp_path / "run" / "checkpoint.pt", "--data", data, "--split", "valid",
                           "--limit", "2", "--mirrored", "--no-column", "--log", tmp_path / "run" / "log.jsonl", "--out", out]])
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["valid_split"]["model"]["scenes"] == 2 and "valid_split_mirrored" in metrics
    assert metrics["curves"]["last_step"] == 2 and (out / "curves.png").is_file()
    captured = capsys.readouterr()
    printed = captured.out
    assert "held-out rollouts from rest" in captured.err  # a bar over the scenes by default
    assert "2 valid scenes from rest: position error" in printed and "2 valid scenes mirrored from rest" in printed
    assert "(standing still" in printed
    main([str(a) for a in ["evaluate", "heldout", tmp_path / "run" / "checkpoint.pt", "--data", data, "--split", "valid",
                           "--limit", "1", "--no-column", "--no-progress", "--force", "--out", out]])
    assert "held-out rollouts" not in capsys.readouterr().err
    code, err = run(["evaluate", "heldout", tmp_path / "run" / "checkpoint.pt", "--data", data, "--out", out], capsys)
    assert code == 2 and "test.npz" in err  # the default split is test, which this dataset lacks
