"""One neural-MPM training pilot or chunk (docs/training.md): train or resume a run folder
under a CPU-time budget, then judge it from rest on held-out scenes.

    python scripts/neural_mpm_pilot.py --out runs/nmpm-p1 --steps 11000 --max-cpu-hours 1
    python scripts/neural_mpm_pilot.py --out runs/nmpm-p1 --resume --max-cpu-hours 4
    python scripts/neural_mpm_pilot.py --data data/ft8,data/col8 --data-shares 3,1 --out runs/nmpm-cols --calls 3

The pilots' options, each passed on to `runout train --engine neural-mpm` (the same run;
--mirror-share is its --mirror, --valid-count its --valid-trajectories), with the pilots'
defaults. Engine settings (cell size, m, history, widths, velocity sweeps) apply to a new run only; a resumed
run keeps its checkpoint's, and its learning-rate schedule unless --lr-decay-steps is given.
"""

from __future__ import annotations

import argparse
from dataclasses import fields

from runout.cli import main as runout
from runout.train_settings import NEURAL_MPM_OPTIONS, NeuralMPMConfig, NeuralMPMSettings


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    for f in fields(NeuralMPMSettings):
        if isinstance(f.default, bool):
            p.add_argument(f"--{f.name.replace('_', '-')}", action=argparse.BooleanOptionalAction, default=f.default)
        else:
            kind = {"int": int, "float": float, "str": str}.get(str(f.type).split(" ")[0], float)
            p.add_argument(f"--{f.name.replace('_', '-')}", type=kind, default=f.default)
    # the engine's options, passed on only when given (a run from --init takes its file's engine)
    p.add_argument("--cell-size", type=float, help=f"default {NeuralMPMConfig.cell_size:g}")
    p.add_argument("--history", type=int, help=f"default {NeuralMPMConfig.history}")
    p.add_argument("--frames-per-call", type=int, help=f"default {NeuralMPMConfig.frames_per_call}")
    p.add_argument("--widths", type=str, help=f"default {','.join(map(str, NeuralMPMConfig.widths))}")
    p.add_argument("--velocity-sweeps", type=int, help=f"default {NeuralMPMConfig.velocity_sweeps}")
    p.add_argument("--resume", action="store_true")
    a = p.parse_args()
    args = ["train", "--engine", "neural-mpm"] + (["--resume"] if a.resume else [])
    for name in [f.name for f in fields(NeuralMPMSettings)] + ["cell_size", "history", "frames_per_call", "widths", "velocity_sweeps"]:
        value = getattr(a, name)
        option = NEURAL_MPM_OPTIONS.get(name, "--" + name.replace("_", "-"))
        if isinstance(value, bool):
            args.append(option if value else "--no-" + option[2:])
        elif value is not None:
            args += [option, str(value)]
    runout(args)


if __name__ == "__main__":
    main()
