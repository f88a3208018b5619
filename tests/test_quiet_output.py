"""Quiet on a CPU: Warp's missing-CUDA-driver warning never reaches the user when no GPU is
asked for, other lines Warp writes still do, and `--device cuda` without a GPU keeps its
one-sentence refusal."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
import torch

from runout.mpm import warp_runtime
from _scenes import COLUMN_BESIDE_BLOCK

REPO = Path(__file__).resolve().parents[1]
DRIVER_LINE = b"Warp CUDA warning: Could not find or load the NVIDIA CUDA driver. GPU execution will not be available.\n"


def runout_command(*args: str, cwd: Path) -> subprocess.CompletedProcess:
    env = os.environ | {"PYTHONPATH": str(REPO / "src"), "OMP_NUM_THREADS": "1"}
    return subprocess.run([sys.executable, "-m", "runout", *args], capture_output=True, text=True, cwd=cwd, env=env)


def test_start_warp_drops_the_driver_warning_and_passes_other_lines(monkeypatch, capfd):
    monkeypatch.setattr(warp_runtime, "_started", False)
    monkeypatch.setattr(warp_runtime.wp, "init", lambda: os.write(2, DRIVER_LINE + b"Warp error: something else\n"))
    warp_runtime.start_warp()
    err = capfd.readouterr().err
    assert "CUDA driver" not in err and "Warp error: something else" in err


def test_an_mpm_run_on_the_cpu_prints_no_warning(tmp_path):
    (tmp_path / "scene.json").write_text(json.dumps(COLUMN_BESIDE_BLOCK | {"time": {"frames": 3}}))
    result = runout_command("mpm", "scene.json", "--out", "run", cwd=tmp_path)
    assert result.returncode == 0, result.stderr
    lines = [line for line in result.stderr.splitlines() if line.strip()]
    assert lines and all(line.startswith("MPM 1 scene(s):") for line in lines), result.stderr  # the progress bar only
    assert (tmp_path / "run" / "final.png").is_file()


@pytest.mark.skipif(torch.cuda.is_available(), reason="this machine has a CUDA GPU")
def test_device_cuda_without_a_gpu_is_one_sentence(tmp_path):
    (tmp_path / "scene.json").write_text(json.dumps(COLUMN_BESIDE_BLOCK))
    result = runout_command("mpm", "scene.json", "--out", "run", "--device", "cuda", cwd=tmp_path)
    assert result.returncode == 2
    assert result.stderr.strip().count("\n") == 0 and "no CUDA GPU is available" in result.stderr
    assert "Warp" not in result.stderr
