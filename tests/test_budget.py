"""The MPM's cost is known before it runs: points and substeps as the solver will use them,
and a one-sentence refusal of what would not fit this machine or would never finish."""

from __future__ import annotations

from pathlib import Path

import pytest

import runout.mpm
from runout.errors import InputError
from runout.mpm import substeps_per_frame
from runout.mpm.budget import GIB, MAX_SUBSTEPS, check_budget, estimate, host_memory
from runout.scene import fill_points, load_scene, save_scene, scene_from_dict
from test_cli_exits import one_sentence, run

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"


def block(width=400.0, height=100.0, cell=4.0, frames=480, youngs=40.0):
    return scene_from_dict({
        "domain": {"width": width, "height": height, "cell_size": cell},
        "time": {"frames": frames},
        "materials": {"sand": {"friction_angle": 30.0, "youngs_modulus": youngs}},
        "regions": [{"material": "sand", "polygon": [[0, 0], [width, 0], [width, height / 2], [0, height / 2]]}],
    })


def test_the_estimate_counts_the_points_and_substeps_the_solver_will_use():
    scene = load_scene(EXAMPLES / "four_layer_slope.toml")
    e = estimate([scene, scene], frames=100)
    assert e.points == 2 * len(fill_points(scene))
    assert e.substeps_per_frame == substeps_per_frame(scene) and e.frames == 100
    assert 0 < e.device_bytes + e.host_bytes < 2 * GIB  # a paper-size run fits any laptop


def test_a_run_that_needs_more_memory_than_the_machine_is_refused():
    frames = 1_000_000
    scene = block(width=4000.0, height=400.0, frames=frames)
    need = estimate([scene]).host_bytes
    assert need > host_memory()
    with pytest.raises(InputError) as err:
        check_budget([scene], source="big.toml")
    message = str(err.value)
    assert message.startswith("big.toml: the MPM run needs about") and "GiB of memory" in message
    assert f"this machine has {host_memory() / GIB:.1f} GiB" in message and "\n" not in message


def test_a_run_of_endless_substeps_is_refused():
    scene = block(width=40.0, height=20.0, cell=0.5, frames=1_000_000, youngs=1e5)
    assert substeps_per_frame(scene) * 1_000_000 > MAX_SUBSTEPS
    with pytest.raises(InputError, match="substeps .* more than the 1e[+]08 allowed"):
        check_budget([scene], source="stiff.toml")


def test_runout_mpm_refuses_it_before_starting(tmp_path, capsys, monkeypatch):
    calls = []
    monkeypatch.setattr(runout.mpm, "simulate", lambda *a, **k: calls.append(a))
    save_scene(block(width=4000.0, height=400.0, frames=1_000_000), tmp_path / "big.toml")
    code, err = run(["mpm", tmp_path / "big.toml", "--out", tmp_path / "o"], capsys)
    assert code == 2 and "GiB of memory" in err and one_sentence(err)
    assert not calls and not (tmp_path / "o").exists()


def test_frames_from_the_command_line_are_bounded(tmp_path, capsys):
    code, err = run(["mpm", EXAMPLES / "small_dam.toml", "--out", tmp_path / "o", "--frames", "2000000"], capsys)
    assert code == 2 and "frames = 2000000 is outside the allowed range [1, 1000000]" in err


def test_an_ordinary_scene_passes():
    scene = load_scene(EXAMPLES / "dam.toml")
    assert check_budget([scene]).points == len(fill_points(scene))
