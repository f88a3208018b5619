"""`runout demo`: a forward GNS runout and an inverse back-calculation with the shipped model.

(a) The four-layer slope (examples/four_layer_slope.toml) fails from rest under the GNS and,
    beside it, under the MPM at the same point spacing (the truth, cached): animation.gif (MPM
    above GNS), final.png (MPM left, GNS right) and metrics.json (runout_compare's measures:
    both fronts, deposit overlap, position error; the errors are printed too).
(b) The small dam (examples/small_dam.toml) collapses in the MPM (the target, cached); the
    inverse analysis back-calculates the undrained strength c of its lower downstream shell
    from the final deposit with the GNS, L-BFGS-B from two starts (the lower loss kept):
    start_KK/ with history.csv, loss.png, parameters.png, deposit.png each, and starts.png.
    The same back-calculation through the MPM itself (reverse-mode AD, --engine mpm-ad) is
    the yardstick: the answer an exact physics gradient gives, in inverse/mpm_ad/.

Scenes are filled at the model's own point spacing (Simulator.point_spacing, from its
training data), so a model trained at coarse cells sees graphs like those it was trained on.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path

from runout.errors import InputError
from runout.compare import comparison_metrics
from runout.inverse import invert, summary_lines
from runout.learned.engine import engine_label
from runout.learned.load import load_engine
from runout.learned.scenes import at_model_spacing, scene_at_rest
from runout.metrics import at_common_times, runout_extent
from runout.mpm.cache import MpmCache
from runout.outputs import prepare_folder
from runout.plots import save_animation, save_side_by_side
from runout.scene import load_scene, save_scene
from runout.trajectory import load_trajectory

Log = Callable[[str], None]
SLOPE = "four_layer_slope.toml"
DAM = "small_dam.toml"
FREE_MATERIAL = "m1_downstream_lower"  # the dam's lower downstream shell: phi = 0, c = s_u = 40 kPa
FORWARD_FRAMES = 400  # frames at most; the rollout stops earlier once the slope is at rest
QUICK_FRAMES = 12  # frames in --quick (a wiring check, not a result)
# L-BFGS-B starts of the GNS inverse: the spec's 70 kPa, then one from a Latin hypercube (seed 0:
# 15.1 kPa), the lower loss kept. The GNS loss of c is bumpy at the model's 8 m resolution
# (docs/training.md, chunk 3), so one start may stop in a dip on its own side of the truth.
INVERSE_STARTS = 2


def run_demo(out: Path, model: Path, examples: Path, quick: bool = False, force: bool = False, log: Log = print) -> list[Path]:
    """The forward runout of EXAMPLES/four_layer_slope.toml and the inverse on
    EXAMPLES/small_dam.toml with the GNS checkpoint MODEL, written under OUT; returns the
    pictures. `quick`: few frames and iterations (a wiring check)."""
    for name in (SLOPE, DAM):
        if not (examples / name).is_file():
            raise InputError(f"--examples {examples}: {name} is missing there.")
    prepare_folder(out, "demo", ("forward", "inverse"), force=force, inputs={"--model": model, "--examples": examples})
    engine = load_engine(model, "cpu")
    if engine.material_width < 2:
        raise InputError(f"{model}: the demo needs a model with a cohesion input (a fine-tuned slope model).")
    forward = _forward(engine, examples / SLOPE, out / "forward", quick, log)
    inverse = _inverse(engine, model, examples / DAM, out / "inverse", quick, log)
    return [*forward, *inverse]


def _forward(engine, scene_path: Path, out: Path, quick: bool, log: Log) -> tuple[Path, Path, Path]:
    """The learned engine's runout of a scene from rest beside the MPM's: animation.gif,
    final.png, metrics.json."""
    scene = at_model_spacing(load_scene(scene_path), engine, scene_path.name, log)
    scene = scene.with_frames(QUICK_FRAMES if quick else FORWARD_FRAMES)
    out.mkdir(parents=True, exist_ok=True)
    truth = load_trajectory(_mpm_target(scene, out, log))
    truth.name = f"{scene.name} (MPM)"
    t0 = time.perf_counter()
    traj = engine.rollout_trajectory(scene_at_rest(scene), truth.n_frames, stop_speed=None)  # every frame the MPM has
    name = engine_label(engine)
    traj.name = f"{scene.name} ({name})"
    log(
        f"forward: {traj.n_points} points at {scene.domain.cell_size:g} m cells, {traj.n_frames} frames "
        f"({(traj.n_frames - 1) * traj.frame_dt:.1f} s of flow) in {time.perf_counter() - t0:.0f} s; "
        f"deposit spans {runout_extent(traj, -1):.0f} m (MPM {runout_extent(truth, -1):.0f} m)"
    )
    metrics = comparison_metrics(truth, traj, scene.domain.cell_size)
    for side in ("left", "right"):
        m = metrics[f"runout_{side}_m"]
        error = "" if m["ape_percent"] is None else f", error {m['ape_percent']:.1f} %"
        log(f"  {side} front {m['predicted']:.1f} m from the axis (MPM {m['truth']:.1f} m{error})")
    log(f"  deposit overlap (IoU of {scene.domain.cell_size:g} m cells) {metrics['deposit_iou']:.2f}; "
        f"mean position error {metrics['position_mse_mean_m2'] ** 0.5:.1f} m (root of the mean square)")
    (out / "metrics.json").write_text(json.dumps(metrics, indent=2))
    truth, traj = at_common_times(truth, traj)
    gif = save_animation([truth, traj], out / "animation.gif", labels=["MPM", name], stride=None if not quick else 6)
    final = save_side_by_side([(truth, "MPM"), (traj, name)], out / "final.png")
    return gif, final, out / "metrics.json"


def _inverse(engine, model: Path, scene_path: Path, out: Path, quick: bool, log: Log) -> tuple[Path, ...]:
    """Back-calculate c of the dam's lower downstream shell from its MPM deposit."""
    scene = at_model_spacing(load_scene(scene_path), engine, scene_path.name, log)
    if FREE_MATERIAL not in scene.materials:
        raise InputError(f"{scene_path}: the demo needs a material named {FREE_MATERIAL}.")
    if quick:
        scene = replace(scene, time=replace(scene.time, frames=QUICK_FRAMES))
    out.mkdir(parents=True, exist_ok=True)
    save_scene(scene, out / "scene.toml")
    target = _mpm_target(scene, out, log)
    spec = _write_spec(out, target.name, scene.materials[FREE_MATERIAL], quick)
    result_dir = out / "result"  # each inversion starts afresh (force: the model may have changed)
    t0 = time.perf_counter()
    name = engine_label(engine)
    log(f"inverse: L-BFGS-B on c of {FREE_MATERIAL}, one line per {name} rollout with its gradient")
    result = invert(spec, result_dir, engine=engine.name, model=model, starts=INVERSE_STARTS,
                    log=lambda line: log(f"  {line}"), force=True)
    evaluations = sum(r.evaluations for r in result.starts)
    log(f"inverse: {evaluations} evaluations from {INVERSE_STARTS} starts in {time.perf_counter() - t0:.0f} s")
    for line in summary_lines(result):
        log(f"  {line}")
    truth = scene.materials[FREE_MATERIAL].cohesion
    log(f"  true value: c = {truth:g} kPa (the MPM target's)")
    yardstick_dir = out / "mpm_ad"
    t0 = time.perf_counter()
    log("yardstick: the same back-calculation through the MPM itself (reverse-mode AD, --engine mpm-ad)")
    yardstick = invert(spec, yardstick_dir, engine="mpm-ad", force=True)
    (found,) = yardstick.best.values
    (learned_found,) = result.best.values
    log(f"  c = {found:.4g} kPa after {yardstick.best.evaluations} evaluations in {time.perf_counter() - t0:.0f} s "
        f"({name}: {learned_found:.4g} kPa, {100 * (learned_found - truth) / truth:+.0f} %; true {truth:g} kPa)")
    names = ("loss.png", "parameters.png", "deposit.png")
    chosen = (result.best.out_dir / n for n in names)  # the start with the lowest loss
    return (*chosen, result_dir / "starts.png", *(yardstick_dir / n for n in names))


def _mpm_target(scene, out: Path, log: Log) -> Path:
    """The scene's MPM trajectory, cached in out/mpm_<key of the solver version and scene>."""
    cache = MpmCache(out, prefix="mpm_")
    if cache.has(scene):
        log(f"{scene.name}: the MPM run cached in {cache.path(scene)}")
        return cache.path(scene)
    t0 = time.perf_counter()
    folder = cache.ensure([scene], progress=False)[0]
    traj = load_trajectory(folder)
    log(f"{scene.name}: MPM, {traj.n_points} points, {traj.n_frames} frames in {time.perf_counter() - t0:.0f} s")
    return folder


def _write_spec(out: Path, target: str, material, quick: bool) -> Path:
    """The inverse spec: c of FREE_MATERIAL free in [10, 100] kPa, everything else as in the scene."""
    # 8 evaluations per start: the 24 of two starts at 12 took the demo past 5 minutes on one
    # thread (6 min 16 s); in that run each start had its answer by evaluation 4 or 5 and the
    # later ones moved c by < 0.1 kPa (line searches in the loss's noise, docs/training.md)
    iterations, evaluations = (1, 2) if quick else (6, 8)
    gtol = 1e6 if quick else 1e-8  # quick: L-BFGS-B stops after evaluating the start
    text = f"""# written by `runout demo`
scene = "scene.toml"

[target]
trajectory = "{target}"
frames = "final"

[parameters.{FREE_MATERIAL}]
phi = {{ fixed = {material.friction_angle:g} }}
c = {{ initial = 70.0, lower = 10.0, upper = 100.0 }}

[optimiser]
max_iterations = {iterations}
max_evaluations = {evaluations}
gtol = {gtol:g}
"""
    path = out / "spec.toml"
    path.write_text(text)
    return path
