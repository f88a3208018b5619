"""The hazard spec (TOML, docs/hazard.md): a scene, a distribution of φ (degrees) and c (kPa)
per uncertain material, how many realisations, the sampler and the thickness thresholds (m).

Every value is checked before anything runs; a wrong one is an InputError of one sentence
naming the file, the field, the value and the allowed range (exit 2).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from pathlib import Path

from runout import checks
from runout.errors import InputError
from runout.reading import read_toml
from runout.scene import MAX_FRAMES, MAX_STRENGTH, Scene, load_scene
from runout.scene.files import check_keys

# spec key -> (Material field, unit, physical lower bound, physical upper bound)
PROPERTIES = {"phi": ("friction_angle", "degrees", 0.0, 60.0), "c": ("cohesion", "kPa", 0.0, MAX_STRENGTH)}
DISTRIBUTIONS = ("normal", "lognormal", "uniform")
SAMPLERS = ("lhs", "sobol")
MAX_REALISATIONS = 1_000_000
MAX_BATCH = 1024
MAX_THRESHOLDS = 32

_TOP_KEYS = {"scene", "realisations", "sampler", "seed", "batch", "frames", "cell_size", "thresholds", "bin_width",
             "materials"}
_MATERIAL_KEYS = {"phi", "c", "correlation"}
_DISTRIBUTION_KEYS = {"distribution", "mean", "std", "lower", "upper"}


@dataclass(frozen=True)
class Distribution:
    """One uncertain strength: normal or lognormal (mean, std of the value itself) or uniform
    on [lower, upper], always truncated to [lower, upper] (defaults: the physical bounds)."""

    kind: str
    mean: float
    std: float
    lower: float
    upper: float


@dataclass(frozen=True)
class MaterialUncertainty:
    """The distributions of one material's φ and c (None: the scene's value, fixed) and the
    correlation of their normal scores (a Gaussian copula, in [-1, 1])."""

    phi: Distribution | None
    c: Distribution | None
    correlation: float = 0.0


@dataclass(frozen=True)
class HazardSpec:
    scene: Scene  # with the spec's frames and cell size
    scene_path: Path
    materials: dict[str, MaterialUncertainty]
    realisations: int
    sampler: str = "lhs"
    seed: int = 0
    batch: int = 16  # realisations per MPM batch and per part file
    thresholds: tuple[float, ...] = (1.0,)  # m of deposit thickness
    bin_width: float = 0.0  # m along x; 0: the scene's cell size

    @property
    def n_batches(self) -> int:
        return -(-self.realisations // self.batch)

    def batch_indices(self, j: int) -> range:
        return range(j * self.batch, min((j + 1) * self.batch, self.realisations))

    def inputs(self) -> list[tuple[str, str]]:
        """The uncertain inputs in sampling order: (material, "phi" or "c")."""
        return [(name, prop) for name, m in self.materials.items() for prop in ("phi", "c") if getattr(m, prop)]

    def record(self) -> dict:
        """Plain data naming everything the results depend on (hazard.json)."""
        return {
            "scene": str(self.scene_path), "realisations": self.realisations, "sampler": self.sampler, "seed": self.seed,
            "batch": self.batch, "frames": self.scene.time.frames, "cell_size": self.scene.domain.cell_size,
            "thresholds": list(self.thresholds), "bin_width": self.bin_width,
            "materials": {name: {"phi": _plain(m.phi), "c": _plain(m.c), "correlation": m.correlation}
                          for name, m in self.materials.items()},
        }


def _plain(d: Distribution | None) -> dict | None:
    return None if d is None else {"distribution": d.kind, "mean": d.mean, "std": d.std, "lower": d.lower, "upper": d.upper}


def load_spec(path: str | Path) -> HazardSpec:
    """The checked spec of a TOML file; the scene path is relative to the spec's folder."""
    path = Path(path)
    data = read_toml(path, "hazard spec")
    check_keys(data, _TOP_KEYS, "top level", path)
    if not isinstance(data.get("scene"), str):
        raise InputError(f"{path}: scene = {checks.show(data.get('scene'))} must name a scene file (TOML or JSON).")
    scene_path = path.parent / data["scene"]
    scene = _scene_for(load_scene(scene_path), data, path)
    materials = _materials(data.get("materials"), scene, path)
    realisations = checks.number(data.get("realisations"), "realisations", path, 1, MAX_REALISATIONS, whole=True)
    sampler = data.get("sampler", "lhs")
    if sampler not in SAMPLERS:
        raise InputError(f"{path}: sampler = {checks.show(sampler)} must be one of {', '.join(SAMPLERS)}.")
    thresholds = data.get("thresholds", [1.0])
    if not isinstance(thresholds, list) or not 1 <= len(thresholds) <= MAX_THRESHOLDS:
        raise InputError(f"{path}: thresholds = {checks.show(thresholds)} must be a list of 1 to {MAX_THRESHOLDS} "
                         "thicknesses in m.")
    for k, h in enumerate(thresholds):
        checks.number(h, f"thresholds[{k}]", path, 0.0, scene.domain.height, " m", lo_open=True)
    bin_width = checks.number(data.get("bin_width", scene.domain.cell_size), "bin_width", path, 0.0,
                              scene.domain.width / 2, " m", lo_open=True)
    return HazardSpec(
        scene=scene, scene_path=scene_path, materials=materials, realisations=realisations, sampler=sampler,
        seed=checks.number(data.get("seed", 0), "seed", path, 0, 2**32 - 1, whole=True),
        batch=checks.number(data.get("batch", 16), "batch", path, 1, MAX_BATCH, whole=True),
        thresholds=tuple(float(h) for h in thresholds), bin_width=float(bin_width),
    )


def _scene_for(scene: Scene, data: dict, path: Path) -> Scene:
    """The scene with the spec's frames and cell size (m), when it gives them."""
    if "frames" in data:
        scene = scene.with_frames(checks.number(data["frames"], "frames", path, 2, MAX_FRAMES, whole=True))
    if "cell_size" in data:
        cell = checks.number(data["cell_size"], "cell_size", path, 1.0, 64.0, " m")
        scene = replace(scene, domain=replace(scene.domain, cell_size=float(cell)))
    return scene


def _materials(table, scene: Scene, path: Path) -> dict[str, MaterialUncertainty]:
    if not isinstance(table, dict) or not table:
        raise InputError(f"{path}: [materials] must give at least one material of the scene "
                         f"({', '.join(scene.material_names)}) a distribution of phi or c.")
    out = {}
    for name, entry in table.items():
        if name not in scene.materials:
            raise InputError(f"{path}: materials.{name} is not a material of the scene; the scene has "
                             f"{', '.join(scene.material_names)}.")
        check_keys(entry, _MATERIAL_KEYS, f"materials.{name}", path)
        dists = {prop: _distribution(entry[prop], f"materials.{name}.{prop}", prop, path) if prop in entry else None
                 for prop in PROPERTIES}
        if dists["phi"] is None and dists["c"] is None:
            raise InputError(f"{path}: materials.{name} must give phi or c a distribution.")
        rho = checks.number(entry.get("correlation", 0.0), f"materials.{name}.correlation", path, -1.0, 1.0)
        if rho and None in dists.values():
            raise InputError(f"{path}: materials.{name}.correlation = {checks.show(rho)} needs distributions of both phi and c.")
        out[name] = MaterialUncertainty(dists["phi"], dists["c"], float(rho))
    return out


def _distribution(table, field: str, prop: str, path: Path) -> Distribution:
    """One checked Distribution; bounds default to the physical range of `prop`."""
    check_keys(table, _DISTRIBUTION_KEYS, field, path)
    _, unit, lo, hi = PROPERTIES[prop]
    kind = table.get("distribution")
    if kind not in DISTRIBUTIONS:
        raise InputError(f"{path}: {field}.distribution = {checks.show(kind)} must be one of {', '.join(DISTRIBUTIONS)}.")
    lower = float(checks.number(table.get("lower", lo), f"{field}.lower", path, lo, hi, f" {unit}"))
    upper = float(checks.number(table.get("upper", hi), f"{field}.upper", path, lo, hi, f" {unit}"))
    if upper < lower:
        raise InputError(f"{path}: {field}.upper = {upper:g} {unit} must be at least {field}.lower = {lower:g} {unit}.")
    if kind == "uniform":
        return Distribution(kind, (lower + upper) / 2, (upper - lower) / math.sqrt(12), lower, upper)
    mean = float(checks.number(table.get("mean"), f"{field}.mean", path, lower, upper, f" {unit}",
                               lo_open=kind == "lognormal" and lower == 0.0))  # a lognormal value is above 0
    std = float(checks.number(table.get("std"), f"{field}.std", path, 0.0, hi, f" {unit}"))
    return Distribution(kind, mean, std, lower, upper)
