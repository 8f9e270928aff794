"""The architecture's contracts: imports go one way and form no cycle, importing has no side
effect, the hot packages hold objects rather than closures, the protocols stay narrow, the signal
table makes the results, kinded tables take the chosen kind's keys, a MuJoCo model is compiled
once, and the loop stays on one screen."""

from __future__ import annotations

import ast
import dataclasses
import hashlib
import inspect
import json
import os
import subprocess
import sys
import tempfile
from functools import cache
from pathlib import Path

import numpy as np
import pytest
from conftest import EX2, PACKAGE, ROOT

from qcontrol.assembly import build_plant, run_scenario
from qcontrol.columns import ColumnForm
from qcontrol.controller import AnyColumnForm, BatchLaw
from qcontrol.controller.user import Law
from qcontrol.controller.user_diagnostics import LawDiagnostics
from qcontrol.engine import SIGNALS, ClosedLoop
from qcontrol.engine.compiled_loop import Schedule
from qcontrol.engine.signals import DERIVED, RECORDED, REDUCTIONS, needed
from qcontrol.errors import QcontrolInputError
from qcontrol.plants import (
    Actuated,
    Backend,
    ColumnIO,
    ColumnStepping,
    Disturbable,
    NativeStepping,
    PhysicsReport,
    Plant,
)
from qcontrol.quantizer import Quantizer
from qcontrol.recording.streamer import StreamTarget
from qcontrol.reference import Reference
from qcontrol.scenario import load_scenario

# Each layer may import only from the layers before it (docs/architecture.md, "Modules").
LAYERS = [
    {"_version", "errors", "schema", "sharing", "timegrid", "expr", "progress", "outputs", "error_rate",
     "resources",
     "provenance", "interrupts", "compiled", "workers"},
    {"columns"},
    {"quantizer", "quantizers", "reference", "disturbance"},
    {"controller"},
    {"plants"},
    {"engine"},
    {"metrics", "scenario", "summary"},
    {"paper"},
    {"assembly"},
    {"recording", "plots", "attribution"},
    {"render"},
    {"sweep", "api", "explain", "region"},
    {"law_comparison"},
    {"reproduce"},
    {"commands"},
    {"cli", "_entry", "__main__"},
]


def _facts_of(source: str) -> dict:
    """What the tests below read from a module's syntax tree (``ast.walk``'s order): its ``from``
    imports ``[level, module, names]``, its plain imports' names, every ``Name``/``Attribute``/
    imported name it uses, and the lines of the functions or lambdas nested in a function or
    lambda (once for each enclosing one), of its lambdas and of its ``hasattr`` calls."""
    facts: dict = {"from": [], "import": [], "names": set(), "nested": [], "lambdas": [], "hasattr": []}
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Name):
            facts["names"].add(node.id)
        elif isinstance(node, ast.Attribute):
            facts["names"].add(node.attr)
        elif isinstance(node, ast.ImportFrom):
            facts["from"].append([node.level, node.module, [alias.name for alias in node.names]])
            facts["names"].update(alias.name for alias in node.names)
        elif isinstance(node, ast.Import):
            facts["import"] += [alias.name for alias in node.names]
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda)):
            facts["nested"] += [inner.lineno for inner in ast.walk(node)
                                if inner is not node and isinstance(inner, (ast.FunctionDef, ast.Lambda))]
        if isinstance(node, ast.Lambda):
            facts["lambdas"].append(node.lineno)
        if isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id == "hasattr":
            facts["hasattr"].append(node.lineno)
    facts["names"] = sorted(facts["names"])
    return facts


# The facts of a module's text are kept by the hash of the text and of _facts_of's own source,
# beside pytest's cache (conftest.py): a session's workers, and the copies of the repository that
# tests/test_recipes.py runs this file in (they are given the same folder), parse a module only
# when its text is new; a module a recipe edits is a new text.
FACTS = Path(os.environ["QCONTROL_TEST_FACTS_DIR"])
_FACTS_OF_SOURCE = inspect.getsource(_facts_of).encode()


@cache
def _facts(path: Path) -> dict:
    """:func:`_facts_of` the module at ``path``, read from the kept facts of its text if any."""
    source = path.read_bytes()
    key = hashlib.sha256(_FACTS_OF_SOURCE + b"\0" + source).hexdigest()
    kept = FACTS / f"{key}.json"
    try:
        return json.loads(kept.read_text())
    except (OSError, ValueError):
        pass
    facts = _facts_of(source.decode())
    FACTS.mkdir(parents=True, exist_ok=True)
    with tempfile.NamedTemporaryFile("w", dir=FACTS, suffix=".tmp", delete=False) as handle:
        json.dump(facts, handle)
    os.replace(handle.name, kept)  # whole or not there, for another worker reading it at once
    return facts


def _layer(module: str) -> int:
    top = module.split(".")[0]
    return next(i for i, layer in enumerate(LAYERS) if top in layer)


def _imports(path: Path) -> set[str]:
    """The qcontrol modules ``path`` imports (relative imports resolved to their top-level name)."""
    package = path.relative_to(PACKAGE).parts[:-1]
    found = set()
    for level, module, names in _facts(path)["from"]:
        if level:
            base = list(package[: len(package) - level + 1])
            target = [*base, *(module.split(".") if module else [])]
            if target:
                found.add(target[0])
            else:  # "from . import x" at the package's top
                found.update(names)
        elif module and module.startswith("qcontrol."):
            found.add(module.split(".")[1])
    return found


def test_imports_go_one_way() -> None:
    upward = []
    for path in sorted(PACKAGE.rglob("*.py")):
        if path.name == "__init__.py" and path.parent == PACKAGE:
            continue
        own = path.relative_to(PACKAGE).parts[0].removesuffix(".py")
        for target in _imports(path) - {own}:
            if _layer(target) > _layer(own):
                upward.append(f"{path.relative_to(ROOT)} imports {target}")
    assert not upward, upward


def _module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _import_graph() -> dict[str, set[str]]:
    """Module -> the qcontrol modules it imports anywhere (top level, functions, TYPE_CHECKING),
    without the edges to its own enclosing packages (Python imports those first anyway)."""
    modules = {_module_name(p): p for p in PACKAGE.rglob("*.py")}
    graph = {}
    for name, path in modules.items():
        package = name.split(".") if path.name == "__init__.py" else name.split(".")[:-1]
        found = set(_facts(path)["import"])
        for level, module, names in _facts(path)["from"]:
            base = package[: len(package) - level + 1] if level else []
            target = ".".join([*base, *(module.split(".") if module else [])])
            for alias in names:
                found.add(f"{target}.{alias}" if f"{target}.{alias}" in modules else target)
        graph[name] = {m for m in found if m in modules and m != name and not name.startswith(m + ".")}
    return graph


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    found: list[list[str]] = []

    def visit(node: str) -> None:
        index[node] = low[node] = len(index)
        stack.append(node)
        for nxt in graph[node]:
            if nxt not in index:
                visit(nxt)
                low[node] = min(low[node], low[nxt])
            elif nxt in stack:
                low[node] = min(low[node], index[nxt])
        if low[node] == index[node]:
            component = []
            while True:
                top = stack.pop()
                component.append(top)
                if top == node:
                    break
            if len(component) > 1:
                found.append(sorted(component))

    for node in sorted(graph):
        if node not in index:
            visit(node)
    return found


def test_no_import_cycles_of_any_kind() -> None:
    assert not _cycles(_import_graph())


def test_the_cycle_finder_finds_a_cycle() -> None:
    assert _cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]


def test_importing_the_package_changes_nothing_process_wide() -> None:
    """Importing every plant (MuJoCo's callbacks included) installs no MuJoCo hook: the warning
    handler and the passive callback are installed by the blocks that use them."""
    code = ("import mujoco, qcontrol, qcontrol.cli, qcontrol.plants.mujoco.plant, qcontrol.recording; "
            "assert mujoco.get_mju_user_warning() is None and mujoco.get_mjcb_passive() is None")
    subprocess.run([sys.executable, "-c", code], check=True, cwd=ROOT)


HOT_PACKAGES = ("engine", "plants", "controller")


def test_no_nested_functions_in_the_hot_packages() -> None:
    """engine/, plants/ and controller/ hold named objects, not closures (a lambda counts)."""
    nested = []
    for package in HOT_PACKAGES:
        for path in sorted((PACKAGE / package).rglob("*.py")):
            nested += [f"{path.relative_to(ROOT)}:{line}" for line in _facts(path)["nested"]]
    assert not nested, nested


def test_no_lambdas_at_all_in_the_hot_packages() -> None:
    """Not even at module or class level: a getter or a default is a named function or class."""
    found = [f"{path.relative_to(ROOT)}:{line}" for package in HOT_PACKAGES
             for path in sorted((PACKAGE / package).rglob("*.py")) for line in _facts(path)["lambdas"]]
    assert not found, found


def test_the_signal_attributes_read_the_record_tables(short_example2) -> None:
    full = run_scenario(short_example2, "ode")
    metrics = run_scenario(short_example2, "ode", record="metrics")
    assert all(getattr(full, s.name) is full.signals[s.name] for s in SIGNALS)
    assert all(getattr(metrics, r.name) is metrics.values[r.name] for r in REDUCTIONS)
    with pytest.raises(AttributeError):
        full.x = np.zeros(3)  # read-only, as before


def _members(protocol: type) -> set[str]:
    own = set(vars(protocol)) | set(getattr(protocol, "__annotations__", {}))
    return {m for m in own if not m.startswith("_") or m in ("__enter__", "__exit__", "__call__")}


@pytest.mark.parametrize(("protocol", "members"), [
    (Plant, {"n", "batch", "reset", "observe", "step", "close", "__enter__", "__exit__"}),
    (Disturbable, {"disturb"}),
    (Actuated, {"actuator", "actuator_limited"}),
    (PhysicsReport, {"warnings", "consistency_report"}),
    (ColumnStepping, {"column_io"}),
    (NativeStepping, {"native_stepper"}),
    (Quantizer, {"max_error", "__call__"}),
    (ColumnIO, {"observe", "step"}),
    # (program: a program of shared trees in the form, the tuning-function law's design; maximum:
    # the bound ratios of (37)-(43), traced into a compiled batch's folds)
    (ColumnForm, {"expm1", "maximum", "column", "terms", "program", "combination", "columns", "array"}),
    (BatchLaw, {"state_name", "state_size", "copies", "coordinates", "initial_state", "control", "advancer",
                "constants", "diagnostics"}),
    (AnyColumnForm, {"advancer_in"}),
    (Law, {"state_size", "initial_state", "control", "state_rate"}),
    (LawDiagnostics, {"diagnostics"}),
    (Schedule, {"grid", "record", "reference", "next_event", "rare_work"}),
    (StreamTarget, {"main_series", "main_label", "stream", "flush", "see_motion", "update_layout",
                    "add_panels"}),
    (Reference, {"derivatives"}),
])
def test_the_protocols_stay_narrow(protocol: type, members: set[str]) -> None:
    assert _members(protocol) == members


def test_a_backend_is_built_with_keywords_and_needs_four() -> None:
    fields = {f.name: f for f in dataclasses.fields(Backend)}
    required = {name for name, f in fields.items() if f.default is dataclasses.MISSING}
    assert required == {"name", "build", "structure", "summary"}
    assert all(f.kw_only for f in fields.values())


def test_the_float_path_is_explained_in_one_module() -> None:
    """Why a batch of one runs on floats is said once, where the float path is chosen."""
    explaining = sorted(str(path.relative_to(PACKAGE)) for path in PACKAGE.rglob("*.py")
                        if "microsecond" in path.read_text())
    assert explaining == ["engine/fastpath.py"]


# What only the float form uses: its form, rows and adapters (engine/fastpath.py) and the
# expression compiler's evaluation on floats with its fallback rule (expr/).
FLOAT_FORM_NAMES = {"FLOATS", "FloatForm", "FloatRows", "FloatQuantize", "FloatDifferencing",
                    "ArrayPlantAsFloats", "ArrayLawAsFloats", "float_io", "float_quantizer", "FloatTerms",
                    "FloatCombination", "scalar_function", "FLOAT_REFUSED", "on_floats"}
FLOAT_FORM_HOMES = {"engine/fastpath.py"}  # and the expression compiler, expr/
# MuJoCo calls its passive callback with one MjData, a copy's plain floats, at every batch size
PER_COPY_FLOATS = {"plants/mujoco/callbacks.py": {"FloatCombination"}}


def _names(path: Path) -> set[str]:
    return set(_facts(path)["names"])


def test_the_float_form_is_known_in_one_module_besides_the_expression_compiler() -> None:
    """Plants and laws are written over columns of any form; only the engine's adapter knows the
    float form a single run steps in (and nothing branches on a reading being floats)."""
    knowing = {}
    for path in PACKAGE.rglob("*.py"):
        name = str(path.relative_to(PACKAGE))
        used = _names(path) & FLOAT_FORM_NAMES
        if used and not name.startswith("expr/") and name not in FLOAT_FORM_HOMES:
            knowing[name] = used
    assert knowing == PER_COPY_FLOATS


def test_no_attribute_probing_in_the_package() -> None:
    offenders = [f"{path.relative_to(ROOT)}:{line}" for path in PACKAGE.rglob("*.py")
                 for line in _facts(path)["hasattr"]]
    assert not offenders, offenders


def test_the_loop_fits_on_one_screen() -> None:
    lines = inspect.getsource(ClosedLoop.run).splitlines()
    assert len(lines) <= 60, len(lines)


# ---------------------------------------------------------------------------------------------
# the signal table


def test_every_signal_is_an_attribute_of_a_trajectory_with_its_width() -> None:
    sc = load_scenario(EX2, ["simulation.duration=0.05"])
    traj = run_scenario(sc, "ode")
    n, m, rows = sc.order, traj.adaptive.shape[1], len(traj.t)
    assert set(traj.signals) == {s.name for s in SIGNALS}
    assert traj.bound_names == ("phi1", "phi2", "phi3")  # the separation (37)-(43) of each phi_i
    assert traj.diagnostic_columns == ("gain_period",)  # the paper's law declares K T
    for signal in SIGNALS:
        array = getattr(traj, signal.name)
        expected = (rows,) if signal.width == "1" else (
            rows, signal.size(n, m, len(traj.bound_names), len(traj.diagnostic_columns)))
        assert array.shape == expected, signal.name
    np.testing.assert_array_equal(traj.y, traj.x[:, 0])


def test_recorded_derived_and_reduced_signals() -> None:
    assert [s.name for s in RECORDED] == ["x", "x_meas", "x_q", "u", "adaptive"]
    for signal in DERIVED:  # a derivation reads only signals above it in the table
        above = [s.name for s in SIGNALS[: SIGNALS.index(signal)]]
        assert set(signal.reads) <= set(above), signal.name
    assert needed(("e_z",)) == ("zbar", "e_z")
    assert {r.name for r in REDUCTIONS} == {"error_rate", "max_abs_z1_last_half", "max_abs_u", "e_z_max",
                                             "final_adaptive", "bound_constants", "max_abs_u_applied",
                                             "reading_saturated_fraction", "max_abs_input_quantization_error",
                                             "input_quantized_fraction",
                                             "saturated_fraction", "diagnostics", "smallest_r"}


def test_a_metrics_run_keeps_the_reductions_of_the_full_record() -> None:
    sc = load_scenario(EX2, ["simulation.duration=1.0"])
    full, lean = run_scenario(sc, "ode").reduced(), run_scenario(sc, "ode", record="metrics")
    for reduction in REDUCTIONS:
        expected, got = full[reduction.name], getattr(lean, reduction.name)
        if isinstance(expected, dict):  # the error rate, by omega
            expected, got = list(expected.values()), list(got.values())
        np.testing.assert_array_equal(expected, got, err_msg=reduction.name)


# ---------------------------------------------------------------------------------------------
# kinded tables: the chosen kind's keys, from its sub-table or directly


def test_a_direct_key_overrides_the_kinds_sub_table() -> None:
    file = load_scenario(EX2)
    direct = load_scenario(EX2, ["controller.kappa_margin=0.1"])
    assert file.controller.settings.kappa_margin == 1.1 and direct.controller.settings.kappa_margin == 0.1


def test_a_direct_key_replaces_its_alternative_in_the_sub_table() -> None:
    sc = load_scenario(EX2, ["controller.kappa=1.2"])  # the sub-table gives kappa_margin
    assert sc.controller.settings.kappa == 1.2 and sc.controller.settings.kappa_margin is None


def test_switching_kind_takes_the_other_kinds_sub_table() -> None:
    sc = load_scenario(EX2, ["controller.kind=comparison", "controller.gain=2.0"])
    assert sc.controller.kind == "comparison" and sc.controller.settings.gain == 2.0
    assert sc.controller.settings.theta == "adaptive"  # from [controller.comparison]


@pytest.mark.parametrize(("overrides", "fragments"), [
    (["controller.gain=2.0"],
     ["controller.gain", "does not apply to kind 'proposed'", "setting of kind 'comparison'",
      "kappa_margin"]),
    (["controller.kind=comparison", "controller.gamma=2.0"],
     ["controller.gamma", "kind 'comparison'", "gain, theta"]),
    (["controller.comparison.gian=2.0"],
     ["--set controller.comparison.gian=2.0: unknown key", "gain, theta"]),
    (["controller.proposed=1"], ["controller.proposed", "must be a table"]),
])
def test_keys_of_another_kind_are_refused_with_the_keys_that_apply(overrides: list[str],
                                                                   fragments: list[str]) -> None:
    with pytest.raises(QcontrolInputError) as err:
        load_scenario(EX2, overrides)
    message = str(err.value)
    assert "\n" not in message and "; " in message
    for fragment in fragments:
        assert fragment in message, message


# ---------------------------------------------------------------------------------------------
# the MuJoCo model is compiled once


def test_the_plant_uses_the_model_compiled_when_the_scenario_loaded() -> None:
    from qcontrol.plants.mujoco.mjcf import compiled

    sc = load_scenario(EX2)
    plant = build_plant(sc, "mujoco")
    assert plant.model is compiled(sc.backends["mujoco"], sc.simulation.dt).model
    assert build_plant(sc, "mujoco").model is plant.model
