"""`runout demo`: what runout computes right, then what a learned engine makes of the same questions.

1. The MPM's forward runout of the paper's four-layer slope (examples/four_layer_slope.toml) from
   rest at the scene's own cells: 1_slope_mpm/slope.png (the start above the deposit). Its error
   line: the same run at cells twice as coarse moves the fronts by so much (the resolution error).
2. The back-calculation through the MPM (reverse-mode AD, `runout invert --engine mpm-ad`) of the
   undrained strength c of the small dam's lower downstream shell (examples/small_dam.toml, true
   40 kPa) from the MPM's deposit: 2_dam_mpm/inverse/ (parameters.png: c at each iteration;
   deposit.png: the deposits against the target).
3. The learned engine of --model (a GNS or a neural MPM: runout.learned reads whichever the file
   holds) on the slope from rest, beside the MPM at the model's point spacing:
   3_slope_learned/final.png (MPM left, learned right), animation.gif, metrics.json.
4. The same back-calculation through the learned engine, L-BFGS-B from two starts (the lower loss
   kept): 4_dam_learned/inverse/.

Each step prints one line saying what it runs, before it runs, then one with its measured error and
time; the pictures' paths come last. Every MPM run is cached in OUT/mpm/, so a second demo reuses them.
"""

from __future__ import annotations

import contextlib
import io
import json
import os
import sys
import time
from collections.abc import Callable
from pathlib import Path

from runout.compare import comparison_metrics
from runout.errors import InputError
from runout.inverse import invert
from runout.learned.engine import engine_label
from runout.learned.load import load_engine
from runout.learned.scenes import at_model_spacing, scene_at_rest
from runout.learned.training_range import range_warnings
from runout.metrics import at_common_times, mound_axis, side_runouts
from runout.mpm.cache import MpmCache
from runout.outputs import prepare_folder
from runout.plots import save_animation, save_comparison, save_side_by_side
from runout.scene import Scene, load_scene, save_scene
from runout.trajectory import Trajectory

Log = Callable[[str], None]
SLOPE = "four_layer_slope.toml"
DAM = "small_dam.toml"
FREE_MATERIAL = "m1_downstream_lower"  # the dam's lower downstream shell: phi = 0, c = s_u = 40 kPa
FOLDERS = ("mpm", "1_slope_mpm", "2_dam_mpm", "3_slope_learned", "4_dam_learned")
FORWARD_FRAMES = 400  # 15 s of flow: the four-layer slope is at rest by then
QUICK_FRAMES = 12  # frames in --quick (a wiring check, not a result)
# L-BFGS-B starts of the learned engine's inverse: the spec's 70 kPa, then one from a Latin
# hypercube (seed 0: 15.1 kPa), the lower loss kept. The shipped GNS's loss of c is bumpy at its
# 8 m cells (docs/training.md, chunk 3), so one start may stop in a dip on its own side of the truth.
INVERSE_STARTS = 2


def run_demo(out: Path, model: Path, examples: Path, quick: bool = False, force: bool = False, log: Log = print) -> list[Path]:
    """The four steps above with the learned engine in MODEL and the scenes in EXAMPLES, written
    under OUT; returns the pictures. `quick`: few frames and evaluations (a wiring check)."""
    for name in (SLOPE, DAM):
        if not (examples / name).is_file():
            raise InputError(f"--examples {examples}: {name} is missing there.")
    engine = load_engine(model, "cpu")
    if engine.material_width < 2:
        raise InputError(f"{model}: the demo needs a model with a cohesion input (a fine-tuned slope model).")
    prepare_folder(out, "demo", FOLDERS, force=force, inputs={"--model": model, "--examples": examples})
    frames = QUICK_FRAMES if quick else FORWARD_FRAMES
    slope = load_scene(examples / SLOPE).with_frames(frames)
    dam = load_scene(examples / DAM)
    if FREE_MATERIAL not in dam.materials:
        raise InputError(f"{examples / DAM}: the demo needs a material named {FREE_MATERIAL}.")
    if quick:
        dam = dam.with_frames(QUICK_FRAMES)
    cache = MpmCache(out / "mpm")
    name = engine_label(engine)
    log(f"runout demo: the MPM, then the {name} in {model}")
    pictures = [_mpm_forward(slope, cache, out / "1_slope_mpm", log)]
    pictures += _back_calculation(dam, cache, out / "2_dam_mpm", quick, log, "mpm-ad", "MPM (reverse-mode AD)")
    learned_slope = at_model_spacing(slope, engine, SLOPE, log=None)
    pictures += _learned_forward(engine, learned_slope, cache, out / "3_slope_learned", quick, log)
    learned_dam = at_model_spacing(dam, engine, DAM, log=None)
    pictures += _back_calculation(learned_dam, cache, out / "4_dam_learned", quick, log, engine.name, name, model)
    return pictures


def _mpm_forward(scene: Scene, cache: MpmCache, out: Path, log: Log) -> Path:
    """Step 1: the MPM's runout at the scene's cells, and the fronts' change at cells twice as coarse."""
    cell = scene.domain.cell_size
    log(f"1. MPM forward runout of {scene.name} from rest at its {cell:g} m cells ({_flow_seconds(scene):.1f} s of flow)")
    t0 = time.perf_counter()
    fine = _mpm(cache, scene)
    coarse = _mpm(cache, scene.with_point_spacing(2 * cell / scene.domain.points_per_cell, SLOPE))
    left, right = side_runouts(fine, mound_axis(fine))
    coarse_left, coarse_right = side_runouts(coarse, mound_axis(coarse))
    log(f"   fronts {left:.1f} m left and {right:.1f} m right of the axis ({fine.n_points} points); at {2 * cell:g} m "
        f"cells {coarse_left:.1f} / {coarse_right:.1f} m ({_percent(coarse_left, left)} / {_percent(coarse_right, right)}: "
        f"the error of halving the resolution); {_seconds(t0)}")
    out.mkdir(parents=True, exist_ok=True)
    last = fine.n_frames - 1
    return save_comparison(fine, fine, out / "slope.png", (0, last), (
        f"{scene.name}, MPM at {cell:g} m cells: t = 0 s", f"t = {last * fine.frame_dt:.1f} s: the deposit"), height=6.0)


def _learned_forward(engine, scene: Scene, cache: MpmCache, out: Path, quick: bool, log: Log) -> tuple[Path, Path]:
    """Step 3: the learned engine's runout from rest beside the MPM's at the same point spacing."""
    name = engine_label(engine)
    at_rest = scene_at_rest(scene)
    log(f"3. {name} forward runout of {scene.name} from rest at its {scene.domain.cell_size:g} m cells "
        f"({_flow_seconds(scene):.1f} s of flow){_outside_training(len(range_warnings(engine, at_rest)))}")
    t0 = time.perf_counter()
    truth = _mpm(cache, scene)
    truth.name = f"{scene.name} (MPM)"
    traj = engine.rollout_trajectory(at_rest, truth.n_frames, stop_speed=None)  # every frame the MPM has
    traj.name = f"{scene.name} ({name})"
    metrics = comparison_metrics(truth, traj, scene.domain.cell_size)
    left, right = metrics["runout_left_m"], metrics["runout_right_m"]
    log(f"   outermost points {left['predicted']:.1f} m left and {right['predicted']:.1f} m right of the axis, the MPM's "
        f"{left['truth']:.1f} / {right['truth']:.1f} m at these cells ({_percent(left['predicted'], left['truth'])} / "
        f"{_percent(right['predicted'], right['truth'])}); deposit overlap {metrics['deposit_iou']:.2f} (the MPM's: 1); "
        f"points {metrics['position_mse_mean_m2'] ** 0.5:.1f} m from the MPM's (root mean square over the run); "
        f"{_seconds(t0)}")
    out.mkdir(parents=True, exist_ok=True)
    (out / "metrics.json").write_text(json.dumps(metrics, indent=2))
    truth, traj = at_common_times(truth, traj)
    final = save_side_by_side([(truth, "MPM"), (traj, name)], out / "final.png")
    gif = save_animation([truth, traj], out / "animation.gif", labels=["MPM", name], stride=6 if quick else None)
    return final, gif


def _back_calculation(scene: Scene, cache: MpmCache, out: Path, quick: bool, log: Log, engine: str, name: str,
                      model: Path | None = None) -> tuple[Path, ...]:
    """Steps 2 and 4: c of FREE_MATERIAL back-calculated from the MPM's deposit of the scene,
    through `engine` (mpm-ad, or the learned engine in `model`, from INVERSE_STARTS starts)."""
    starts = 1 if model is None else INVERSE_STARTS
    log(f"{'2' if model is None else '4'}. {name} back-calculation of c of the small dam's {FREE_MATERIAL} from the "
        f"MPM's deposit, at {scene.domain.cell_size:g} m cells, L-BFGS-B from {starts} start{'s' * (starts > 1)}")
    t0 = time.perf_counter()
    out.mkdir(parents=True, exist_ok=True)
    save_scene(scene, out / "scene.toml")
    target = cache.ensure([scene], progress=False)[0]
    spec = _write_spec(out, target, scene.materials[FREE_MATERIAL], quick, learned=model is not None)
    warnings: list[str] = []  # values outside a learned engine's training ranges: counted, not listed
    result = _replacing_quietly(lambda: invert(spec, out / "inverse", engine=engine, model=model, starts=starts,
                                               force=True, warn=warnings.append))
    evaluations = sum(r.evaluations for r in result.starts)
    truth = scene.materials[FREE_MATERIAL].cohesion
    (found,) = result.best.values
    log(f"   c = {found:.2f} kPa for a true {truth:g} kPa ({_percent(found, truth, digits=2)}) after {evaluations} "
        f"evaluation{'s' * (evaluations != 1)}; {_seconds(t0)}{_outside_training(len(warnings))}")
    best = result.best.out_dir
    pictures = (best / "parameters.png", best / "deposit.png")
    return (*pictures, out / "inverse" / "starts.png") if starts > 1 else pictures


def _replacing_quietly(run: Callable):
    """run(), leaving out the "--force removes ..." notice of a back-calculation that replaces
    the demo's own earlier one in its folder (meant for a user's folders); every other line
    it writes to stderr passes."""
    caught = io.StringIO()
    with contextlib.redirect_stderr(caught):
        result = run()
    sys.stderr.writelines(line for line in caught.getvalue().splitlines(keepends=True)
                          if not line.startswith("--force removes"))
    return result


def _mpm(cache: MpmCache, scene: Scene) -> Trajectory:
    return cache.load(scene, progress=False)


def _outside_training(count: int) -> str:
    """The words for `count` values (of a scene, or search bounds) outside the learned engine's
    training ranges."""
    if not count:
        return ""
    return f"; {count} values outside the model's training ranges (runout rollout and invert name them)"


def _flow_seconds(scene: Scene) -> float:
    return (scene.time.frames - 1) * scene.time.frame_dt


def _seconds(t0: float) -> str:
    return f"{time.perf_counter() - t0:.0f} s"


def _percent(value: float, truth: float, digits: int = 1) -> str:
    return f"{100 * (value - truth) / truth:+.{digits}f} %"


def _write_spec(out: Path, target: Path, material, quick: bool, learned: bool) -> Path:
    """The inverse spec: c of FREE_MATERIAL free in [10, 100] kPa, everything else as in the scene."""
    # At most 6 evaluations per learned start: in the shipped GNS's run each start had its answer
    # by the 6th (the later ones moved c by < 0.1 kPa: line searches in the loss's noise), and
    # each evaluation is a rollout with its gradient, 7-11 s on 2 cores. The MPM's 8 reach the
    # truth to 0.1 %.
    iterations, evaluations = (1, 2) if quick else (6, 6 if learned else 8)
    gtol = 1e6 if quick else 1e-8  # quick: L-BFGS-B stops after evaluating the start
    text = f"""# written by `runout demo`
scene = "scene.toml"

[target]
trajectory = "{Path(os.path.relpath(target, out)).as_posix()}"
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
