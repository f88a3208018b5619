"""`runout invert --engine mpm-ad`: the MPM's exact gradient, checked against mpm-fd, drives the usual inverse."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

import runout.inverse.mpm_ad as mpm_ad
from runout.errors import InputError
from runout.inverse import invert, load_inverse_spec, load_observation
from runout.inverse.history import HISTORY_JSON
from runout.inverse.mpm_ad import MpmAutodiff
from runout.inverse.mpm_fd import MpmFiniteDifference
from runout.mpm import simulate
from runout.scene import save_scene, scene_from_dict
from runout.trajectory import save_trajectory
from _scenes import COLUMN_BESIDE_BLOCK

# 160 moving points; the truth: c = 5 kPa in the column, phi = 20 degrees in the block
SCENE = COLUMN_BESIDE_BLOCK
PARAMETERS = """
[parameters.column]
c = { initial = 12.0, lower = 0.0, upper = 20.0 }
[parameters.block]
phi = { initial = 25.0, lower = 10.0, upper = 35.0 }
"""


pytestmark = pytest.mark.usefixtures("one_thread")


@pytest.fixture(scope="module")
def folder(tmp_path_factory):
    """Scene file, an MPM target at the truth, and a spec observing frames 6 and 12."""
    folder = tmp_path_factory.mktemp("mpm_ad")
    scene = scene_from_dict(SCENE, "ad")
    save_scene(scene, folder / "scene.toml")
    save_trajectory(simulate([scene], progress=False)[0], folder / "target")
    (folder / "spec.toml").write_text(
        f'scene = "scene.toml"\n[target]\ntrajectory = "target"\nframes = [6, 12]\n{PARAMETERS}\n'
        "[optimiser]\nmax_iterations = 8\n"
    )
    return folder


def test_gradient_agrees_with_mpm_fd(folder):
    """Central differences at a relative step of 0.008. With solver 5 (FLIP share a rate in
    time, relaxation with local damping, whose sign() is non-smooth) the loss has fine-scale
    roughness: at steps 0.0005 / 0.002 / 0.008 the FD gradient's second component was 9.9e-5 /
    8.7e-5 / 8.2e-5 against AD's 8.2e-5, so small steps measure the roughness, not the slope."""
    spec = load_inverse_spec(folder / "spec.toml")
    observation = load_observation(spec)
    values = np.array([12.0, 25.0])
    ad = MpmAutodiff(spec, observation)(values)
    fd = MpmFiniteDifference(spec, observation, step=0.008)(values)
    assert ad.loss == pytest.approx(fd.loss, rel=1e-5)  # the same run (fd records float32)
    assert np.all(np.abs(fd.gradient) > 2e-5)  # m^2 per kPa, per degree
    np.testing.assert_allclose(ad.gradient, fd.gradient, rtol=0.02)
    assert ad.backward_s > 0 and ad.peak_memory_bytes > 0


def test_invert_with_mpm_ad_recovers_both_parameters(folder, tmp_path, capsys):
    lines = []
    result = invert(folder / "spec.toml", tmp_path / "out", engine="mpm-ad", log=lines.append)
    assert result.best.values == pytest.approx([5.0, 20.0], rel=0.02)
    history = json.loads((tmp_path / "out" / HISTORY_JSON).read_text())
    assert all(e["backward_s"] > 0 for e in history["evaluations"])
    assert "backward" in lines[0] and "MB held" in lines[0]
    for name in ("history.csv", "loss.png", "parameters.png", "deposit.png"):
        assert (tmp_path / "out" / name).stat().st_size > 0


def test_a_run_whose_kept_states_do_not_fit_is_refused(folder, monkeypatch):
    monkeypatch.setattr(mpm_ad, "device_memory", lambda device: 1024)
    spec = load_inverse_spec(folder / "spec.toml")
    with pytest.raises(InputError) as caught:
        MpmAutodiff(spec, load_observation(spec))
    message = str(caught.value)
    assert message.startswith(str(folder / "spec.toml")) and "mpm-ad" in message and "points" in message
    assert message.count(". ") == 0 and message.endswith(".")


def test_the_command_refuses_it_with_exit_code_2(folder, tmp_path, monkeypatch, capsys):
    import sys

    from runout.cli import main

    monkeypatch.setattr(mpm_ad, "device_memory", lambda device: 1024)
    monkeypatch.setattr(sys, "argv", ["runout", "invert", str(folder / "spec.toml"), "--engine", "mpm-ad",
                                      "--out", str(tmp_path / "o")])
    with pytest.raises(SystemExit) as exit_info:
        main()
    assert exit_info.value.code == 2
    err = capsys.readouterr().err
    assert "mpm-ad engine keeps" in err and "--engine mpm-fd" in err


def test_mpm_ad_runs_on_the_warp_kernels_and_no_option_selects_the_torch_solver(folder, tmp_path, monkeypatch,
                                                                                  capsys):
    import sys

    from runout.cli import main

    spec = load_inverse_spec(folder / "spec.toml")
    assert MpmAutodiff(spec, load_observation(spec)).model.backend == "warp"
    monkeypatch.setattr(sys, "argv", ["runout", "invert", str(folder / "spec.toml"), "--engine", "mpm-ad", "--compile",
                                      "--out", str(tmp_path / "o")])
    with pytest.raises(SystemExit) as exit_info:
        main()
    assert exit_info.value.code == 2
    assert "--compile" in capsys.readouterr().err
    assert not (tmp_path / "o" / "history.json").exists()
