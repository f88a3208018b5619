"""The paper's test scenes, built from the example scene files at the model's point spacing,
optionally shrunk.

Every study fills its scenes at the spacing the model was trained at (model_scene, through
runout.learned.scenes.at_model_spacing), and the MPM reference runs on those same scenes, so
both engines see the same points at the same resolution. `--scale s` then shrinks a
scene's domain and polygons by s (cell size and point spacing stay), so the same study runs
on a few hundred points in a test; scale 1 is the paper's geometry.
"""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

from runout import checks
from runout.errors import InputError
from runout.evaluate.study_settings import ColumnCase
from runout.scene import EXAMPLES, Scene, load_scene

COLUMN_ASPECTS = (0.5, 1.0, 2.0)  # H0 / L0 of examples/column_a{a}.toml
COLUMN_MATERIAL = "soil"


def example_scene(examples: Path, name: str) -> Scene:
    path = Path(examples) / name
    if not path.is_file():
        raise InputError(f"{path}: no such example scene; pass --examples with the folder holding {name}.")
    return load_scene(path)


def model_scene(examples: Path, name: str, engine, log=None) -> Scene:
    """EXAMPLES/name filled at the learned engine's point spacing; `log` gets one line when
    the scene's own cells differ."""
    from runout.learned.scenes import at_model_spacing  # the engines only when a model is given

    return at_model_spacing(example_scene(examples, name), engine, name, log)


def check_scale(scale: float) -> None:
    """InputError unless --scale is a finite number in (0, 1]."""
    checks.number(scale, "--scale", None, 0.0, 1.0, lo_open=True)


def scaled(scene: Scene, scale: float) -> Scene:
    """The scene with its domain (rounded up to whole cells) and polygons times `scale`."""
    check_scale(scale)
    if scale == 1:
        return scene
    cell = scene.domain.cell_size
    whole = lambda length: max(4, math.ceil(length * scale / cell - 1e-9)) * cell  # noqa: E731  (m)
    domain = replace(scene.domain, width=whole(scene.domain.width), height=whole(scene.domain.height))
    regions = tuple(replace(r, polygon=tuple((x * scale, y * scale) for x, y in r.polygon)) for r in scene.regions)
    return replace(scene, domain=domain, regions=regions)


def column_file(aspect: float) -> str:
    """The example column of an aspect ratio, column_a{a}.toml."""
    if aspect not in COLUMN_ASPECTS:
        allowed = ", ".join(f"{a:g}" for a in COLUMN_ASPECTS)
        raise InputError(f"aspect ratio {aspect:g} has no example column; choose from {allowed}.")
    return f"column_a{aspect:g}.toml"


def column_scene(column: Scene, case: ColumnCase, frames: int, scale: float = 1.0) -> Scene:
    """The example column of the case's aspect ratio (e.g. model_scene of column_file(a))
    with the case's phi and c, `frames` frames, shrunk by `scale`."""
    scene = scaled(column, scale).with_materials(
        **{COLUMN_MATERIAL: {"friction_angle": float(case.phi), "cohesion": float(case.cohesion)}}
    )
    return replace(scene.with_frames(frames), name=case.name)
