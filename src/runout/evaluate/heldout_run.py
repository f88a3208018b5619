"""`runout evaluate heldout`: the accuracy of a learned engine's checkpoint (GNS or neural MPM:
the file says which), as its model card and docs/training.md report it.

1. Rollouts from rest (frame 0 held, as users' scenes start) of the first `limit` scenes of
   DATA/SPLIT.npz, scored against the MPM beside standing still (runout.evaluate.heldout):
   mean position error (m), front errors relative to the fronts' travel, extent runout error,
   mean displacement; with `mirrored`, the same scenes reflected left-right as well (a model
   that learned the physics, not the side the training slopes face, scores them alike).
2. A column collapse (by default examples/column_a1.toml) filled at the model's point spacing,
   run by the MPM and by the engine from rest for `frames` frames: normalised runout of each and
   their difference; OUT/column.png shows both.
3. With a run's log (the GNS's log.jsonl or the neural MPM's train.log.jsonl), its training and
   validation curves (OUT/curves.png).
Everything goes to OUT/metrics.json.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path

import numpy as np

from runout.outputs import write_atomic

WRITES = ("metrics.json", "column.png", "curves.png")


def run_heldout(engine, model: Path, data: Path, out: Path, split: str = "test", limit: int = 16, mirrored: bool = False,
                column: Path | None = None, frames: int = 240, log: Path | None = None,
                echo: Callable[[str], None] = print, progress: bool = False) -> dict:
    """The measures above for the checkpoint `model`; writes OUT/metrics.json (and the pictures)
    and returns the metrics. engine: the model's learned engine (runout.learned.load.load_engine);
    column None: no column run; progress: a bar over the held-out scenes on stderr."""
    from runout.evaluate.heldout import evaluate_heldout

    metrics = {"model": str(model)}
    for key in heldout_keys(split, mirrored):
        t0 = time.perf_counter()
        metrics[key] = evaluate_heldout(engine, data, split, limit, progress, mirrored=key.endswith("mirrored"))
        metrics[key]["rollout_wall_s"] = round(time.perf_counter() - t0, 1)
    if column is not None:
        metrics["column"] = column_run(engine, column, frames, out)
    if log is not None:
        metrics["curves"] = curves(log, out / "curves.png")
    write_atomic(out / "metrics.json", json.dumps(metrics, indent=1))
    for line in summary_lines(metrics, model, split):
        echo(line)
    return metrics


def heldout_keys(split: str, mirrored: bool) -> list[str]:
    return [f"{split}_split"] + ([f"{split}_split_mirrored"] if mirrored else [])


def summary_lines(metrics: dict, model: Path, split: str) -> list[str]:
    """One line per held-out measure, then one per family and start, each beside standing still."""
    lines = []
    for key in heldout_keys(split, f"{split}_split_mirrored" in metrics):
        m, still = metrics[key]["model"], metrics[key]["standing_still"]
        scenes = f"{split} scenes{' mirrored' if key.endswith('mirrored') else ''}"
        lines.append(f"{model}: {m['scenes']} {scenes} from rest: position error {m['position_error_m']:.2f} m "
                     f"(standing still {still['position_error_m']:.2f}), fronts {100 * m['front_error']:.1f} % of their travel, "
                     f"extent runout error {100 * m['runout_error']:.1f} %, mean displacement {m['displacement_m']:.1f} m "
                     f"(MPM {m['displacement_mpm_m']:.1f}); {metrics[key]['rollout_wall_s']:.0f} s")
        for kind, scores in metrics[key]["by_kind"].items():
            m, still = scores["model"], scores["standing_still"]
            lines.append(f"  {kind:15s} {m['scenes']:2d} scenes: position error {m['position_error_m']:.2f} m "
                         f"(standing still {still['position_error_m']:.2f}), fronts {100 * m['front_error']:.1f} %, "
                         f"extent {100 * m['runout_error']:.1f} %, mean displacement {m['displacement_m']:.1f} m "
                         f"(MPM {m['displacement_mpm_m']:.1f})")
    if "column" in metrics:
        c = metrics["column"]
        error = "" if c["relative_error"] is None else f", error {100 * c['relative_error']:+.1f} %"
        lines.append(f"  column {c['scene']}, {c['frames']} frames: normalised runout MPM {c['mpm_normalised_runout']:.3g}, "
                     f"{c['engine']} {c['engine_normalised_runout']:.3g}{error}")
    return lines


def column_run(engine, scene_path: Path, frames: int, out: Path) -> dict:
    """The column scene filled at the engine's point spacing, run by the MPM and by the engine
    from rest for `frames` frames: both normalised runouts; OUT/column.png shows both."""
    from runout.learned.engine import engine_label
    from runout.learned.scenes import at_model_spacing, scene_at_rest
    from runout.metrics import normalised_extent
    from runout.mpm import simulate
    from runout.plots import save_comparison
    from runout.scene import load_scene

    scene = at_model_spacing(load_scene(scene_path), engine)
    scene = replace(scene, time=replace(scene.time, frames=frames))
    t0 = time.perf_counter()
    truth = simulate([scene], device="cpu", progress=False)[0]
    mpm_s = time.perf_counter() - t0
    predicted = engine.rollout_trajectory(scene_at_rest(scene), frames, stop_speed=None)
    mpm_ln, engine_ln = normalised_extent(truth), normalised_extent(predicted)
    save_comparison(truth, predicted, out / "column.png", (truth.n_frames - 1, predicted.n_frames - 1),
                    ("MPM, last frame", f"{engine_label(engine)}, last frame"))
    return {"scene": scene_path.name, "cell_size_m": scene.domain.cell_size, "points": truth.n_points, "frames": frames,
            "mpm_normalised_runout": mpm_ln, "engine": engine.name, "engine_normalised_runout": engine_ln,
            "relative_error": (engine_ln - mpm_ln) / mpm_ln if mpm_ln else None, "mpm_wall_s": round(mpm_s, 1)}


def read_log(log: Path) -> list[dict]:
    """The rows of a training run's log.jsonl; InputError unless it is one with loss rows."""
    from runout.errors import InputError
    from runout.reading import read_text

    try:
        rows = [json.loads(line) for line in read_text(log, "training log (log.jsonl)").splitlines() if line.strip()]
    except json.JSONDecodeError as exc:
        raise InputError(f"{log}: line {exc.lineno} is not JSON; give a training run's log.jsonl.") from None
    if not all(isinstance(r, dict) for r in rows) or not any("loss" in r and "step" in r for r in rows):
        raise InputError(f"{log}: holds no training losses; give a training run's log.jsonl.")
    return rows


def curves(log: Path, path: Path) -> dict:
    """Training loss (mean of each logged group of steps) and validation rollout figures
    against the step, from a run's log.jsonl, drawn to `path`."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = read_log(log)
    if any(r.get("event") == "valid" and "position_error_m" in r for r in rows):
        return _neural_mpm_curves(rows, path)
    loss = [(r["step"], r["loss"]) for r in rows if "loss" in r and "step" in r]
    valid = [(r["step"], r["valid_runout_error"], r["valid_position_mse_m2"]) for r in rows if "valid_runout_error" in r]
    fig, axes = plt.subplots(1, 2, figsize=(10, 3.6), constrained_layout=True)
    steps, _ = zip(*loss)
    _loss_panel(axes[0], loss, "training loss (normalised acceleration MSE)")
    if valid:
        vs, ve, vm = zip(*valid)
        axes[1].plot(vs, 100 * np.abs(ve), "o-", color="C1", label="|runout error| (%)")
        twin = axes[1].twinx()
        twin.semilogy(vs, vm, "s--", color="C2", label="position MSE (m²)")
        twin.set_ylabel("position MSE over the rollout (m²)")
        axes[1].legend(loc="upper left", fontsize=8)
        twin.legend(loc="upper right", fontsize=8)
    axes[1].set(xlabel="step", ylabel="|runout error| (%)", title="validation rollouts")
    _save(fig, axes, path)
    return {"last_step": steps[-1], "loss_last_1000_steps": float(np.mean([v for s, v in loss if s > steps[-1] - 1000])),
            "validation": [{"step": s, "runout_error": e, "position_mse_m2": m} for s, e, m in valid]}


def _neural_mpm_curves(rows: list[dict], path: Path) -> dict:
    """The neural MPM's train.log.jsonl drawn to `path`: its loss (soil position MSE over the K
    calls, cells squared) and the held-out position error from rest (m) of each dataset it
    validates on, against the step; the validation rows as a list."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    loss = [(r["step"], r["loss"]) for r in rows if r.get("event") == "loss"]
    starts = [r for r in rows if r.get("event") == "start"]
    measure = str((starts[0].get("settings") or {}).get("data", "the measure")).split(",")[0] if starts else "the measure"
    valid = [{"data": r.get("data", measure), **{k: r[k] for k in ("step", "cpu_hours", "position_error_m", "front_error",
                                                                   "runout_error") if k in r}}
             for r in rows if r.get("event") == "valid" and "position_error_m" in r]
    fig, axes = plt.subplots(1, 2, figsize=(10, 3.6), constrained_layout=True)
    _loss_panel(axes[0], loss, "training loss (position MSE, cells²)")
    for k, data in enumerate(dict.fromkeys(v["data"] for v in valid)):
        mine = [v for v in valid if v["data"] == data]
        axes[1].plot([v["step"] for v in mine], [v["position_error_m"] for v in mine], "o-", ms=3, color=f"C{k + 1}",
                     label=f"{data}{' (the measure)' if data == measure else ''}")
    if valid:
        axes[1].legend(fontsize=8)
    axes[1].set(xlabel="step", ylabel="position error from rest (m)", title="held-out scenes from rest", ylim=(0, None))
    _save(fig, axes, path)
    last = loss[-1][0] if loss else 0
    return {"last_step": last, "loss_last_1000_steps": float(np.mean([v for s, v in loss if s > last - 1000])) if loss else None,
            "validation": valid}


def _loss_panel(ax, loss: list[tuple[int, float]], ylabel: str) -> None:
    """The logged losses against the step (log scale) with a running mean over about 1/50 of them."""
    if loss:
        steps, values = zip(*loss)
        ax.semilogy(steps, values, lw=0.5, color="0.6", label="mean of each logged group")
        width = max(1, len(values) // 50)
        smooth = np.convolve(values, np.ones(width) / width, mode="valid")
        ax.semilogy(steps[width - 1:], smooth, color="C0", label=f"running mean of {width}")
        ax.legend(fontsize=8)
    ax.set(xlabel="step", ylabel=ylabel, title="training")


def _save(fig, axes, path: Path) -> None:
    import matplotlib.pyplot as plt
    from matplotlib.ticker import FuncFormatter

    for ax in axes:  # thousands of steps: six-digit tick labels run into each other
        ax.xaxis.set_major_formatter(FuncFormatter(lambda v, _: f"{v / 1000:g}k"))
    fig.savefig(path, dpi=110)
    plt.close(fig)
