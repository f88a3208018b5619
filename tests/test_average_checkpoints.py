"""scripts/average_checkpoints.py: the mean of one run's checkpoints, loadable as a model."""

import importlib.util
from pathlib import Path

import torch

from runout.contract import FeatureSchema
from runout.gns.checkpoint import load_simulator, save_checkpoint
from runout.gns.simulator import NetworkConfig, Normalisation, Simulator

REPO = Path(__file__).resolve().parents[1]
TINY = NetworkConfig(latent=8, hidden=8, hidden_layers=1, message_passing_steps=1)
STATS = Normalisation((0.0, -0.01), (0.02, 0.03), (0.0, -1e-3), (2e-3, 3e-3), 2.5e-3)


def _script():
    spec = importlib.util.spec_from_file_location("average_checkpoints", REPO / "scripts" / "average_checkpoints.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _checkpoint(path: Path, seed: int, radius: float = 4.6, step: int = 100) -> Path:
    torch.manual_seed(seed)
    simulator = Simulator(FeatureSchema(material_features=("tan_phi",)), STATS, radius, TINY)
    return save_checkpoint(path, simulator, step=step)


def test_the_average_is_the_parameterwise_mean_and_loads_as_a_model(tmp_path):
    paths = [_checkpoint(tmp_path / f"s{k}.pt", seed=k, step=100 * (k + 1)) for k in range(3)]
    out = tmp_path / "mean.pt"
    assert _script().main([str(out), *map(str, paths)]) == 0
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
    script = _script()
    assert script.main([str(tmp_path / "out.pt"), str(a), str(b)]) == 2
    assert "'radius' differs" in capsys.readouterr().err
    assert script.main([str(tmp_path / "out.pt"), str(a)]) == 2
    assert "at least 2" in capsys.readouterr().err
    assert not (tmp_path / "out.pt").exists()
