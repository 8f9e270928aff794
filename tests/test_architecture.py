"""The architecture's contracts: imports go one way, the signal table makes the results, kinded tables
take the chosen kind's keys, a MuJoCo model is compiled once, and the loop stays on one screen."""

from __future__ import annotations

import ast
import inspect
from pathlib import Path

import numpy as np
import pytest

from qcontrol.assembly import build_plant, run_scenario
from qcontrol.engine import SIGNALS, ClosedLoop
from qcontrol.engine.signals import DERIVED, RECORDED, REDUCTIONS, needed
from qcontrol.errors import QcontrolInputError
from qcontrol.scenario import load_scenario

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "qcontrol"
EX2 = ROOT / "scenarios" / "example2.toml"

# Each layer may import only from the layers before it (docs/architecture.md, "Modules").
LAYERS = [
    {"_version", "errors", "schema", "timegrid", "expr", "progress", "outputs", "error_rate", "resources",
     "provenance"},
    {"quantizer", "reference", "disturbance"},
    {"controller"},
    {"plants"},
    {"engine"},
    {"metrics", "scenario"},
    {"paper"},
    {"assembly"},
    {"recording", "plots", "attribution"},
    {"sweep", "api", "explain", "region"},
    {"law_comparison"},
    {"reproduce"},
    {"cli", "_entry"},
]


def _layer(module: str) -> int:
    top = module.split(".")[0]
    return next(i for i, layer in enumerate(LAYERS) if top in layer)


def _imports(path: Path) -> set[str]:
    """The qcontrol modules ``path`` imports (relative imports resolved to their top-level name)."""
    package = path.relative_to(PACKAGE).parts[:-1]
    found = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom) and node.level:
            base = list(package[: len(package) - node.level + 1])
            target = [*base, *(node.module.split(".") if node.module else [])]
            if target:
                found.add(target[0])
            else:  # "from . import x" at the package's top
                found.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("qcontrol."):
            found.add(node.module.split(".")[1])
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


def test_no_attribute_probing_in_the_package() -> None:
    offenders = [
        f"{path.relative_to(ROOT)}:{node.lineno}"
        for path in PACKAGE.rglob("*.py")
        for node in ast.walk(ast.parse(path.read_text()))
        if isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id == "hasattr"
    ]
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
                                             "saturated_fraction", "diagnostics"}


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
    sc = load_scenario(EX2, ["controller.kind=baseline", "controller.gain=2.0"])
    assert sc.controller.kind == "baseline" and sc.controller.settings.gain == 2.0
    assert sc.controller.settings.theta == "adaptive"  # from [controller.baseline]


@pytest.mark.parametrize(("overrides", "fragments"), [
    (["controller.gain=2.0"],
     ["controller.gain", "does not apply to kind 'proposed'", "setting of kind 'baseline'", "kappa_margin"]),
    (["controller.kind=baseline", "controller.gamma=2.0"],
     ["controller.gamma", "kind 'baseline'", "gain, theta"]),
    (["controller.baseline.gian=2.0"], ["controller.baseline.gian: unknown key", "gain, theta"]),
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
