"""scripts/cpu_chunk.sh, the campaign's one command per chunk, run in a copy of the repository
layout with a stand-in for `runout` that records its arguments: the fine-tune's start (BASE=),
the onset schedule (ONSET=, kept by a resumed run), the refusal of a base from before the recipe
and of a file python cannot read."""

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import torch

REPO = Path(__file__).resolve().parents[1]
RECORDER = """#!/bin/bash
# stand-in for runout: record the arguments; `train` leaves the checkpoint and log a run leaves
echo "$@" >> "$(dirname "$0")/../../calls.txt"
if [ "$1" = train ]; then
  out=$(echo "$@" | sed -E 's/.*--out ([^ ]+).*/\\1/')
  schedule=$(echo "$@" | sed -E 's/.*--onset-schedule ([^ ]+).*/\\1/')
  mkdir -p "$out"
  "$(dirname "$0")/python" -c "import sys, torch; torch.save({'optimizer': {}, 'train': {'exact_rest': True, 'onset_schedule': tuple(tuple(float(x) if i == 1 else int(x) for i, x in enumerate(e.split(':'))) for e in sys.argv[2].split(','))}}, sys.argv[1])" "$out/checkpoint.pt" "$schedule"
  echo '{"step": 1}' > "$out/log.jsonl"
fi
"""


@pytest.fixture
def layout(tmp_path):
    (tmp_path / "scripts").mkdir()
    shutil.copy(REPO / "scripts" / "cpu_chunk.sh", tmp_path / "scripts")
    bin_dir = tmp_path / ".venv" / "bin"
    bin_dir.mkdir(parents=True)
    (bin_dir / "runout").write_text(RECORDER)
    (bin_dir / "runout").chmod(0o755)
    (bin_dir / "python").write_text(f'#!/bin/bash\nexec "{sys.executable}" "$@"\n')  # this venv's python
    (bin_dir / "python").chmod(0o755)
    (tmp_path / "data" / "ft8").mkdir(parents=True)
    (tmp_path / "data" / "ft8" / "metadata.json").write_text("{}")
    (tmp_path / "models").mkdir()
    torch.save({"model": {}, "train": {"exact_rest": True}}, tmp_path / "models" / "best.pt")  # weights only, the recipe's
    torch.save({"model": {}, "optimizer": {}, "train": {}}, tmp_path / "models" / "base.pt")  # from before the recipe
    return tmp_path


def chunk(root: Path, **env) -> subprocess.CompletedProcess:
    return subprocess.run(["bash", str(root / "scripts" / "cpu_chunk.sh"), "finetune", "0.01"], cwd=root,
                          env={**os.environ, **env}, capture_output=True, text=True)


def calls(root: Path) -> list[str]:
    return (root / "calls.txt").read_text().splitlines()


def test_a_fine_tune_starts_from_BASE_with_ONSET_and_its_resume_keeps_that_schedule(layout):
    first = chunk(layout, BASE="models/best.pt", ONSET="0:0.4:4,12000:0.5:2")
    assert first.returncode == 0, first.stderr
    args = calls(layout)[-1].split()
    assert args[args.index("--init") + 1] == "models/best.pt" and "--resume" not in args
    assert args[args.index("--onset-schedule") + 1] == "0:0.4:4,12000:0.5:2"
    assert (layout / "models" / "slope-train.pt").is_file() and (layout / "models" / "slope-train.log.jsonl").is_file()

    second = chunk(layout)  # no ONSET: the run's own schedule, not the recipe's three phases
    assert second.returncode == 0, second.stderr
    args = calls(layout)[-1].split()
    assert "--resume" in args and "--init" not in args
    assert args[args.index("--onset-schedule") + 1] == "0:0.4:4,12000:0.5:2"


def test_a_fine_tune_from_a_base_trained_before_the_recipe_is_refused(layout):
    result = chunk(layout)  # BASE defaults to models/base.pt, which lacks the recipe's settings
    assert result.returncode == 2
    assert "models/base.pt predates the recipe" in result.stderr
    assert not (layout / "calls.txt").exists() or all(not c.startswith("train") for c in calls(layout))


def test_a_base_file_that_cannot_be_read_stops_the_chunk_with_its_own_message(layout):
    (layout / "models" / "damaged.pt").write_bytes(b"not a checkpoint")
    result = chunk(layout, BASE="models/damaged.pt")
    assert result.returncode == 2
    assert "could not read models/damaged.pt" in result.stderr
    assert "predates the recipe" not in result.stderr
    assert not (layout / "calls.txt").exists() or all(not c.startswith("train") for c in calls(layout))
