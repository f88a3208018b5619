"""Dam inversion study (paper §5.2): the MPM makes the target deposit, the inverse module
back-calculates c of material 1, c of material 2 (a tight box) and phi of material 3.

The parameters, bounds and loss come from examples/dam_inverse.toml (the paper's Table 3:
c1 in [10, 100] kPa, c2 in [99, 101] kPa, phi3 in [5, 50] degrees); this study only points
its target at the cached MPM run of examples/dam.toml and calls `runout.inverse.invert`.
The model loss is the MSE between the normalised true and inferred parameters. The target
is an MPM run of the dam at the model's point spacing, the spacing the inverse rolls the
learned engine (GNS or neural MPM) out at.

The same spec is then solved through the MPM itself (`--engine mpm-ad`, reverse-mode AD through
the solver) as the yardstick: the same target, start, bounds and optimiser, so the two engines'
answers and their seconds per L-BFGS-B iteration stand side by side (paper §5.2 compares the
GNS's inverse with the MPM's in accuracy and cost; here the learned engine is whichever the
model file holds). Each engine's data loss at the true values (one more forward run, the
inverse's own loss) tells where a wrong answer comes from: above its answer's loss, the engine's
response is off (the model); about equal, a flat loss surface; below, the optimiser.

Writes OUT/inverse/: scene.toml and spec.toml (the problem solved), target.png (initial
geometry, MPM deposit, its displacement), run/ (history.json, history.csv, loss.png,
parameters.png, deposit.png from the inverse module, the learned engine), run_mpm_ad/ (the same, MPM-AD;
unless yardstick=False) and summary.json.
"""

from __future__ import annotations

import json
import tomllib
from pathlib import Path

from matplotlib.figure import Figure  # no pyplot: no global figure state, no GUI backend

from runout.evaluate.context import StudyContext
from runout.evaluate.model_card import model_card
from runout.evaluate.scenes import EXAMPLES, example_scene, model_scene, scaled
from runout.inverse import invert
from runout.learned.engine import engine_label
from runout.learned.load import load_engine
from runout.plots import draw_displacement, draw_materials
from runout.scene import save_scene
from runout.trajectory import Trajectory, load_trajectory

DAM_SCENE = "dam.toml"
DAM_SPEC = "dam_inverse.toml"


YARDSTICK = "mpm-ad"
YARDSTICK_RUN = "run_mpm_ad"


def run_inverse(model: Path, out: Path, run: StudyContext, examples: Path = EXAMPLES, frames: int | None = None,
                scale: float = 1.0, max_iterations: int | None = None, log=None, yardstick: bool = True) -> dict:
    """Run the study (the learned engine, then the MPM-AD yardstick unless `yardstick` is False);
    returns the summary written to OUT/inverse/summary.json."""
    folder = Path(out) / "inverse"
    engine = load_engine(model, run.device)
    scene = scaled(model_scene(examples, DAM_SCENE, engine, run.log), scale)
    scene = scene.with_frames(frames) if frames is not None else scene
    target = run.cache.ensure([scene], run.device, run.progress)[0]
    folder.mkdir(parents=True, exist_ok=True)
    save_scene(scene, folder / "scene.toml")
    spec = spec_text(_example_spec(examples), target.resolve(), max_iterations)
    (folder / "spec.toml").write_text(spec)
    result = invert(folder / "spec.toml", folder / "run", model=model, device=run.device, log=log)
    log_loss_at_truth(result, engine_label(engine), log)
    draw_target(load_trajectory(target), folder / "target.png")
    summary = summarise(result, model)
    summary.update(scale=scale, frames=scene.time.frames, engine=engine.name)
    if yardstick:
        if log:
            log(f"the yardstick: the same inverse through the MPM ({YARDSTICK})")
        measured = invert(folder / "spec.toml", folder / YARDSTICK_RUN, device=run.device, engine=YARDSTICK, log=log)
        log_loss_at_truth(measured, "MPM-AD", log)
        summary["yardstick"] = engine_summary(measured) | {"engine": YARDSTICK}
    (folder / "summary.json").write_text(json.dumps(summary, indent=1))
    return summary


def _example_spec(examples: Path) -> dict:
    example_scene(examples, DAM_SCENE)  # the spec's scene must be there too
    return tomllib.loads((Path(examples) / DAM_SPEC).read_text())


def spec_text(example: dict, target: Path, max_iterations: int | None) -> str:
    """The example spec with scene.toml beside it, the cached MPM run as the target and,
    when given, max_iterations (with twice as many evaluations)."""
    optimiser = dict(example.get("optimiser", {}))
    if max_iterations is not None:
        optimiser.update(max_iterations=max_iterations, max_evaluations=2 * max_iterations)
    lines = ['scene = "scene.toml"', "", "[target]", f"trajectory = {json.dumps(str(target))}", 'frames = "final"']
    for material, props in example["parameters"].items():
        lines += ["", f"[parameters.{json.dumps(material)}]"] + [f"{k} = {_toml(v)}" for k, v in props.items()]
    for table in ("loss", "rollout"):
        if table in example:
            lines += ["", f"[{table}]"] + [f"{k} = {_toml(v)}" for k, v in example[table].items()]
    lines += ["", "[optimiser]"] + [f"{k} = {_toml(v)}" for k, v in optimiser.items()]
    return "\n".join(lines) + "\n"


def _toml(value) -> str:
    if isinstance(value, dict):
        return "{ " + ", ".join(f"{k} = {_toml(v)}" for k, v in value.items()) + " }"
    if isinstance(value, str):
        return json.dumps(value)
    return repr(value)


def summarise(result, model: Path) -> dict:
    return {"study": "inverse", "model": model_card(model).to_dict()} | engine_summary(result)


def engine_summary(result) -> dict:
    """One engine's answer: parameters (true, inferred, bounds), losses, iterations and cost."""
    best = result.best
    history = best.history
    spent = sum(r.forward_s + r.backward_s for r in history.records)  # s, every evaluation of the best start
    return {
        "parameters": [
            {"name": p.name, "unit": p.unit, "lower": p.lower, "upper": p.upper, "initial": p.initial,
             "true": None if history.true_values is None else history.true_values[k], "inferred": float(best.values[k])}
            for k, p in enumerate(result.spec.free)
        ],
        "final_data_loss_m2": best.loss,
        "data_loss_at_true_m2": result.loss_at_truth,  # None: the target names no true values
        "iterations": best.iterations,
        "evaluations": best.evaluations,
        "message": best.message,
        "seconds": spent,
        "seconds_per_iteration": spent / max(best.iterations, 1),
        "history": [
            {"iteration": r.iteration, "values": r.values, "data_loss_m2": r.loss, "model_loss": history.model_loss(r),
             "forward_s": r.forward_s, "backward_s": r.backward_s}
            for r in history.iterations
        ],
        "run_folder": str(best.out_dir),
    }


def log_loss_at_truth(result, label: str, log) -> None:
    """One line: the engine's data loss at the true values beside its answer's, when they are known."""
    if log and result.loss_at_truth is not None:
        log(f"{label} at the true values: data loss {result.loss_at_truth:.4g} m² "
            f"(its answer: {result.best.loss:.4g} m²)")


def draw_target(target: Trajectory, path: Path) -> None:
    """(a) initial geometry, (b) MPM deposit, (c) its displacement field (m)."""
    fig = Figure(figsize=(11, 8.5), layout="constrained")
    axes = fig.subplots(3, 1)
    draw_materials(axes[0], target, 0, "(a) initial configuration")
    draw_materials(axes[1], target, -1, f"(b) MPM deposit, frame {target.n_frames - 1}", legend=False)
    image = draw_displacement(axes[2], target, target.n_frames - 1, "(c) displacement of the deposit")
    fig.colorbar(image, ax=axes[2], label="displacement (m)")
    fig.savefig(path, dpi=120)
