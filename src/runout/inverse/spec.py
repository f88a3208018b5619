"""The inverse spec: which material strengths to find, from which observation (TOML).

Units: friction angle phi in degrees, cohesion c in kPa, positions in metres. Frames are
0-based indices of the target trajectory; frame 0 is the scene at rest, where every engine
starts (a GNS's window holds copies of it), so the first frame one can observe is frame 1.
See docs/inverse-format.md.
"""

from __future__ import annotations

import hashlib
import json
import math
from dataclasses import dataclass, replace
from pathlib import Path

from runout.errors import InputError
from runout.reading import read_toml
from runout.scene import MAX_STRENGTH, Scene, load_scene
from runout.scene.limits import SMALLEST_SIZE
from runout.scene.files import check_keys


# spec key -> (Material field, unit, smallest allowed value, largest allowed value)
PROPERTIES = {
    "phi": ("friction_angle", "degrees", 0.0, 60.0),
    "c": ("cohesion", "kPa", 0.0, MAX_STRENGTH),
}
WEIGHTINGS = ("uniform", "displacement")
LOSS_KINDS = ("positions", "thickness")

_TOP_KEYS = {"scene", "target", "parameters", "loss", "optimiser", "rollout"}
_TARGET_KEYS = {"trajectory", "positions", "frames"}
_LOSS_KEYS = {"kind", "weighting", "front_weight", "bin_width"}
_OPTIMISER_KEYS = {"max_iterations", "max_evaluations", "ftol", "gtol"}
_ROLLOUT_KEYS = {"steps"}
_FREE_KEYS = {"initial", "lower", "upper"}


@dataclass(frozen=True)
class FreeParameter:
    """One optimised property of one material, in physical units, with its box bounds."""

    material: str
    prop: str  # "phi" (degrees) or "c" (kPa)
    initial: float
    lower: float
    upper: float

    @property
    def name(self) -> str:
        return f"{self.prop}[{self.material}]"

    @property
    def unit(self) -> str:
        return PROPERTIES[self.prop][1]

    @property
    def field(self) -> str:
        """The Material attribute this parameter sets."""
        return PROPERTIES[self.prop][0]

    def normalise(self, value: float) -> float:
        return (value - self.lower) / (self.upper - self.lower)

    def physical(self, u: float) -> float:
        return self.lower + u * (self.upper - self.lower)


@dataclass(frozen=True)
class TargetSpec:
    trajectory: Path | None  # directory (or .npz) written by `runout mpm`
    positions: Path | None  # .npy of observed positions [N, 2] or [F, N, 2] (m)
    frames: tuple[int, ...] | None  # None: the final frame only


@dataclass(frozen=True)
class LossSpec:
    kind: str = "positions"  # or "thickness": the soil's thickness profile along x (runout.inverse.loss)
    weighting: str = "uniform"  # or "displacement": w = 1 + front_weight * |d| / max |d| (positions only)
    front_weight: float = 4.0
    bin_width: float | None = None  # m, the thickness profile's bins; None: two point spacings


@dataclass(frozen=True)
class OptimiserSpec:
    max_iterations: int = 30
    max_evaluations: int = 60
    ftol: float = 1e-10  # L-BFGS-B: stop when the loss (m^2) falls by less than this, relatively
    gtol: float = 1e-8  # L-BFGS-B: stop when the projected normalised gradient is this small


@dataclass(frozen=True)
class InverseSpec:
    source: Path
    scene_path: Path  # the scene file the spec names
    scene: Scene  # with every `fixed` value applied; free values are set per evaluation
    target: TargetSpec
    free: tuple[FreeParameter, ...]
    loss: LossSpec
    optimiser: OptimiserSpec
    steps: int | None  # rollout steps; None: as far as the last observed frame
    digest: str  # sha256 of the problem (spec less [optimiser]): a resumed run must match it

    @property
    def names(self) -> list[str]:
        return [p.name for p in self.free]

    def initial_normalised(self) -> list[float]:
        return [p.normalise(p.initial) for p in self.free]

    def scene_at(self, values) -> Scene:
        """The scene with the free parameters set to `values` (physical units)."""
        changes: dict[str, dict[str, float]] = {}
        for p, v in zip(self.free, values):
            changes.setdefault(p.material, {})[p.field] = float(v)
        return self.scene.with_materials(**changes)


def load_inverse_spec(path: str | Path) -> InverseSpec:
    """Read and check an inverse spec file; raise InputError with one sentence on any fault."""
    path = Path(path)
    data = read_toml(path, "inverse spec file")
    return spec_from_dict(data, path, problem_digest(data))


def problem_digest(data: dict) -> str:
    """sha256 of everything but the [optimiser] limits, so a finished run can be continued
    with a larger max_iterations from its history."""
    problem = {k: v for k, v in data.items() if k != "optimiser"}
    return hashlib.sha256(json.dumps(problem, sort_keys=True, default=str).encode()).hexdigest()


def spec_from_dict(data: dict, source: Path, digest: str = "") -> InverseSpec:
    check_keys(data, _TOP_KEYS, "top level", source)
    if "scene" not in data or not isinstance(data["scene"], str):
        raise InputError(f"{source}: 'scene' must name a scene file, e.g. scene = \"dam.toml\".")
    scene_path = _relative(source, data["scene"])
    scene = load_scene(scene_path)
    fixed, free = _parameters(data.get("parameters", {}), scene, source)
    scene = scene.with_materials(**fixed) if fixed else scene
    return InverseSpec(
        source=source,
        scene_path=scene_path,
        scene=scene,
        target=_target(data.get("target"), source),
        free=free,
        loss=_loss(data.get("loss", {}), source),
        optimiser=_optimiser(data.get("optimiser", {}), source),
        steps=_rollout_steps(data.get("rollout", {}), source),
        digest=digest,
    )


def _relative(source: Path, name: str) -> Path:
    """Paths in a spec are relative to the spec file's folder."""
    p = Path(name).expanduser()
    return p if p.is_absolute() else source.parent / p


def _number(table: dict, key: str, where: str, source: Path) -> float:
    value = table[key]
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise InputError(f"{source}: {where}.{key} = {value!r} must be a finite number.")
    return float(value)


def _whole(table: dict, key: str, where: str, source: Path, default: int) -> int:
    value = table.get(key, default)
    if isinstance(value, bool) or not isinstance(value, int) or value < 1:
        raise InputError(f"{source}: {where}.{key} = {value!r} must be a positive whole number.")
    return value


# ----------------------------------------------------------------------------- parameters


def _parameters(table, scene: Scene, source: Path):
    """Split [parameters.<material>] tables into fixed changes and free parameters."""
    if not isinstance(table, dict):
        raise InputError(f"{source}: [parameters] must be a table of materials.")
    unknown = sorted(set(table) - set(scene.materials))
    if unknown:
        raise InputError(
            f"{source}: parameters.{unknown[0]} is not a material of the scene; its materials are "
            f"{', '.join(scene.materials)}."
        )
    fixed: dict[str, dict[str, float]] = {}
    free: list[FreeParameter] = []
    for material, props in table.items():
        check_keys(props, set(PROPERTIES), f"parameters.{material}", source)
        for prop, entry in props.items():
            where = f"parameters.{material}.{prop}"
            if isinstance(entry, dict) and "fixed" in entry:
                fixed.setdefault(material, {})[PROPERTIES[prop][0]] = _fixed(entry, prop, where, source)
            else:
                free.append(_free(entry, material, prop, where, source))
    if not free:
        raise InputError(f"{source}: nothing to optimise; give at least one property 'lower' and 'upper' bounds.")
    for p in free:
        _check_deformable(scene, p, source)
    return fixed, tuple(free)


def _fixed(entry: dict, prop: str, where: str, source: Path) -> float:
    check_keys(entry, {"fixed"}, where, source)
    value = _number(entry, "fixed", where, source)
    _check_allowed(value, prop, where + ".fixed", source)
    return value


def _free(entry, material: str, prop: str, where: str, source: Path) -> FreeParameter:
    check_keys(entry, _FREE_KEYS, where, source)
    for key in ("lower", "upper"):
        if key not in entry:
            raise InputError(f"{source}: {where} needs either 'fixed' or both 'lower' and 'upper'.")
    lower = _number(entry, "lower", where, source)
    upper = _number(entry, "upper", where, source)
    unit = PROPERTIES[prop][1]
    if not lower < upper:
        raise InputError(f"{source}: {where} has lower = {lower:g} not below upper = {upper:g} {unit}.")
    _check_allowed(lower, prop, where + ".lower", source)
    _check_allowed(upper, prop, where + ".upper", source)
    initial = _number(entry, "initial", where, source) if "initial" in entry else 0.5 * (lower + upper)
    if not lower <= initial <= upper:
        raise InputError(
            f"{source}: {where}.initial = {initial:g} is outside its bounds [{lower:g}, {upper:g}] {unit}."
        )
    return FreeParameter(material, prop, initial, lower, upper)


def _check_allowed(value: float, prop: str, where: str, source: Path) -> None:
    _, unit, lo, hi = PROPERTIES[prop]
    if not lo <= value <= hi:
        hi_txt = "inf" if hi == math.inf else f"{hi:g}"
        raise InputError(f"{source}: {where} = {value:g} is outside the allowed range [{lo:g}, {hi_txt}] {unit}.")


def _check_deformable(scene: Scene, p: "FreeParameter", source: Path) -> None:
    regions = [r for r in scene.regions if r.material == p.material]
    if not regions or all(r.fixed for r in regions):
        raise InputError(
            f"{source}: material '{p.material}' has no moving (non-fixed) region, so its strength cannot affect the runout."
        )
    if scene.materials[p.material].model == "elastic":
        raise InputError(
            f"{source}: parameters.{p.material}.{p.prop} cannot be optimised, because material '{p.material}' is "
            "elastic and has no strength (give it model = \"mohr-coulomb\" in the scene)."
        )


# ----------------------------------------------------------------------------- other tables


def _target(table, source: Path) -> TargetSpec:
    if table is None:
        raise InputError(f"{source}: the spec has no [target] section.")
    check_keys(table, _TARGET_KEYS, "target", source)
    given = [k for k in ("trajectory", "positions") if k in table]
    if len(given) != 1:
        raise InputError(f"{source}: [target] must give exactly one of 'trajectory' or 'positions'.")
    path_value = table[given[0]]
    if not isinstance(path_value, str):
        raise InputError(f"{source}: target.{given[0]} must be a path string.")
    path = _relative(source, path_value)
    return TargetSpec(
        trajectory=path if given[0] == "trajectory" else None,
        positions=path if given[0] == "positions" else None,
        frames=_frames(table.get("frames", "final"), source),
    )


def _frames(value, source: Path) -> tuple[int, ...] | None:
    if value == "final":
        return None
    ok = isinstance(value, list) and value and all(isinstance(f, int) and not isinstance(f, bool) for f in value)
    if not ok:
        raise InputError(f"{source}: target.frames must be \"final\" or a list of frame numbers, e.g. [200, 479].")
    if len(set(value)) != len(value) or sorted(value) != value:
        raise InputError(f"{source}: target.frames = {value} must be increasing without repeats.")
    if value[0] < 1:
        raise InputError(f"{source}: target.frames starts at {value[0]}, but frame 0 is the scene at rest; observe frame 1 or later.")
    return tuple(value)


def _loss(table, source: Path) -> LossSpec:
    check_keys(table, _LOSS_KEYS, "loss", source)
    weighting = table.get("weighting", "uniform")
    if weighting not in WEIGHTINGS:
        raise InputError(f"{source}: loss.weighting = {weighting!r} must be one of {', '.join(WEIGHTINGS)}.")
    kind = table.get("kind", "positions")
    if kind not in LOSS_KINDS:
        raise InputError(f"{source}: loss.kind = {kind!r} must be one of {', '.join(LOSS_KINDS)}.")
    if kind == "thickness" and weighting != "uniform":
        raise InputError(f"{source}: loss.weighting = {weighting!r} weights points, which loss.kind = \"thickness\" "
                         "does not compare one by one; leave weighting out or use kind = \"positions\".")
    if kind == "positions" and "bin_width" in table:
        raise InputError(f"{source}: loss.bin_width sets the bins of loss.kind = \"thickness\"; "
                         "the positions loss has none, so leave it out.")
    spec = LossSpec(kind=kind, weighting=weighting)
    if "front_weight" in table:
        w = _number(table, "front_weight", "loss", source)
        if w < 0:
            raise InputError(f"{source}: loss.front_weight = {w:g} must be zero or positive.")
        spec = replace(spec, front_weight=w)
    if "bin_width" in table:
        b = _number(table, "bin_width", "loss", source)
        if not SMALLEST_SIZE <= b <= 1000:  # a subnormal width would make the bins overflow
            raise InputError(f"{source}: loss.bin_width = {b:g} m is outside the allowed range (0, 1000] m.")
        spec = replace(spec, bin_width=b)
    return spec


def _optimiser(table, source: Path) -> OptimiserSpec:
    check_keys(table, _OPTIMISER_KEYS, "optimiser", source)
    d = OptimiserSpec()
    tols = {}
    for key in ("ftol", "gtol"):
        if key in table:
            tols[key] = _number(table, key, "optimiser", source)
            if tols[key] <= 0:
                raise InputError(f"{source}: optimiser.{key} = {tols[key]:g} must be positive.")
    return replace(
        d,
        max_iterations=_whole(table, "max_iterations", "optimiser", source, d.max_iterations),
        max_evaluations=_whole(table, "max_evaluations", "optimiser", source, d.max_evaluations),
        **tols,
    )


def _rollout_steps(table, source: Path) -> int | None:
    check_keys(table, _ROLLOUT_KEYS, "rollout", source)
    return _whole(table, "steps", "rollout", source, 1) if "steps" in table else None
