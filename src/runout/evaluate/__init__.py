"""The paper's forward and inverse studies as reproducible runs for any GNS checkpoint.

    from runout.evaluate import ColumnGrid, EngineRun, MpmCache, run_columns, write_report
    run_columns("model.pt", "out/eval", ColumnGrid(), EngineRun(MpmCache(), device="cuda"))
    write_report("out/eval", "docs/results.md")

Every study writes OUT/<study>/summary.json (with the model's card), a CSV where there is a
table of cases, and its figures. Scenes are filled at the model's point spacing for both
engines; MPM runs are cached on disk by scene (runout.mpm.cache).
See docs/evaluation.md.
"""

from runout.evaluate.columns import ColumnGrid, run_columns
from runout.evaluate.diagnostics import PAPER_CASE, run_diagnostics
from runout.evaluate.engines import EngineRun
from runout.evaluate.inverse_study import run_inverse
from runout.evaluate.report import write_report
from runout.evaluate.scenes import ColumnCase, column_file, column_scene, model_scene, scaled
from runout.evaluate.sensitivity import SensitivityConfig, run_sensitivity
from runout.evaluate.slope import run_slope
from runout.mpm.cache import DEFAULT_CACHE, MpmCache, scene_key

__all__ = [
    "DEFAULT_CACHE", "PAPER_CASE", "ColumnCase", "ColumnGrid", "EngineRun", "MpmCache", "SensitivityConfig",
    "column_file", "column_scene", "model_scene", "run_columns", "run_diagnostics", "run_inverse", "run_sensitivity",
    "run_slope", "scaled", "scene_key", "write_report",
]
