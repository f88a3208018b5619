"""The layers of src/runout (docs/architecture.md): a module imports only from its own layer
and the layers below it, and the scene and file layers load without torch."""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[1] / "src" / "runout"

# Bottom to top; a module belongs to the layer of the longest name here that it starts with.
LAYERS = (
    ("foundation", ("runout", "runout.errors", "runout.defaults", "runout.contract", "runout.npz", "runout.outputs",
                    "runout.reading", "runout.shipped")),
    ("data", ("runout.scene", "runout.checks", "runout.simfiles", "runout.trajectory", "runout.dataset", "runout.metrics")),
    ("engines", ("runout.transfer", "runout.memory", "runout.mpm", "runout.gns", "runout.neural_mpm", "runout.learned")),
    ("views", ("runout.plots", "runout.vtk")),
    ("applications", ("runout.families", "runout.train", "runout.train_settings", "runout.inverse", "runout.evaluate", "runout.compare",
                      "runout.generate", "runout.demo", "runout.validate", "runout.validate_figures", "runout.mpm_run",
                      "runout.rollout_run", "runout.training", "runout.neural_mpm.training", "runout.neural_mpm.settings",
                      "runout.hazard", "runout.average")),
    ("cli", ("runout.cli", "runout.__main__")),
)


def layer_of(module: str) -> int:
    matches = [(len(name), rank) for rank, (_, names) in enumerate(LAYERS) for name in names
               if module == name or module.startswith(name + ".")]
    assert matches, f"{module} is in no layer; add it to LAYERS and docs/architecture.md"
    return max(matches)[1]


def module_name(path: Path) -> str:
    parts = path.relative_to(PACKAGE.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _is_module(name: str) -> bool:
    relative = Path(*name.split(".")[1:])
    return (PACKAGE / relative).with_suffix(".py").is_file() or (PACKAGE / relative / "__init__.py").is_file()


def _type_checking_only(tree: ast.Module) -> set[int]:
    """ids of the import nodes under `if TYPE_CHECKING:` (never run, so never loaded)."""
    skipped = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.If) and getattr(node.test, "id", getattr(node.test, "attr", None)) == "TYPE_CHECKING":
            skipped |= {id(n) for child in node.body for n in ast.walk(child)}
    return skipped


def imported_modules(path: Path, type_only: bool = False) -> set[str]:
    """Every runout module `path` imports, at the top or inside a function; with type_only,
    also those it imports only for type names (under `if TYPE_CHECKING:`)."""
    tree = ast.parse(path.read_text())
    skipped = set() if type_only else _type_checking_only(tree)
    found = set()
    for node in ast.walk(tree):
        if id(node) in skipped:
            continue
        if isinstance(node, ast.Import):
            found |= {alias.name for alias in node.names if alias.name.split(".")[0] == "runout"}
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and (node.module or "").split(".")[0] == "runout":
            for alias in node.names:
                child = f"{node.module}.{alias.name}"
                found.add(child if _is_module(child) else node.module)
        elif isinstance(node, ast.ImportFrom) and node.level > 0:
            raise AssertionError(f"{path}: use absolute imports (from runout... import ...)")
    return found


def test_no_module_imports_from_a_higher_layer():
    upward = []
    for path in sorted(PACKAGE.rglob("*.py")):
        module = module_name(path)
        for imported in sorted(imported_modules(path)):
            if layer_of(imported) > layer_of(module):
                upward.append(f"{module} ({LAYERS[layer_of(module)][0]}) imports {imported} ({LAYERS[layer_of(imported)][0]})")
    assert not upward, "\n".join(upward)


def test_no_modules_import_each_other():
    """No circle of imports, not even one closed by imports for type names only: a module that
    needs another's types sits above it (scene.model below scene.seeding, families above
    plots.families)."""
    graph = {module_name(path): imported_modules(path, type_only=True) for path in sorted(PACKAGE.rglob("*.py"))}
    circles = []
    for start in graph:
        path, seen = _circle_from(start, graph, [start], set())
        if path and min(path) == start:  # each circle once, from its smallest module
            circles.append(" -> ".join(path))
    assert not circles, "\n".join(circles)


def _circle_from(module: str, graph: dict, path: list[str], seen: set[str]):
    for imported in sorted(graph.get(module, ())):
        if imported == path[0] and len(path) > 1:
            return path + [imported], seen
        if imported not in seen and imported != module:
            seen.add(imported)
            found, seen = _circle_from(imported, graph, path + [imported], seen)
            if found:
                return found, seen
    return None, seen


def test_the_layer_check_sees_imports_inside_functions(tmp_path):
    source = tmp_path / "module.py"
    source.write_text("def f():\n    from runout.cli import app\n    import runout.plots.frames\n")
    assert imported_modules(source) == {"runout.cli.app", "runout.plots.frames"}
    assert layer_of("runout.scene.model") < layer_of("runout.gns.rollout") < layer_of("runout.plots.frames") < layer_of("runout.cli.app")


def test_the_scene_loads_without_torch():
    code = "import runout.scene, sys; assert 'torch' not in sys.modules"
    subprocess.run([sys.executable, "-c", code], check=True)


def test_the_data_layer_loads_without_torch():
    modules = ", ".join(name for layer in LAYERS[:2] for name in layer[1])
    subprocess.run([sys.executable, "-c", f"import {modules}, sys; assert 'torch' not in sys.modules"], check=True)


def test_the_command_line_starts_without_torch_or_matplotlib():
    """`runout --help` and every command's options load only the settings they derive from
    (runout.train_settings, runout.evaluate.study_settings, ...); the engines load when a command runs."""
    code = ("import runout.cli, sys; heavy = [m for m in ('torch', 'matplotlib', 'scipy', 'warp') if m in sys.modules]; "
            "assert not heavy, heavy")
    subprocess.run([sys.executable, "-c", code], check=True)


ENGINE_PACKAGES = ("runout.gns", "runout.neural_mpm")
# What only the GNS reads (runout.gns.schema): the shared contract names none of it.
GNS_ONLY = {"NetworkConfig", "NETWORK_LIMITS", "MAX_STEPS", "FeatureSchema", "wall_clip", "type_embedding", "overburden",
            "node_width", "edge_width", "latent", "hidden", "message_passing_steps"}


def test_the_contract_holds_only_what_every_learned_engine_shares():
    """runout.contract: history, stride, particle types, material features, the codec and the
    radius per spacing; the GNS's node inputs and layer sizes are runout.gns.schema's."""
    tree = ast.parse((PACKAGE / "contract.py").read_text())
    names = {getattr(node, attr) for node in ast.walk(tree) for attr in ("id", "attr", "name", "arg")
             if isinstance(getattr(node, attr, None), str)}
    names |= {node.value for node in ast.walk(tree) if isinstance(node, ast.Constant) and isinstance(node.value, str)}
    assert not names & GNS_ONLY, sorted(names & GNS_ONLY)


# Modules that serve every learned engine: they reach one only through runout.learned.load.
ANY_ENGINE = ("runout.cli", "runout.compare", "runout.rollout_run", "runout.demo", "runout.inverse",
              "runout.evaluate.heldout", "runout.evaluate.heldout_run", "runout.evaluate.columns", "runout.evaluate.slope",
              "runout.evaluate.diagnostics", "runout.evaluate.inverse_study", "runout.contract", "runout.learned")
ENGINE_LOADER = "runout.learned.load"  # the one module that opens each engine's package, by the file's engine


def _package(module: str, packages) -> str | None:
    return next((p for p in packages if module == p or module.startswith(p + ".")), None)


def engine_leaks() -> list[str]:
    """Imports of an engine's package by a module that serves every engine (a command module
    above all), and by another engine's package."""
    leaks = []
    for path in sorted(PACKAGE.rglob("*.py")):
        module = module_name(path)
        own = _package(module, ENGINE_PACKAGES)
        for imported in imported_modules(path, type_only=True):
            engine = _package(imported, ENGINE_PACKAGES)
            if engine is None or module == ENGINE_LOADER:
                continue
            if _package(module, ANY_ENGINE) or (own is not None and engine != own):
                leaks.append(f"{module} imports {imported}")
    return leaks


def test_commands_reach_the_learned_engines_only_through_the_contract():
    """A command module (and every module that serves any learned engine: compare, rollout,
    the demo, the inverse, the engine-blind studies, the contract) takes a learned engine through
    runout.learned (load_engine), never one engine's package; gns/ never imports the neural MPM,
    nor the neural MPM gns/."""
    leaks = engine_leaks()
    assert not leaks, "\n".join(leaks)


def test_the_engine_check_sees_a_command_that_imports_the_gns(tmp_path, monkeypatch):
    for folder, source in (("cli", "from runout.gns.rollout import rollout\n"),
                           ("gns", "def f():\n    import runout.neural_mpm.engine\n")):
        (tmp_path / "runout" / folder).mkdir(parents=True)
        (tmp_path / "runout" / folder / "leak.py").write_text(source)
    monkeypatch.setattr(sys.modules[__name__], "PACKAGE", tmp_path / "runout")
    assert sorted(engine_leaks()) == ["runout.cli.leak imports runout.gns.rollout",
                                      "runout.gns.leak imports runout.neural_mpm.engine"]
