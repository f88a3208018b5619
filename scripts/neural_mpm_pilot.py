"""One neural-MPM training pilot or chunk (docs/training.md): train or resume a run folder
under a CPU-time budget, then judge it from rest on held-out scenes.

    python scripts/neural_mpm_pilot.py --out runs/nmpm-p1 --steps 11000 --max-cpu-hours 1
    python scripts/neural_mpm_pilot.py --out runs/nmpm-p1 --resume --max-cpu-hours 4
    python scripts/neural_mpm_pilot.py --data data/ft8,data/col8 --data-shares 3,1 --out runs/nmpm-cols --calls 3

Engine settings (cell size, m, history, widths) apply to a new run only; a resumed run keeps
its checkpoint's.
"""

from __future__ import annotations

import argparse
import json
from dataclasses import fields
from pathlib import Path

from runout.neural_mpm.engine import NeuralMPMConfig
from runout.neural_mpm.training import TrainSettings, datasets, train


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    for f in fields(TrainSettings):
        if f.type in ("bool",) or isinstance(f.default, bool):
            p.add_argument(f"--{f.name.replace('_', '-')}", action=argparse.BooleanOptionalAction, default=f.default)
        else:
            kind = {"int": int, "float": float, "str": str}.get(str(f.type).split(" ")[0], float)
            p.add_argument(f"--{f.name.replace('_', '-')}", type=kind, default=f.default)
    p.add_argument("--cell-size", type=float, default=NeuralMPMConfig.cell_size)
    p.add_argument("--history", type=int, default=NeuralMPMConfig.history)
    p.add_argument("--frames-per-call", type=int, default=NeuralMPMConfig.frames_per_call)
    p.add_argument("--widths", type=str, default=",".join(map(str, NeuralMPMConfig.widths)))
    p.add_argument("--resume", action="store_true")
    a = p.parse_args()
    settings = TrainSettings(**{f.name: getattr(a, f.name) for f in fields(TrainSettings)})
    config = NeuralMPMConfig(cell_size=a.cell_size, history=a.history, frames_per_call=a.frames_per_call,
                             widths=tuple(int(w) for w in a.widths.split(",")),
                             point_spacing=_spacing(Path(datasets(settings)[0])))
    train(settings, config, resume=a.resume)


def _spacing(data: Path) -> float:
    meta = json.loads((data / "metadata.json").read_text())
    return float(meta.get("point_spacing", meta.get("cell_size", 8.0) / 2))


if __name__ == "__main__":
    main()
