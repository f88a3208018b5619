"""The paper's forward and inverse studies as reproducible runs for any learned engine's
checkpoint (GNS or neural MPM; the file says which; the data-size study fine-tunes a GNS).

    from runout.evaluate import ColumnGrid, MpmCache, StudyContext, run_columns, write_report
    run_columns("model.pt", "out/eval", ColumnGrid(), StudyContext(MpmCache(), device="cuda"))
    write_report("out/eval", "docs/results.md")

Every study writes OUT/<study>/summary.json (with the model's card), a CSV where there is a
table of cases, and its figures. Scenes are filled at the model's point spacing for both
engines; MPM runs are cached on disk by scene (runout.mpm.cache).
See docs/evaluation.md.
"""

from importlib import import_module

# Each name and the module that owns it; a study's engines load only when it is used, so the
# command line (which reads the study settings) starts without torch.
_OWNERS = {
    "ColumnCase": "study_settings", "ColumnGrid": "study_settings", "PAPER_CASE": "study_settings",
    "SensitivityConfig": "study_settings",
    "run_columns": "columns", "run_diagnostics": "diagnostics", "StudyContext": "context",
    "run_inverse": "inverse_study", "write_report": "report", "column_file": "scenes", "column_scene": "scenes",
    "model_scene": "scenes", "scaled": "scenes", "run_sensitivity": "sensitivity", "run_slope": "slope",
}
_MPM = {"DEFAULT_CACHE", "MpmCache", "scene_key"}  # runout.mpm.cache

__all__ = sorted([*_OWNERS, *_MPM])


def __getattr__(name: str):
    if name in _MPM:
        return getattr(import_module("runout.mpm.cache"), name)
    if name in _OWNERS:
        return getattr(import_module(f"runout.evaluate.{_OWNERS[name]}"), name)
    raise AttributeError(f"module 'runout.evaluate' has no attribute {name!r}")
