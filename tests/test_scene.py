"""Scene files: round trip, point filling, and one clear sentence for every kind of bad input."""

from __future__ import annotations

import copy
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from runout.cli.app import app
from runout.errors import InputError
from runout.scene import fill_points, load_scene, save_scene, scene_from_dict, scene_to_toml

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"

GOOD = {
    "domain": {"width": 100.0, "height": 60.0},
    "materials": {"sand": {"friction_angle": 30.0, "cohesion": 5.0}, "rock": {"model": "elastic"}},
    "regions": [
        {"material": "rock", "polygon": [[0, 0], [100, 0], [100, 8], [0, 8]], "fixed": True},
        {"material": "sand", "polygon": [[0, 8], [60, 8], [20, 40], [0, 40]]},
    ],
}


def bad(**edits):
    """GOOD with edits given as path=value, path like 'materials.sand.cohesion'."""
    data = copy.deepcopy(GOOD)
    for path, value in edits.items():
        keys = path.split("__")
        target = data
        for k in keys[:-1]:
            target = target[int(k)] if k.isdigit() else target[k]
        last = keys[-1]
        if value is DELETE:
            del target[int(last) if last.isdigit() else last]
        else:
            target[int(last) if last.isdigit() else last] = value
    return data


DELETE = object()


def test_examples_load_and_fill():
    for path in sorted(EXAMPLES.glob("*.toml")):
        text = path.read_text()
        if "[domain]" not in text:
            continue  # inverse specs live here too
        scene = load_scene(path)
        assert len(fill_points(scene)) > 100, path.name


def test_flip_defaults_to_wave_and_round_trips(tmp_path):
    """The FLIP share is "wave" (a fixed rate in time) unless a scene gives a number."""
    scene = scene_from_dict(GOOD, "good")
    assert scene.time.flip == "wave"
    apic = scene_from_dict({**GOOD, "time": {"flip": 0.0}}, "apic")
    assert apic.time.flip == 0.0
    save_scene(scene, tmp_path / "s.toml")
    assert load_scene(tmp_path / "s.toml").time.flip == "wave"


def test_toml_round_trip(tmp_path):
    scene = scene_from_dict(GOOD, "good")
    save_scene(scene, tmp_path / "s.toml")
    again = load_scene(tmp_path / "s.toml")
    assert again.regions == scene.regions and again.materials == scene.materials
    assert again.domain == scene.domain and again.time == scene.time
    assert scene_to_toml(again) == scene_to_toml(scene)


def test_points_fill_regions_on_the_lattice():
    scene = scene_from_dict(GOOD, "good")
    pts = fill_points(scene)
    assert np.allclose((pts.position / 2.0) % 1.0, 0.5)  # (i + 1/2) * 2 m
    rock = pts.fixed
    assert rock.sum() == 50 * 4  # 100 x 8 m at 2 m spacing
    assert (pts.particle_type[rock] == 3).all() and (pts.particle_type[~rock] == 6).all()
    sand_area = 0.5 * (60 + 20) * 32
    assert abs((~rock).sum() * 4.0 - sand_area) / sand_area < 0.05


def test_shared_edge_points_belong_to_one_region():
    data = bad(regions=[
        {"material": "sand", "polygon": [[0, 0], [50, 0], [50, 21], [0, 21]]},
        {"material": "sand", "polygon": [[0, 21], [50, 21], [50, 41], [0, 41]]},
    ])
    pts = fill_points(scene_from_dict(data, "two"))
    assert len(np.unique(pts.position, axis=0)) == len(pts.position)


@pytest.mark.parametrize(
    "edits, words",
    [
        ({"domain__depth": 3.0}, "unknown key 'depth' in [domain]"),
        ({"materials__sand__phi": 3.0}, "unknown key 'phi'"),
        ({"domain__width": DELETE}, "missing the required key 'width'"),
        ({"regions": DELETE}, "no [regions] section"),
        ({"regions__1__material": "clay"}, "'clay' is not defined"),
        ({"regions__1__polygon": [[0, 8], [60, 40], [60, 8], [0, 30]]}, "intersects itself"),
        ({"regions__1__polygon": [[0, 4], [60, 4], [20, 40], [0, 40]]}, "overlap"),
        ({"regions__1__polygon": [[0, 8], [160, 8], [20, 40], [0, 40]]}, "outside the domain"),
        ({"regions__1__polygon": [[10.2, 10.2], [10.8, 10.2], [10.5, 10.8]]}, "too small to hold a single point"),
        ({"regions__1__polygon": [[0, 8], [60, 8]]}, "at least 3 [x, y] pairs"),
        ({"materials__sand__friction_angle": 75.0}, "friction_angle = 75 is outside the allowed range [0, 60]"),
        ({"materials__sand__cohesion": -1.0}, "cohesion = -1 is outside the allowed range [0, 10000] kPa"),
        ({"materials__sand__cohesion": 1e6}, "cohesion = 1e+06 is outside the allowed range [0, 10000] kPa"),
        ({"materials__sand__youngs_modulus": 0.0}, "youngs_modulus = 0 is outside the allowed range (0, 100000] MPa"),
        ({"materials__sand__youngs_modulus": 1e12}, "youngs_modulus = 1e+12 is outside the allowed range (0, 100000] MPa"),
        ({"materials__sand__density": 1e5}, "density = 100000 is outside the allowed range (0, 10000] kg/m3"),
        ({"materials__sand__tension_cutoff": 1e9}, "tension_cutoff = 1e+09 is outside"),
        ({"regions__1__velocity": [1e30, 0.0]}, "velocity = [1e+30, 0] m/s has a speed of 1e+30 m/s, outside the allowed range [0, 100] m/s"),
        ({"regions__1__velocity": [0.0, float("nan")]}, "velocity = [0, nan] m/s has a speed of nan m/s, outside the allowed range [0, 100] m/s"),
        ({"domain__width": 1e9}, "width = 1e+09 is outside the allowed range (0, 20000] m"),
        ({"domain__cell_size": 0.01}, "candidate points, more than the 2e+06 allowed"),
        ({"time": {"frames": 2_000_000}}, "frames = 2e+06 is outside the allowed range [1, 1e+06]"),
        ({"materials__sand__density": -5.0}, "density = -5 is outside"),
        ({"materials__sand__poisson_ratio": 0.5}, "poisson_ratio = 0.5 is outside the allowed range (0, 0.5)"),
        ({"materials__sand__model": "cam-clay"}, "must be 'mohr-coulomb' or 'elastic'"),
        ({"domain__height": -60.0}, "height = -60 is outside"),
        ({"time": {"frames": 0}}, "frames = 0 is outside"),
        ({"time": {"frames": 2.5}}, "frames = 2.5 must be a positive whole number"),
        ({"materials__sand__cohesion": "ten"}, "must be a finite number"),
        ({"domain__base_friction": "smooth"}, "base_friction = 'smooth' must be a number in [0, 10] or \"rough\""),
        ({"domain__base_friction": 11.0}, "base_friction = 11 is outside the allowed range [0, 10]"),
        ({"time": {"flip": "apic"}}, "time.flip = 'apic' must be a number in [0, 1] or \"wave\""),
        ({"time": {"flip": 1.5}}, "flip = 1.5 is outside the allowed range [0, 1]"),
    ],
)
def test_bad_scene_gives_one_clear_sentence(edits, words):
    with pytest.raises(InputError) as err:
        scene_from_dict(bad(**edits), "slope.toml")
    message = str(err.value)
    assert message.startswith("slope.toml: ") and words in message
    assert message.count(". ") == 0 and "\n" not in message


def test_cli_exit_code_2_on_bad_scene(tmp_path):
    path = tmp_path / "broken.toml"
    path.write_text('[domain]\nwidth = 100.0\nheight = 60.0\n[materials.sand]\nfriction_angle = 99.0\n'
                    '[[regions]]\nmaterial = "sand"\npolygon = [[0, 0], [50, 0], [50, 20]]\n')
    from runout.cli import main  # noqa: F401  (the entry point maps InputError to exit 2)
    import subprocess
    import sys

    done = subprocess.run([sys.executable, "-m", "runout", "show", str(path), "--out", str(tmp_path / "x.png")],
                          capture_output=True, text=True)
    assert done.returncode == 2
    assert "friction_angle = 99 is outside the allowed range [0, 60] degrees" in done.stderr
    assert "Traceback" not in done.stderr


def test_show_draws_a_scene(tmp_path):
    result = CliRunner().invoke(app, ["show", str(EXAMPLES / "dam.toml"), "--out", str(tmp_path / "dam.png")])
    assert result.exit_code == 0, result.output
    assert (tmp_path / "dam.png").stat().st_size > 10_000
