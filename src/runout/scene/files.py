"""Scene files: TOML (or JSON with the same keys) to Scene and back; see docs/scene-format.md.

A value a file leaves out takes the dataclass default (runout.scene.model, from runout.defaults).
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict
from pathlib import Path

from runout.defaults import FLIP_WAVE, ROUGH
from runout.errors import InputError
from runout.reading import read_json, read_toml
from runout.scene.model import Domain, Material, Region, Scene, TimeSpec, check_scene

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"  # the example scene files, shipped as package data

_DOMAIN_KEYS = {"width", "height", "cell_size", "points_per_cell", "base_friction", "wall_friction"}
_TIME_KEYS = {"frame_dt", "frames", "cfl", "flip", "damping"}
_MATERIAL_KEYS = {
    "model", "friction_angle", "cohesion", "youngs_modulus", "poisson_ratio", "density", "k0",
    "tension_cutoff",
}
_REGION_KEYS = {"material", "polygon", "velocity", "fixed"}
_TOP_KEYS = {"domain", "time", "materials", "regions", "name"}


def check_keys(table, allowed: set[str], where: str, source) -> None:
    """InputError unless `table` is a table whose keys are all in `allowed` (scene and spec files)."""
    if not isinstance(table, dict):
        raise InputError(f"{source}: [{where}] is a {type(table).__name__}; it must be a table of keys.")
    unknown = sorted(set(table) - allowed)
    if unknown:
        raise InputError(
            f"{source}: unknown key '{unknown[0]}' in [{where}]; allowed keys are "
            f"{', '.join(sorted(allowed))}."
        )


def _number(table: dict, key: str, where: str, source: str, default=None) -> float:
    if key not in table:
        if default is None:
            raise InputError(f"{source}: [{where}] is missing the required key '{key}'.")
        return default
    value = table[key]
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise InputError(f"{source}: {where}.{key} = {value!r} must be a finite number.")
    return float(value)


def _friction(table: dict, key: str, source: str, default: float) -> float:
    """A Coulomb coefficient, or "rough" (no slip: math.inf)."""
    if table.get(key) == "rough":
        return ROUGH
    if isinstance(table.get(key), str):
        raise InputError(f"{source}: domain.{key} = {table[key]!r} must be a number in [0, 10] or \"rough\".")
    return _number(table, key, "domain", source, default)


def _flip(table: dict, source: str) -> float | str:
    """The FLIP share: "wave" (a fixed rate in time, the default) or a fixed share per substep."""
    if table.get("flip") == FLIP_WAVE:
        return FLIP_WAVE
    if isinstance(table.get("flip"), str):
        raise InputError(f"{source}: time.flip = {table['flip']!r} must be a number in [0, 1] or \"wave\".")
    return _number(table, "flip", "time", source, TimeSpec.flip)


def scene_from_dict(data: dict, source: str = "<scene>") -> Scene:
    """Build and check a Scene from the dictionary form of a scene file."""
    check_keys(data, _TOP_KEYS, "top level", source)
    for required in ("domain", "materials", "regions"):
        if required not in data:
            raise InputError(f"{source}: the scene has no [{required}] section.")

    d = data["domain"]
    check_keys(d, _DOMAIN_KEYS, "domain", source)
    ppc = d.get("points_per_cell", Domain.points_per_cell)
    if isinstance(ppc, bool) or not isinstance(ppc, int):
        raise InputError(f"{source}: domain.points_per_cell = {ppc!r} must be a whole number in [1, 6].")
    domain = Domain(
        width=_number(d, "width", "domain", source),
        height=_number(d, "height", "domain", source),
        cell_size=_number(d, "cell_size", "domain", source, Domain.cell_size),
        points_per_cell=ppc,
        base_friction=_friction(d, "base_friction", source, Domain.base_friction),
        wall_friction=_number(d, "wall_friction", "domain", source, Domain.wall_friction),
    )

    t = data.get("time", {})
    check_keys(t, _TIME_KEYS, "time", source)
    frames = t.get("frames", TimeSpec.frames)
    if isinstance(frames, bool) or not isinstance(frames, int):
        raise InputError(f"{source}: time.frames = {frames!r} must be a positive whole number.")
    time = TimeSpec(
        frame_dt=_number(t, "frame_dt", "time", source, TimeSpec.frame_dt),
        frames=frames,
        cfl=_number(t, "cfl", "time", source, TimeSpec.cfl),
        flip=_flip(t, source),
        damping=_number(t, "damping", "time", source, TimeSpec.damping),
    )

    mats_in = data["materials"]
    if not isinstance(mats_in, dict) or not mats_in:
        raise InputError(f"{source}: [materials] must define at least one material table.")
    materials = {}
    for name, m in mats_in.items():
        where = f"materials.{name}"
        check_keys(m, _MATERIAL_KEYS, where, source)
        model = m.get("model", Material.model)
        if model not in ("mohr-coulomb", "elastic"):
            raise InputError(f"{source}: {where}.model = {model!r} must be 'mohr-coulomb' or 'elastic'.")
        k0 = m.get("k0")
        materials[name] = Material(
            name=name,
            model=model,
            friction_angle=_number(m, "friction_angle", where, source, Material.friction_angle),
            cohesion=_number(m, "cohesion", where, source, Material.cohesion),
            youngs_modulus=_number(m, "youngs_modulus", where, source, Material.youngs_modulus),
            poisson_ratio=_number(m, "poisson_ratio", where, source, Material.poisson_ratio),
            density=_number(m, "density", where, source, Material.density),
            k0=None if k0 is None else _number(m, "k0", where, source),
            tension_cutoff=_number(m, "tension_cutoff", where, source, Material.tension_cutoff),
        )

    regions_in = data["regions"]
    if not isinstance(regions_in, list) or not regions_in:
        raise InputError(f"{source}: [[regions]] must list at least one region.")
    regions = []
    for k, r in enumerate(regions_in):
        where = f"regions[{k}]"
        check_keys(r, _REGION_KEYS, where, source)
        if "material" not in r:
            raise InputError(f"{source}: {where} is missing the required key 'material'.")
        if "polygon" not in r:
            raise InputError(f"{source}: {where} is missing the required key 'polygon'.")
        poly = r["polygon"]
        if (
            not isinstance(poly, list)
            or len(poly) < 3
            or not all(isinstance(p, list) and len(p) == 2 for p in poly)
            or not all(isinstance(v, (int, float)) and not isinstance(v, bool) for p in poly for v in p)
        ):
            raise InputError(
                f"{source}: {where}.polygon must be a list of at least 3 [x, y] pairs of numbers (m)."
            )
        vel = r.get("velocity", [0.0, 0.0])
        if not (isinstance(vel, list) and len(vel) == 2 and all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in vel)):
            raise InputError(f"{source}: {where}.velocity must be a pair [vx, vy] of numbers (m/s).")
        fixed = r.get("fixed", False)
        if not isinstance(fixed, bool):
            raise InputError(f"{source}: {where}.fixed = {fixed!r} must be true or false.")
        regions.append(
            Region(
                material=str(r["material"]),
                polygon=tuple((float(x), float(y)) for x, y in poly),
                velocity=(float(vel[0]), float(vel[1])),
                fixed=fixed,
            )
        )
    scene = Scene(domain, materials, tuple(regions), time, str(data.get("name", Path(source).stem)))
    check_scene(scene, source)
    return scene


def load_scene(path: str | Path) -> Scene:
    """Read a TOML (or JSON) scene file; raise InputError naming what is wrong."""
    path = Path(path)
    read = read_json if path.suffix.lower() == ".json" else read_toml
    data = read(path, "scene file")
    check_keys(data, _TOP_KEYS, "top level", path)
    return scene_from_dict({"name": path.stem, **data}, str(path))


def scene_to_dict(scene: Scene) -> dict:
    out = {
        "name": scene.name,
        "domain": {k: ("rough" if k == "base_friction" and v == ROUGH else v)
                   for k, v in asdict(scene.domain).items()},
        "time": asdict(scene.time),
        "materials": {},
        "regions": [],
    }
    for name, m in scene.materials.items():
        md = asdict(m)
        md.pop("name")
        if md["k0"] is None:
            md.pop("k0")
        out["materials"][name] = md
    for r in scene.regions:
        out["regions"].append(
            {
                "material": r.material,
                "polygon": [list(p) for p in r.polygon],
                "velocity": list(r.velocity),
                "fixed": r.fixed,
            }
        )
    return out


def _toml_value(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        return repr(v)
    if isinstance(v, str):
        return json.dumps(v)
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    raise TypeError(f"cannot write {type(v).__name__} to TOML")


def scene_to_toml(scene: Scene) -> str:
    """The scene as a TOML scene file (the inverse of load_scene)."""
    d = scene_to_dict(scene)
    lines = [f"name = {_toml_value(d['name'])}", "", "[domain]"]
    lines += [f"{k} = {_toml_value(v)}" for k, v in d["domain"].items()]
    lines += ["", "[time]"] + [f"{k} = {_toml_value(v)}" for k, v in d["time"].items()]
    for name, m in d["materials"].items():
        lines += ["", f"[materials.{json.dumps(name)}]"]
        lines += [f"{k} = {_toml_value(v)}" for k, v in m.items()]
    for r in d["regions"]:
        lines += ["", "[[regions]]"] + [f"{k} = {_toml_value(v)}" for k, v in r.items()]
    return "\n".join(lines) + "\n"


def save_scene(scene: Scene, path: str | Path) -> None:
    Path(path).write_text(scene_to_toml(scene))


# ----------------------------------------------------------------------------- key checks
