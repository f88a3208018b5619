"""`runout average`: the mean of one run's checkpoints, loadable as a model."""

from pathlib import Path

import torch

from runout.gns.checkpoint import load_simulator, save_checkpoint
from runout.gns.schema import FeatureSchema
from runout.gns.schema import NetworkConfig
from runout.gns.simulator import GraphNetworkSimulator, Normalisation
from test_cli_exits import one_sentence, run

TINY = NetworkConfig(latent=8, hidden=8, hidden_layers=1, message_passing_steps=1)
STATS = Normalisation((0.0, -0.01), (0.02, 0.03), (0.0, -1e-3), (2e-3, 3e-3), 2.5e-3)


def _checkpoint(path: Path, seed: int, radius: float = 4.6, step: int = 100) -> Path:
    torch.manual_seed(seed)
    simulator = GraphNetworkSimulator(FeatureSchema(material_features=("tan_phi",)), STATS, radius, TINY)
    return save_checkpoint(path, simulator, step=step)


def test_the_average_is_the_parameterwise_mean_and_loads_as_a_model(tmp_path, capsys):
    paths = [_checkpoint(tmp_path / f"s{k}.pt", seed=k, step=100 * (k + 1)) for k in range(3)]
    out = tmp_path / "mean.pt"
    code, err = run(["average", *paths, "--out", out], capsys)
    assert code == 0, err
    mean = load_simulator(out)
    models = [load_simulator(p) for p in paths]
    for name, value in mean.state_dict().items():
        expected = sum(m.state_dict()[name] for m in models) / 3
        torch.testing.assert_close(value, expected, rtol=1e-6, atol=1e-7)
    # not a copy of one input: the seeds give different weights
    assert not torch.equal(mean.state_dict()[name], models[0].state_dict()[name])
    assert torch.load(out, weights_only=True)["step"] == 300  # the last input's step


def test_checkpoints_of_different_runs_or_a_single_one_are_refused_with_exit_2(tmp_path, capsys):
    a = _checkpoint(tmp_path / "a.pt", seed=0)
    b = _checkpoint(tmp_path / "b.pt", seed=1, radius=9.2)
    out = tmp_path / "out.pt"
    code, err = run(["average", a, b, "--out", out], capsys)
    assert code == 2 and one_sentence(err) and "'radius' differs" in err, err
    code, err = run(["average", a, "--out", out], capsys)
    assert code == 2 and one_sentence(err) and "at least 2" in err, err
    code, err = run(["average", a, a, "--out", a], capsys)
    assert code == 2 and one_sentence(err) and "one of the inputs" in err, err
    assert not out.exists()
