"""Column-collapse study (paper §5.1.1): the MPM and a learned engine (GNS or neural MPM) over a
grid of aspect ratio, phi and c.

For every case: L_0 and L_f are the runout fronts (the largest x of the soil points plus
half the point spacing, i.e. the edge of the material the points stand for) of the column
against the left wall at the first and the last frame (m), L^n = (L_f - L_0) / L_0, and the
error is |L^n_predicted - L^n_MPM| / L^n_MPM x 100 (%), "predicted" being the engine's.
Per aspect ratio: mean error, its coefficient of variation and R² of the engine against the
MPM (1:1 line). The engine starts from rest (the MPM's frame 0 held), as a user's scene does;
both run at the model's point spacing.

Writes OUT/columns/: cases.csv, summary.json, runout_1to1.png, error_heatmaps.png,
evolution_p25.png, evolution_p50.png, evolution_p75.png and predicted/<case>/ (the engine's
trajectories). Summaries written before the keys named no engine say gns where these say
predicted (runout.evaluate.report reads both).
"""

from __future__ import annotations

import csv
import json
import shutil
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
from tqdm.auto import tqdm

from runout.evaluate.column_figures import draw_error_heatmaps, draw_evolution, draw_runout_comparison
from runout.evaluate.context import StudyContext
from runout.evaluate.model_card import model_card
from runout.evaluate.scenes import column_file, column_scene, model_scene
from runout.evaluate.study_settings import PAPER_ASPECTS, PAPER_COHESIONS, PAPER_PHIS, ColumnCase, ColumnGrid  # noqa: F401  (re-exported)
from runout.learned.engine import engine_label
from runout.learned.load import load_engine
from runout.metrics import (
    absolute_percentage_error, at_common_times, coefficient_of_variation, normalised_runout, r_squared, runout_front,
)
from runout.mpm.cache import MpmCache
from runout.trajectory import Trajectory, load_trajectory, save_trajectory

PERCENTILES = (25, 50, 75)  # error percentiles whose cases get a time-evolution figure
PREDICTED = "predicted"  # the folder of the engine's trajectories, as runout compare names it
CSV_COLUMNS = (
    "case", "aspect", "phi_deg", "cohesion_kpa", "L0_m", "Lf_mpm_m", "Lf_predicted_m",
    "runout_norm_mpm", "runout_norm_predicted", "ape_percent", "frames", "predicted_wall_s", "mpm_key",
)


@dataclass
class ColumnResult:
    case: str
    aspect: float
    phi_deg: float
    cohesion_kpa: float
    L0_m: float
    Lf_mpm_m: float
    Lf_predicted_m: float
    runout_norm_mpm: float
    runout_norm_predicted: float
    ape_percent: float
    frames: int
    predicted_wall_s: float
    mpm_key: str


def run_columns(model: Path, out: Path, grid: ColumnGrid, run: StudyContext) -> dict:
    """Run the study; returns the summary written to OUT/columns/summary.json."""
    folder = Path(out) / "columns"
    cases = grid.cases()
    engine = load_engine(model, run.device)
    columns = {a: model_scene(grid.examples, column_file(a), engine, run.log) for a in dict.fromkeys(grid.aspects)}
    scenes = [column_scene(columns[c.aspect], c, grid.frames, grid.scale) for c in cases]
    mpm_dirs = run.cache.ensure(scenes, run.device, run.progress)
    label = engine_label(engine)
    rows = []
    for case, scene, mpm_dir in tqdm(list(zip(cases, scenes, mpm_dirs)), desc=f"{label} columns", disable=not run.progress):
        truth = load_trajectory(mpm_dir)
        start = time.perf_counter()
        predicted = engine.rollout_trajectory(truth, truth.n_frames, stop_speed=None)
        wall = time.perf_counter() - start
        save_trajectory(predicted, folder / PREDICTED / case.name, engine.material_width)
        truth, predicted = at_common_times(truth, predicted)  # the MPM at the engine's times (frame stride)
        rows.append(case_result(case, truth, predicted, scene.domain.point_spacing / 2, wall, mpm_dir.name))
    write_csv(rows, folder / "cases.csv")
    summary = summarise(rows, grid, model)
    draw_outputs(rows, folder, run.cache, scenes, label)
    (folder / "summary.json").write_text(json.dumps(summary, indent=1))
    return summary


def case_result(case: ColumnCase, truth: Trajectory, predicted: Trajectory, edge: float, wall: float, key: str) -> ColumnResult:
    """edge: half the point spacing (m), added to the largest x to get the material's front."""
    l0 = runout_front(truth, 0) + edge
    lf_mpm, lf_predicted = runout_front(truth, -1) + edge, runout_front(predicted, -1) + edge
    n_mpm, n_predicted = normalised_runout(l0, lf_mpm), normalised_runout(l0, lf_predicted)
    return ColumnResult(
        case.name, case.aspect, case.phi, case.cohesion, l0, lf_mpm, lf_predicted, n_mpm, n_predicted,
        float(absolute_percentage_error(n_predicted, n_mpm)), predicted.n_frames, wall, key,
    )


def write_csv(rows: list[ColumnResult], path: Path) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=CSV_COLUMNS)
        writer.writeheader()
        for row in rows:
            writer.writerow(asdict(row))


def aspect_statistics(rows: list[ColumnResult]) -> list[dict]:
    """Per aspect ratio: number of cases, mean and CV of the error (%), R² of L^n."""
    stats = []
    for aspect in sorted({r.aspect for r in rows}):
        group = [r for r in rows if r.aspect == aspect]
        ape = np.array([r.ape_percent for r in group])
        stats.append({
            "aspect": aspect,
            "cases": len(group),
            "mean_ape_percent": float(np.nanmean(ape)),
            "cv_ape": coefficient_of_variation(ape) if len(group) > 1 else float("nan"),
            "r2": r_squared([r.runout_norm_predicted for r in group], [r.runout_norm_mpm for r in group]),
        })
    return stats


def friction_statistics(rows: list[ColumnResult]) -> list[dict]:
    """Per aspect ratio and friction angle: number of cases and the mean signed error of L^n (%,
    predicted minus MPM over MPM: positive runs too far), which says whether the engine's runout
    falls with φ as steeply as the MPM's; and the mean absolute error (%)."""
    stats = []
    for aspect in sorted({r.aspect for r in rows}):
        for phi in sorted({r.phi_deg for r in rows if r.aspect == aspect}):
            group = [r for r in rows if r.aspect == aspect and r.phi_deg == phi]
            signed = [100.0 * (r.runout_norm_predicted - r.runout_norm_mpm) / r.runout_norm_mpm for r in group
                      if r.runout_norm_mpm != 0]
            stats.append({
                "aspect": aspect, "phi_deg": phi, "cases": len(group),
                "mean_signed_error_percent": float(np.nanmean(signed)) if signed else float("nan"),
                "mean_ape_percent": float(np.nanmean([r.ape_percent for r in group])),
            })
    return stats


def percentile_cases(rows: list[ColumnResult]) -> dict[int, ColumnResult]:
    """The case at each error percentile: rank round(q / 100 x (n - 1)) of the sorted errors."""
    ranked = sorted(rows, key=lambda r: (np.nan_to_num(r.ape_percent, nan=np.inf), r.case))
    return {q: ranked[round(q / 100 * (len(ranked) - 1))] for q in PERCENTILES}


def summarise(rows: list[ColumnResult], grid: ColumnGrid, model: Path) -> dict:
    ape = np.array([r.ape_percent for r in rows])
    return {
        "study": "columns",
        "model": model_card(model).to_dict(),
        "grid": {"aspects": list(grid.aspects), "phis_deg": list(grid.phis), "cohesions_kpa": list(grid.cohesions),
                 "frames": grid.frames, "scale": grid.scale},
        "cases": len(rows),
        "mean_ape_percent": float(np.nanmean(ape)),
        "median_ape_percent": float(np.nanmedian(ape)),
        "by_aspect": aspect_statistics(rows),
        "by_friction_angle": friction_statistics(rows),
        "percentile_cases": {str(q): asdict(r) for q, r in percentile_cases(rows).items()},
        "predicted_wall_s_total": float(sum(r.predicted_wall_s for r in rows)),
    }


def draw_outputs(rows: list[ColumnResult], folder: Path, cache: MpmCache, scenes, label: str) -> None:
    """label: the engine's name in the figures (GNS, neural MPM)."""
    stats = aspect_statistics(rows)
    draw_runout_comparison(rows, stats, folder / "runout_1to1.png", label)
    draw_error_heatmaps(rows, stats, folder / "error_heatmaps.png")
    by_name = {s.name: s for s in scenes}
    drawn: dict[str, Path] = {}  # a case at two percentiles (few cases) is drawn once
    for q, row in percentile_cases(rows).items():
        path = folder / f"evolution_p{q}.png"
        if row.case in drawn:
            shutil.copyfile(drawn[row.case], path)
            continue
        truth = cache.load(by_name[row.case], progress=False)
        draw_evolution(*at_common_times(truth, load_trajectory(folder / PREDICTED / row.case)), row, q, path, label)
        drawn[row.case] = path
