"""The files of a finished study (units in every column name: m, degrees, kPa):

    realisations.csv / .json   every realisation's strengths and front runouts
    exceedance.csv             x (m, bin centre) and P(thickness > h) for each threshold h
    runout_cdf.csv             each front's sorted runouts (m) and their empirical CDF
    summary.json               each front's P5 / P50 / P95 (m), the P95's bootstrap standard
                               error and whether it is settled to 1 %, rank correlations
    exceedance.png, runouts.png  (runout.hazard.figures)
"""

from __future__ import annotations

import csv
import io
import json
import math
from pathlib import Path

import numpy as np

from runout.hazard.deposit import FRONTS
from runout.hazard.figures import save_exceedance, save_runouts
from runout.hazard.spec import PROPERTIES, HazardSpec
from runout.hazard.statistics import empirical_cdf, exceedance, front_summary, rank_correlations
from runout.outputs import write_atomic

RESULT_FILES = ("realisations.csv", "realisations.json", "exceedance.csv", "runout_cdf.csv", "summary.json",
                "exceedance.png", "runouts.png")


def input_names(spec: HazardSpec) -> list[str]:
    """Column names of the inputs with their units, e.g. 'phi[m2]_degrees'."""
    return [f"{prop}[{material}]_{PROPERTIES[prop][1]}" for material, prop in spec.inputs()]


def write_results(spec: HazardSpec, data: dict[str, np.ndarray], out: Path) -> dict:
    """Write every result file into out; returns the summary."""
    x = (np.arange(data["thickness"].shape[1]) + 0.5) * spec.bin_width  # m, bin centres
    probability = exceedance(data["thickness"], spec.thresholds)
    summary = _summary(spec, data)
    _write_realisations(spec, data, out)
    _write_table(out / "exceedance.csv", ["x_m", *(f"p_thickness_above_{h:g}_m" for h in spec.thresholds)],
                 np.column_stack([x, probability.T]))
    cdfs = [empirical_cdf(data["runouts"][:, f]) for f in range(len(FRONTS))]
    _write_table(out / "runout_cdf.csv", [col for f in FRONTS for col in (f"{f}_runout_m", f"{f}_probability")],
                 np.column_stack([c for pair in cdfs for c in pair]))
    write_atomic(out / "summary.json", json.dumps(summary, indent=2, allow_nan=False) + "\n")
    save_exceedance(spec.scene, x, probability, spec.thresholds, out / "exceedance.png")
    save_runouts(data["runouts"], summary["fronts"], out / "runouts.png")
    return summary


def _summary(spec: HazardSpec, data: dict[str, np.ndarray]) -> dict:
    fronts = {f: front_summary(data["runouts"][:, k], spec.seed) for k, f in enumerate(FRONTS)}
    rho = rank_correlations(data["inputs"], data["runouts"])
    correlations = {name: {f: _finite(rho[i, k]) for k, f in enumerate(FRONTS)} for i, name in enumerate(input_names(spec))}
    for f in fronts.values():
        f["p95_standard_error_m"] = _finite(f["p95_standard_error_m"])
    return {"realisations": spec.realisations, "thresholds_m": list(spec.thresholds), "bin_width_m": spec.bin_width,
            "fronts": fronts, "spearman": correlations,
            "thickness": "summed seeded area of the final soil points per x bin / bin width (m)"}


def _finite(value: float) -> float | None:
    return float(value) if math.isfinite(value) else None


def _write_realisations(spec: HazardSpec, data: dict[str, np.ndarray], out: Path) -> None:
    names = ["realisation", *input_names(spec), *(f"{f}_runout_m" for f in FRONTS)]
    rows = np.column_stack([np.arange(spec.realisations), data["inputs"], data["runouts"]])
    _write_table(out / "realisations.csv", names, rows)
    records = [dict(zip(names, [int(r[0]), *map(float, r[1:])])) for r in rows]
    write_atomic(out / "realisations.json", json.dumps(records, indent=1) + "\n")


def _write_table(path: Path, header: list[str], rows: np.ndarray) -> None:
    text = io.StringIO()
    writer = csv.writer(text, lineterminator="\n")
    writer.writerow(header)
    writer.writerows([[f"{v:.10g}" for v in row] for row in rows])
    write_atomic(path, text.getvalue())
