"""runout installed like a package: the wheel carries the shipped model and the example scenes,
and an installed runout finds them from a folder outside the checkout; `runout --version`;
every file in models/ small enough to ship."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

import runout

REPO = Path(__file__).resolve().parents[1]
MB = 1024**2


def test_every_model_file_is_below_16_mb():
    files = sorted((REPO / "models").glob("*.pt"))
    assert REPO / "models" / "slope.pt" in files
    for path in files:
        assert path.stat().st_size < 16 * MB, f"{path.name} is {path.stat().st_size / MB:.1f} MB"


def test_version_is_printed_and_is_the_package_s(tmp_path):
    result = subprocess.run([sys.executable, "-m", "runout", "--version"], capture_output=True, text=True,
                            cwd=tmp_path, env=_env(REPO / "src"))
    assert result.returncode == 0 and result.stdout == f"runout {runout.__version__}\n" and result.stderr == ""
    changelog = (REPO / "CHANGELOG.md").read_text()
    assert f"## {runout.__version__} " in changelog  # the version's entry in the changelog


def _env(first_on_path: Path) -> dict:
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "RUNOUT_MODELS")}
    return env | {"PYTHONPATH": str(first_on_path), "OMP_NUM_THREADS": "1"}


def _source_copy(folder: Path) -> Path:
    """What `pip install .` reads from the checkout: the project files, src/ (runout/models is
    a link to models/) and the files models/ ships."""
    for name in ("pyproject.toml", "README.md", "LICENSE"):
        shutil.copy(REPO / name, folder / name)
    shutil.copytree(REPO / "src", folder / "src", symlinks=True,
                    ignore=shutil.ignore_patterns("__pycache__", "*.egg-info"))
    (folder / "models").mkdir()
    for name in ("slope.pt", "neural-mpm.pt", "README.md"):
        shutil.copy(REPO / "models" / name, folder / "models" / name)
    return folder


def test_the_installed_wheel_runs_the_demo_from_outside_the_checkout(tmp_path):
    pytest.importorskip("setuptools", reason="building the wheel offline needs setuptools (the test extra)")
    (tmp_path / "checkout").mkdir()
    source = _source_copy(tmp_path / "checkout")  # no models/ beside or above the installed package
    wheels, site, elsewhere = tmp_path / "wheels", tmp_path / "env" / "lib" / "site", tmp_path / "elsewhere"
    pip = [sys.executable, "-m", "pip", "--disable-pip-version-check", "-q"]
    subprocess.run([*pip, "wheel", "--no-deps", "--no-build-isolation", "-w", str(wheels), str(source)], check=True,
                   cwd=tmp_path, capture_output=True)
    (wheel,) = wheels.glob("runout-*.whl")
    subprocess.run([*pip, "install", "--no-deps", "--target", str(site), str(wheel)], check=True, capture_output=True)
    installed = site / "runout"
    for name in ("slope.pt", "neural-mpm.pt"):
        assert (installed / "models" / name).stat().st_size == (REPO / "models" / name).stat().st_size
    assert (installed / "examples" / "four_layer_slope.toml").is_file()
    assert not (installed / "models" / "slope-train.pt").exists()  # resume files stay in the checkout
    assert not (installed / "models" / "neural-mpm-train.pt").exists()

    elsewhere.mkdir()
    result = subprocess.run([sys.executable, "-m", "runout", "demo", "--out", "d", "--quick"], capture_output=True,
                            text=True, cwd=elsewhere, env=_env(site))
    assert result.returncode == 0, result.stderr
    assert f"neural MPM in {installed / 'models' / 'neural-mpm.pt'}" in result.stdout  # the installed copy, not the checkout's
    assert (elsewhere / "d" / "1_slope_mpm" / "slope.png").stat().st_size > 0
    assert (elsewhere / "d" / "3_slope_learned" / "final.png").stat().st_size > 0
    assert result.stderr == ""  # quiet: no CUDA-driver warning from Warp, no library warnings
