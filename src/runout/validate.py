"""Validation of the MPM against absolute references: theory, experiments and the paper's MPM.

Each case builds its scenes, runs the solver with the defaults a user gets, compares one
measured number with a reference band and says whether it is met. `run_validation` runs a
list of cases, draws one picture per case and writes a Markdown report. Units: m, s, kPa,
degrees. The references (see ../shared/reference/mpm-notes.md and the paper §5.1.1):

- vertical cut of height H in soil (phi, c), unit weight gamma: it stands by the lower-bound
  theorem for H <= 2 c / gamma tan(45 + phi / 2) (sigma_v = gamma z, sigma_h = 0 needs no
  tension); it must fail above the upper bound 3.83 c / gamma tan(45 + phi / 2);
- 2D dry granular columns (Lajeunesse et al. 2005, Lube et al. 2005, 2D DEM of Kumar 2015):
  L^n = (L_f - L_0) / L_0 between 1.2 a and 1.67 a for a <= 2.3, between 1.9 a^(2/3) and
  2.7 a^(2/3) above; the top keeps its height for a <= 0.6;
- the paper's MPM columns: L^n 0.848 (a = 1, phi 45, c 10), 1.088 (a = 1, phi 22.5, c 70),
  2.102 (a = 2, phi 33.75, c 10);
- Griffiths & Lane (1999) example 1: 2:1 slope, phi 20, c / (gamma H) = 0.05, FS = 1.4;
- a rigid block on a plane inclined at theta with Coulomb mu: s = g (sin theta - mu cos theta) t^2 / 2.
"""

from __future__ import annotations

import json
import math
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from runout.mpm import simulate
from runout.mpm.batch import BACKEND
from runout.mpm.geostatic import GRAVITY
from runout.scene import Scene, scene_from_dict

RHO = 1800.0  # kg/m^3, the paper's soils
GAMMA_KPA = RHO * GRAVITY / 1e3  # unit weight, kPa/m

PAPER_COLUMNS = (  # (name, width, height, phi, c kPa, paper's MPM L^n)
    ("a1_phi45_c10", 150.0, 150.0, 45.0, 10.0, 0.848),
    ("a1_phi22.5_c70", 150.0, 150.0, 22.5, 70.0, 1.088),
    ("a2_phi33.75_c10", 100.0, 200.0, 33.75, 10.0, 2.102),
)
DRY_ASPECTS = (0.5, 1.0, 2.0, 4.0)
DRY_PHI = 25.0


@dataclass
class CaseResult:
    """One check: the measured value against a reference band [low, high]."""

    case: str
    quantity: str
    measured: float
    low: float
    high: float
    reference: str
    figure: str = ""
    extra: dict = field(default_factory=dict)

    @property
    def met(self) -> bool:
        return bool(self.low <= self.measured <= self.high)


# ---------------------------------------------------------------- scenes


def _scene(regions, materials, width, height, cell, frames, **domain) -> Scene:
    return scene_from_dict({
        "domain": {"width": width, "height": height, "cell_size": cell, **domain},
        "time": {"frames": frames},
        "materials": materials,
        "regions": regions,
    })


def cut_scene(height: float, phi: float, c: float, cell: float, frames: int) -> Scene:
    """A vertical cut: a block 100 m wide and `height` tall against the left wall."""
    poly = [[0, 0], [100, 0], [100, height], [0, height]]
    top = math.ceil((height + 20) / cell) * cell
    return _scene([{"material": "soil", "polygon": poly}],
                  {"soil": {"friction_angle": phi, "cohesion": c}}, 300.0, top, cell, frames)


def column_scene(width: float, height: float, phi: float, c: float, cell: float, frames: int) -> Scene:
    """A column against the left wall on the rigid frictional base (the paper's setup)."""
    top = math.ceil((height + 8) / cell) * cell
    run_room = max(8.0 * width, 4.0 * height)
    domain_w = math.ceil((width + run_room) / cell) * cell
    return _scene([{"material": "soil", "polygon": [[0, 0], [width, 0], [width, height], [0, height]]}],
                  {"soil": {"friction_angle": phi, "cohesion": c}}, domain_w, top, cell, frames)


def griffiths_lane_scene(strength_factor: float, cell: float, frames: int, height: float = 40.0) -> Scene:
    """Griffiths & Lane example 1: a 2:1 slope of height H on a rigid base at toe level, phi 20,
    c = 0.05 gamma H; both strengths (c, tan phi) divided by strength_factor."""
    c = 0.05 * GAMMA_KPA * height / strength_factor
    phi = math.degrees(math.atan(math.tan(math.radians(20.0)) / strength_factor))
    poly = [[0, 0], [40 + 2 * height, 0], [40, height], [0, height]]
    width = math.ceil((40 + 2 * height + 120) / cell) * cell
    return _scene([{"material": "soil", "polygon": poly}], {"soil": {"friction_angle": phi, "cohesion": c}},
                  width, math.ceil((height + 8) / cell) * cell, cell, frames)


def incline_scene(theta: float, mu: float, cell: float, frames: int) -> Scene:
    """An elastic block (16 m x 8 m) resting on fixed ground inclined at theta with Coulomb mu."""
    t = math.radians(theta)
    length = 200.0
    x1, y1 = length * math.cos(t), length * math.sin(t)
    base = 2 * cell  # ground thickness below the plane at the low end
    width = math.ceil((x1 + 8) / cell) * cell
    height = math.ceil((y1 + base + 24) / cell) * cell
    ground = [[0, 0], [width, 0], [width, base], [x1, base], [0, base + y1]]
    # block on the plane near the top (the plane descends to the right from (0, base + y1))
    s0, w, h = 30.0, 16.0, 8.0
    d = np.array([math.cos(t), -math.sin(t)])  # down-slope
    n = np.array([math.sin(t), math.cos(t)])  # outward normal
    p0 = np.array([0.0, base + y1]) + s0 * d
    block = [p0, p0 + w * d, p0 + w * d + h * n, p0 + h * n]
    return _scene(
        [{"material": "ground", "polygon": ground, "fixed": True},
         {"material": "block", "polygon": [list(map(float, p)) for p in block]}],
        {"ground": {"model": "elastic"}, "block": {"model": "elastic"}},
        width, height, cell, frames, base_friction=mu,
    )


# ---------------------------------------------------------------- measures


def column_normalised_runout(traj, width: float) -> float:
    """L^n = (L_f - L_0) / L_0 of a column of width L_0 against the left wall, L_f the
    farthest soil point of the last frame (runout.metrics.normalised_runout is the formula
    for any two lengths)."""
    return float((traj.positions[-1, traj.soil, 0].max() - width) / width)


def column_normalised_runout_percentile(traj, width: float, q: float = 99.9) -> float:
    """L^n from the q-th percentile of the last frame's soil x instead of the farthest point,
    to show how much of L^n is a thin tail of a few points."""
    return float((np.percentile(traj.positions[-1, traj.soil, 0], q) - width) / width)


def largest_displacement(traj) -> float:
    return float(np.linalg.norm(traj.positions[:, traj.soil] - traj.positions[0, traj.soil], axis=2).max())


def dry_envelope(a: float) -> tuple[float, float]:
    """The experimental band of L^n for a dry 2D column of aspect ratio a (before the +-25 %)."""
    if a <= 2.3:
        return 1.2 * a, 1.67 * a
    return 1.9 * a ** (2 / 3), 2.7 * a ** (2 / 3)


# ---------------------------------------------------------------- cases


def case_cuts(cell: float, frames: int, backend: str = BACKEND) -> list[tuple[CaseResult, object, str]]:
    """Cuts 40 m high: stand at 0.8 of the lower bound, fail at 1.3 of the upper bound."""
    height = 40.0
    out, scenes, meta = [], [], []
    for phi in (0.0, 20.0):
        k = math.tan(math.radians(45 + phi / 2))
        c_stand = height * GAMMA_KPA / (0.8 * 2 * k)  # H = 0.8 x lower bound
        c_fail = height * GAMMA_KPA / (1.3 * 3.83 * k)  # H = 1.3 x upper bound
        scenes += [cut_scene(height, phi, c_stand, cell, frames), cut_scene(height, phi, c_fail, cell, frames)]
        meta += [(phi, c_stand, "stands"), (phi, c_fail, "fails")]
    for traj, (phi, c, what) in zip(simulate(scenes, progress=False, backend=backend), meta):
        d = largest_displacement(traj)
        if what == "stands":
            band, ref = (0.0, 1.0), f"H = 0.8 x 2c/gamma tan(45+phi/2) must stand: largest displacement < 1 m"
        else:
            band, ref = (4.0, math.inf), f"H = 1.3 x 3.83 c/gamma tan(45+phi/2) must fail: largest displacement > 4 m (0.1 H)"
        name = f"cut_phi{phi:g}_c{c:.0f}_{what}"
        res = CaseResult(name, "largest displacement (m)", d, *band, ref, extra={"phi": phi, "c_kpa": c})
        out.append((res, traj, "cut"))
    return out


def case_paper_columns(cell: float, frames: int, backend: str = BACKEND) -> list[tuple[CaseResult, object, str]]:
    scenes = [column_scene(w, h, phi, c, cell, frames) for _, w, h, phi, c, _ in PAPER_COLUMNS]
    out = []
    for traj, (name, w, h, phi, c, ref) in zip(simulate(scenes, progress=False, backend=backend), PAPER_COLUMNS):
        ln = column_normalised_runout(traj, w)
        res = CaseResult(f"column_{name}", "L^n", ln, 0.85 * ref, 1.15 * ref,
                         f"paper's MPM L^n = {ref} (within 15 %)",
                         extra={"width": w, "height": h, "reference": ref,
                                "Ln_p99.9": column_normalised_runout_percentile(traj, w)})
        out.append((res, traj, "column"))
    return out


def case_dry_columns(cell: float, frames: int, aspects=DRY_ASPECTS, base: float = 100.0,
                     backend: str = BACKEND) -> list[tuple[CaseResult, object, str]]:
    """Dry columns (c = 0, phi 25) of fixed height... of base `base` m (taller ones narrower)."""
    shapes = []
    for a in aspects:
        w = base if a <= 1 else base / a ** 0.5
        shapes.append((a, w, a * w))
    scenes = [column_scene(w, h, DRY_PHI, 0.0, cell, frames) for _, w, h in shapes]
    out = []
    for traj, (a, w, h) in zip(simulate(scenes, progress=False, backend=backend), shapes):
        lo, hi = dry_envelope(a)
        ln = column_normalised_runout(traj, w)
        res = CaseResult(f"dry_column_a{a:g}", "L^n", ln, 0.75 * lo, 1.25 * hi,
                         f"experiments/2D DEM {lo:.2f} ... {hi:.2f} (+-25 %)",
                         extra={"a": a, "width": w, "height": h, "Ln_p99.9": column_normalised_runout_percentile(traj, w)})
        out.append((res, traj, "column"))
        if a <= 0.6:
            top = float(traj.positions[-1, traj.soil, 1].max())
            out.append((CaseResult(f"dry_column_a{a:g}_top", "final top height (m)", top, h - cell, h + 0.5,
                                   f"the top keeps its height {h:g} m for a <= 0.6 (within one cell)"), traj, "column"))
    return out


def case_griffiths_lane(cell: float, frames: int, backend: str = BACKEND) -> list[tuple[CaseResult, object, str]]:
    scenes = [griffiths_lane_scene(1.0, cell, frames), griffiths_lane_scene(1.6, cell, frames)]
    t_stand, t_fail = simulate(scenes, progress=False, backend=backend)
    return [
        (CaseResult("griffiths_lane_fs1.4", "largest displacement (m)", largest_displacement(t_stand), 0.0, 1.0,
                    "FS = 1.4 (Griffiths & Lane 1999): stands, largest displacement < 1 m"), t_stand, "slope"),
        (CaseResult("griffiths_lane_strength_div1.6", "largest displacement (m)", largest_displacement(t_fail), 2.0, math.inf,
                    "strengths / 1.6 gives FS = 0.875: fails, largest displacement > 2 m"), t_fail, "slope"),
    ]


def case_incline(cell: float, frames: int, theta: float = 30.0, mu: float = 0.3,
                 backend: str = BACKEND) -> list[tuple[CaseResult, object, str]]:
    traj = simulate([incline_scene(theta, mu, cell, frames)], progress=False, backend=backend)[0]
    t = np.arange(traj.n_frames) * traj.frame_dt
    moving = traj.soil
    c0 = traj.positions[0, moving].mean(0)
    disp = traj.positions[:, moving].mean(1) - c0
    r = math.radians(theta)
    s = disp @ np.array([math.cos(r), -math.sin(r)])
    theory = 0.5 * GRAVITY * (math.sin(r) - mu * math.cos(r)) * t**2
    ratio = float(s[-1] / theory[-1])
    res = CaseResult(f"block_incline_theta{theta:g}_mu{mu:g}", "s / s_theory at the last frame", ratio, 0.97, 1.03,
                     "s = g (sin theta - mu cos theta) t^2 / 2 within 3 %",
                     extra={"t": t.tolist(), "s": s.tolist(), "theory": theory.tolist()})
    return [(res, traj, "incline")]


def case_convergence(cell: float, frames: int, backend: str = BACKEND) -> list[tuple[CaseResult, object, str]]:
    """The paper's a = 1 column (150 m) dry, phi 30: runout L_f - L_0 at dt and dt/2, and with
    2 x 2 and 3 x 3 points per cell; and the paper's a = 1, phi 45, c 10 kPa column at dt and
    dt/2 (the steep-friction case, where the runout moves most with the time step)."""
    w = 150.0
    base = column_scene(w, w, 30.0, 0.0, cell, frames)
    steep = column_scene(w, w, 45.0, 10.0, cell, frames)
    half = lambda scene: scene_from_dict({**_as_dict(scene), "time": {"frames": frames, "cfl": scene.time.cfl / 2}})  # noqa: E731
    dense = scene_from_dict({**_as_dict(base), "domain": {**_as_dict(base)["domain"], "points_per_cell": 3}})
    t0, t1, t2 = simulate([base, half(base), dense], progress=False, backend=backend)
    s0, s1 = simulate([steep, half(steep)], progress=False, backend=backend)
    out = []
    for name, ref, tr in (("dt/2", t0, t1), ("3x3 points", t0, t2), ("dt/2 phi45 c10", s0, s1)):
        r0 = ref.positions[-1, ref.soil, 0].max() - w
        r = tr.positions[-1, tr.soil, 0].max() - w
        change = float(abs(r - r0) / r0 * 100)
        out.append((CaseResult(f"convergence_{cell:g}m_{name.replace('/', '_').replace(' ', '_')}", "runout change (%)",
                               change, 0.0, 5.0, f"runout {r0:.1f} m -> {r:.1f} m with {name}: change < 5 %",
                               extra={"runout_m": float(r), "runout_base_m": float(r0)}), tr, "column"))
    return out


def _as_dict(scene: Scene) -> dict:
    from runout.scene import scene_to_dict

    return scene_to_dict(scene)


# ---------------------------------------------------------------- suite

CASES = {
    "cuts": case_cuts,
    "paper_columns": case_paper_columns,
    "dry_columns": case_dry_columns,
    "griffiths_lane": case_griffiths_lane,
    "incline": case_incline,
    "convergence": case_convergence,
}
QUICK = ("cuts", "griffiths_lane", "incline", "convergence")


def _cells(name: str, quick: bool) -> tuple[float, ...]:
    """Cell sizes a case runs at: the paper's 4 m; convergence also at 8 m (the CPU models'
    resolution). --quick keeps the small scenes at 4 m and runs convergence at 8 m only."""
    if name == "convergence":
        return (8.0,) if quick else (4.0, 8.0)
    return (4.0,)


def run_validation(out: Path, quick: bool = False, cases=None, report: Path | None = None,
                   command: str = "runout validate", progress=print, backend: str = BACKEND) -> list[CaseResult]:
    """Run the cases (at the cell sizes of _cells) on the MPM `backend` (runout.mpm.batch),
    draw each, write results.json and the Markdown report. Returns the results."""
    from runout.validate_figures import draw_case

    out.mkdir(parents=True, exist_ok=True)
    names = list(cases or (QUICK if quick else CASES))
    results: list[CaseResult] = []
    for name in names:
        for cell in _cells(name, quick):
            frames = 300 if name in ("cuts", "griffiths_lane") else 120 if name == "incline" else 600
            start = time.perf_counter()
            items = CASES[name](cell, frames, backend=backend)
            wall = time.perf_counter() - start
            for res, traj, kind in items:
                res.extra["cell_m"] = cell
                res.extra["wall_s"] = round(wall, 1)
                res.extra["backend"] = backend
                res.figure = draw_case(res, traj, kind, out)
                results.append(res)
                progress(f"{res.case}: {res.quantity} = {res.measured:.3f} "
                         f"[{res.low:.3g}, {res.high:.3g}] {'met' if res.met else 'NOT met'}")
    (out / "results.json").write_text(json.dumps(
        [{**{k: v for k, v in asdict(r).items() if k != "extra"}, "met": r.met,
          "extra": {k: v for k, v in r.extra.items() if k not in ("t", "s", "theory")}} for r in results],
        indent=1, default=float))
    write_report(results, report or out / "validation.md", command, out)
    return results


def write_report(results: list[CaseResult], path: Path, command: str, figures: Path) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    met = sum(r.met for r in results)
    lines = [
        "# MPM validation",
        "",
        f"Made by `{command}` ({met} of {len(results)} checks met). Every number is measured by that",
        "command with the solver's defaults; the bands are the references of src/runout/validate.py.",
        "Why the solver makes the choices it makes, and what is still open: docs/scene-format.md",
        "(\"The solver's choices, and why\").",
        "",
        "| case | quantity | measured | allowed | reference | met | cell (m) | figure |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in results:
        hi = "inf" if math.isinf(r.high) else f"{r.high:.3g}"
        fig = Path(r.figure)
        try:
            rel = fig.relative_to(path.parent)
        except ValueError:
            rel = fig
        lines.append(f"| {r.case} | {r.quantity} | {r.measured:.3f} | [{r.low:.3g}, {hi}] | {r.reference} | "
                     f"{'yes' if r.met else '**no**'} | {r.extra.get('cell_m', '')} | [png]({rel}) |")
    by_cell = {r.extra.get("cell_m"): r.extra["runout_base_m"] for r in results
               if r.case.startswith("convergence_") and "phi45" not in r.case and "runout_base_m" in r.extra}
    if 4.0 in by_cell and 8.0 in by_cell:
        r4, r8 = by_cell[4.0], by_cell[8.0]
        lines += ["", f"Resolution: the convergence column's runout L_f - L_0 is {r4:.1f} m at 4 m cells and "
                  f"{r8:.1f} m at 8 m cells ({(r8 - r4) / r4 * 100:+.1f} %), the change a model trained at 8 m "
                  "inherits."]
    path.write_text("\n".join(lines) + "\n")


def report_from_json(results_json: Path, path: Path, command: str) -> None:
    """Rewrite the Markdown report from a results.json (after editing the report's layout)."""
    rows = json.loads(Path(results_json).read_text())
    results = [CaseResult(d["case"], d["quantity"], d["measured"], d["low"], d["high"], d["reference"],
                          d["figure"], d["extra"]) for d in rows]
    write_report(results, path, command, Path(results_json).parent)
