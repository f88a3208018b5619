"""The record of an inverse run: every evaluation, written atomically to history.json and
history.csv after each one, and read back to resume a killed run.

An evaluation is one loss + gradient at one point. L-BFGS-B accepts some of them as its
iterates; those carry their iteration number (0 = the starting point), line-search trials
carry none. JSON floats round-trip exactly, so a resumed run can replay recorded evaluations
and L-BFGS-B follows the same path.
"""

from __future__ import annotations

import csv
import io
import json
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from runout import checks
from runout.errors import InputError
from runout.inverse.spec import FreeParameter
from runout.outputs import write_atomic

HISTORY_JSON = "history.json"
HISTORY_CSV = "history.csv"


@dataclass
class Record:
    evaluation: int
    iteration: int | None  # the L-BFGS-B iterate this point became; None for a line-search trial
    normalised: list[float]  # [P] in [0, 1] between each parameter's bounds
    values: list[float]  # [P] degrees / kPa
    loss: float  # m^2
    gradient: list[float]  # [P] d loss / d value
    gradient_normalised: list[float]  # [P] d loss / d normalised value
    forward_s: float
    backward_s: float
    peak_memory_bytes: int


@dataclass
class RunInfo:
    """What must match for a run to resume from a history."""

    digest: str  # sha256 of the spec file
    engine: str
    model: str
    start: list[float]  # normalised starting point


class History:
    def __init__(self, out_dir: Path, free: tuple[FreeParameter, ...], info: RunInfo,
                 memory_measure: str, true_values: list[float] | None):
        self.out_dir = Path(out_dir)
        self.free = free
        self.info = info
        self.memory_measure = memory_measure
        self.true_values = true_values
        self.records: list[Record] = []
        self.result: dict | None = None

    @property
    def iterations(self) -> list[Record]:
        return [r for r in self.records if r.iteration is not None]

    @property
    def kept(self) -> Record | None:
        """The evaluation the run ended on when it is no L-BFGS-B iterate (the evaluations ran out
        in a line search, and the lowest loss was kept); None when the run ended on an iterate."""
        if self.result is None or any(r.values == list(self.result["values"]) for r in self.iterations):
            return None
        return next((r for r in self.records if r.values == list(self.result["values"])), None)

    def add(self, record: Record) -> None:
        self.records.append(record)
        self.write()

    def mark_iteration(self, normalised: np.ndarray, iteration: int) -> None:
        """Mark the latest evaluation at `normalised` as L-BFGS-B iterate `iteration`."""
        for record in reversed(self.records):
            if np.array_equal(record.normalised, normalised):
                if record.iteration != iteration:
                    record.iteration = iteration
                    self.write()
                return

    def finish(self, result: dict) -> None:
        self.result = result
        self.write()

    def model_loss(self, record: Record) -> float | None:
        """Mean squared error of the normalised parameters against the true ones (paper Fig. 'model loss')."""
        if self.true_values is None:
            return None
        truth = [p.normalise(v) for p, v in zip(self.free, self.true_values)]
        return float(np.mean((np.asarray(record.normalised) - truth) ** 2))

    # ------------------------------------------------------------------ files

    def to_dict(self) -> dict:
        return {
            "run": asdict(self.info),
            "parameters": [
                {"name": p.name, "material": p.material, "property": p.prop, "unit": p.unit,
                 "initial": p.initial, "lower": p.lower, "upper": p.upper,
                 "true": None if self.true_values is None else self.true_values[k]}
                for k, p in enumerate(self.free)
            ],
            "memory_measure": self.memory_measure,
            "evaluations": [asdict(r) for r in self.records],
            "result": self.result,
        }

    def write(self) -> None:
        self.out_dir.mkdir(parents=True, exist_ok=True)
        write_atomic(self.out_dir / HISTORY_JSON, json.dumps(self.to_dict(), indent=1))
        write_atomic(self.out_dir / HISTORY_CSV, self.to_csv())

    def to_csv(self) -> str:
        names = [f"{p.name} ({p.unit})" for p in self.free]
        header = ["evaluation", "iteration", "loss (m^2)", "model loss"] + names
        header += [f"d loss / d {p.name}" for p in self.free]
        header += ["forward (s)", "backward (s)", "peak memory (MB)"]
        buffer = io.StringIO()
        writer = csv.writer(buffer)
        writer.writerow(header)
        for r in self.records:
            model_loss = self.model_loss(r)
            writer.writerow(
                [r.evaluation, "" if r.iteration is None else r.iteration, repr(r.loss),
                 "" if model_loss is None else repr(model_loss)]
                + [repr(v) for v in r.values] + [repr(g) for g in r.gradient]
                + [f"{r.forward_s:.4f}", f"{r.backward_s:.4f}", f"{r.peak_memory_bytes / 1e6:.3f}"]
            )
        return buffer.getvalue()

    def resume_from_disk(self) -> None:
        """Load recorded evaluations from out_dir, after checking they belong to this run and
        hold the numbers a replay returns (runout.checks)."""
        path = self.out_dir / HISTORY_JSON
        if not path.is_file():
            return
        data = checks.json_table(path, "history")
        if data.get("run") != asdict(self.info):
            raise InputError(
                f"{path}: was written by a different spec, engine, model or starting point; "
                "use another --out folder or remove it to start afresh."
            )
        try:
            self.records = [Record(**r) for r in data["evaluations"]]
        except (TypeError, KeyError) as exc:
            raise InputError(f"{path}: the recorded evaluations are malformed ({exc}); remove it to start afresh.") from None
        for k, r in enumerate(self.records):
            checks.number(r.loss, f"evaluations[{k}].loss", path, 0.0, unit=" m²")
            for key in ("normalised", "gradient_normalised"):
                checks.numbers(getattr(r, key), f"evaluations[{k}].{key}", path, len(self.free))
