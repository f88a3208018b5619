"""Velocity- and physical-space error diagnostics of one column case (paper §5.1.1).

At chosen frames (80, 200 and the last), each soil point's velocity v_pred in the learned
engine's run (GNS or neural MPM) and its MPM velocity v_true (m/s, over the frame interval
ending there) give the error |v_pred - v_true|. The training velocity distribution is the model's own normalisation statistics (vel_mean,
vel_std in m per model step, converted to m/s); a point lies outside the k-sigma ellipse when
((v_x - m_x) / s_x)^2 + ((v_y - m_y) / s_y)^2 > k^2 (the statistics are per axis, so the
ellipses are axis-aligned).

Writes OUT/diagnostics/: summary.json, velocity_diagnostics.png (rows: velocity space
coloured by error, positions coloured by error, positions coloured by speed) and predicted/
(the engine's trajectory).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from runout.evaluate.context import StudyContext
from runout.evaluate.diagnostics_figures import draw_diagnostics
from runout.evaluate.model_card import model_card
from runout.evaluate.scenes import EXAMPLES, column_file, column_scene, model_scene
from runout.evaluate.study_settings import PAPER_CASE, ColumnCase  # noqa: F401  (PAPER_CASE re-exported)
from runout.learned.engine import engine_label
from runout.learned.load import load_engine
from runout.metrics import at_common_times, velocities
from runout.trajectory import Trajectory, save_trajectory

PAPER_FRAMES = (80, 200)  # and the last frame


def diagnostic_frames(n_frames: int, stride: int = 1) -> list[int]:
    """Frames 80 and 200 when the run has them, and the last frame (all >= 1), as indices of
    a run with one frame every `stride` dataset frames (the nearest)."""
    return sorted({round(f / stride) for f in PAPER_FRAMES if round(f / stride) < n_frames} | {n_frames - 1})


def training_velocity(engine, frame_dt: float) -> tuple[np.ndarray, np.ndarray]:
    """Mean and standard deviation (m/s) of the training velocities, per axis; frame_dt is
    the model's step (s), frame_stride dataset frames."""
    mean, std = engine.velocity_statistics()  # m per engine step
    return np.asarray(mean) / frame_dt, np.asarray(std) / frame_dt


def sigma_distance(v: np.ndarray, mean: np.ndarray, std: np.ndarray) -> np.ndarray:
    """[N] how many standard deviations each velocity [N, 2] lies from the training mean
    (the k of the axis-aligned k-sigma ellipse through it)."""
    return np.sqrt((((v - mean) / std) ** 2).sum(axis=1))


def frame_statistics(truth: Trajectory, predicted: Trajectory, frame: int, mean, std) -> dict:
    soil = truth.soil
    v_pred, v_true = velocities(predicted, frame)[soil], velocities(truth, frame)[soil]
    error = np.linalg.norm(v_pred - v_true, axis=1)  # m/s
    outside = sigma_distance(v_pred, mean, std) > 2.0
    return {
        "frame": frame,
        "median_error_m_s": float(np.median(error)),
        "p90_error_m_s": float(np.percentile(error, 90)),
        "share_outside_2sigma": float(outside.mean()),
        "mean_error_inside_2sigma_m_s": float(error[~outside].mean()) if (~outside).any() else None,
        "mean_error_outside_2sigma_m_s": float(error[outside].mean()) if outside.any() else None,
        "speed_error_correlation": _correlation(np.linalg.norm(v_pred, axis=1), error),
    }


def _correlation(a: np.ndarray, b: np.ndarray) -> float | None:
    """Pearson correlation, None when either side does not vary."""
    if a.std() == 0 or b.std() == 0:
        return None
    return float(np.corrcoef(a, b)[0, 1])


def run_diagnostics(model: Path, out: Path, run: StudyContext, case: ColumnCase = PAPER_CASE, frames: int = 600,
                    scale: float = 1.0, examples: Path = EXAMPLES) -> dict:
    """Run the diagnostics; returns the summary written to OUT/diagnostics/summary.json."""
    folder = Path(out) / "diagnostics"
    engine = load_engine(model, run.device)
    column = model_scene(examples, column_file(case.aspect), engine, run.log)
    scene = column_scene(column, case, frames, scale)
    truth = run.cache.load(scene, run.device, run.progress)
    predicted = engine.rollout_trajectory(truth, truth.n_frames, stop_speed=None, progress=run.progress)
    save_trajectory(predicted, folder / "predicted", engine.material_width)
    truth, predicted = at_common_times(truth, predicted)  # the MPM at the engine's times (frame stride)
    mean, std = training_velocity(engine, predicted.frame_dt)
    chosen = diagnostic_frames(truth.n_frames, engine.frame_stride)
    draw_diagnostics(truth, predicted, chosen, mean, std, case, folder / "velocity_diagnostics.png", engine_label(engine))
    summary = {
        "study": "diagnostics",
        "model": model_card(model).to_dict(),
        "case": {"aspect": case.aspect, "phi_deg": case.phi, "cohesion_kpa": case.cohesion, "frames": frames, "scale": scale},
        "training_velocity_m_s": {"mean": mean.tolist(), "std": std.tolist()},
        "frames": [frame_statistics(truth, predicted, f, mean, std) for f in chosen],
    }
    (folder / "summary.json").write_text(json.dumps(summary, indent=1))
    return summary
