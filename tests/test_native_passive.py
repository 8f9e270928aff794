"""The compiled passive callback computes what the Python one computes, to the last bit, and
behaves as a process-global hook must (guarded by its tag, restored after the last plant)."""

from __future__ import annotations

import ctypes
import math
import pathlib
import warnings

import mujoco
import numpy as np
import pytest
from conftest import ROOT

from qcontrol.assembly import run_scenario
from qcontrol.compiled import ENVIRONMENT_SWITCH
from qcontrol.expr import compile_expression
from qcontrol.plants.mujoco import callbacks
from qcontrol.plants.mujoco.native import native_force, struct_offsets
from qcontrol.scenario import load_scenario

SCENARIOS = [p for p in sorted(ROOT.glob("scenarios/*.toml"))  # MuJoCo's: order 2, with a MuJoCo twin
             if load_scenario(p).order == 2 and "mujoco" in load_scenario(p).backends]
PROBE = """<mujoco><size nuserdata="32"/><worldbody><body><joint type="slide" axis="1 0 0"/>
<geom size="0.1" mass="1"/></body></worldbody></mujoco>"""

# every row of the expression table, constants folded or not, and each way math can raise
EXPRESSIONS = [
    "x2**2*cos(x1)", "0.1*x2**2", "sqrt(x1)", "log(x2)", "exp(x2)", "x1**0.5", "x2**x1", "1/x1",
    "tan(x1) - tanh(x2)", "sin(x1)*abs(x2) + sign(x1)*x2", "min(x1, x2, 0.5) - max(x2, x1)",
    "-x1 + 2*pi + x1**(1+1) + sin(0.5)*x2 + log(0.5)*x1 - (x1*x2)", "(x1 - x2)/(x1 + x2)",
    "exp(-x1**2)*x2**3 + 0.2*sqrt(abs(x2)) - 3", "cbrt(x1) - cbrt(-8)*x2", "spow(x1, 1/3) + spow(x2, x1)",
    "spow(x2, -1) + spow(-2, 0.5)",
]
VALUES = [0.0, -0.0, 1.0, -1.0, 0.5, -2.5, 3.0, 700.0, -710.0, 1e308, -1e-310, math.inf, -math.inf, math.nan]


def bits(value: float) -> int | str:
    return "nan" if math.isnan(value) else int(np.float64(value).view(np.int64))


def test_struct_offsets_match_the_bindings_addresses() -> None:
    offsets = struct_offsets()
    model = mujoco.MjModel.from_xml_string(PROBE)
    data = mujoco.MjData(model)
    for name in ("qpos", "qvel", "qfrc_passive", "userdata"):
        word = np.frombuffer((ctypes.c_uint64 * 1).from_address(data._address + offsets[name]),
                             dtype=np.uint64)[0]
        assert int(word) == getattr(data, name).ctypes.data
    nuser = np.frombuffer((ctypes.c_int64 * 1).from_address(model._address + offsets["nuserdata"]),
                          dtype=np.int64)[0]
    assert nuser == model.nuserdata == 32


@pytest.mark.parametrize("source", EXPRESSIONS)
def test_native_force_is_the_python_force_bit_for_bit(source: str) -> None:
    term = compile_expression(source, ["x1", "x2"])
    native = native_force([term])
    assert native is not None, "numba is a dependency: the native callback must compile"
    inertia, theta = 0.37, -1.3
    python = callbacks.GeneralizedForce([(theta, term)], inertia).at
    model = mujoco.MjModel.from_xml_string(PROBE)
    data = mujoco.MjData(model)
    native.fill(data, 0, 0, [inertia * theta])
    mismatches = []
    for q in VALUES:
        for v in VALUES:
            data.qpos[0], data.qvel[0], data.qfrc_passive[0] = q, v, 0.0
            native.pointer(model._address, data._address)
            expected = 0.0 + python(q, v)  # the Python callback adds to qfrc_passive = 0
            if bits(data.qfrc_passive[0]) != bits(expected):
                mismatches.append((q, v, data.qfrc_passive[0], expected))
    assert not mismatches, mismatches[:5]


def test_compiled_paths_off_or_unavailable_fall_back_to_python(monkeypatch: pytest.MonkeyPatch) -> None:
    import qcontrol.compiled as compiled_paths

    term = compile_expression("x2**2*cos(x1) + 1", ["x1", "x2"])
    monkeypatch.setenv(ENVIRONMENT_SWITCH, "0")
    assert native_force([term]) is None  # chosen: no warning
    monkeypatch.setenv(ENVIRONMENT_SWITCH, "1")
    monkeypatch.setattr(compiled_paths, "numba_missing", lambda: "numba cannot be imported (test)")
    monkeypatch.setattr(compiled_paths, "_SAID", set())
    with pytest.warns(RuntimeWarning, match="run in Python, not compiled: numba cannot be imported"):
        assert native_force([term]) is None
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # said once per process
        assert native_force([term]) is None


def test_generated_code_is_cached_in_the_user_cache_folder(monkeypatch: pytest.MonkeyPatch,
                                                           tmp_path: pathlib.Path) -> None:
    from qcontrol.compiled import cache

    monkeypatch.delenv("QCONTROL_CACHE_DIR")
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    assert cache.cache_folder() == tmp_path / "qcontrol" / "compiled"
    monkeypatch.setenv("QCONTROL_CACHE_DIR", str(tmp_path / "elsewhere"))
    text = "VALUE = 42\n"
    module = cache.generated_module("probe", text)
    assert module.VALUE == 42 and module.__file__.startswith(str(tmp_path / "elsewhere"))
    files = list((tmp_path / "elsewhere").glob("qcontrol_probe_*.py"))
    assert len(files) == 1 and files[0].read_text() == text
    assert cache.generated_module("probe", text) is module  # keyed by the text: the same module
    assert cache.generated_module("probe", "VALUE = 43\n").VALUE == 43


def test_untagged_data_is_left_alone() -> None:
    """Another model's data (no tag in its userdata) is not touched by the installed callback."""
    native = native_force([compile_expression("x2 + 1", ["x1", "x2"])])
    model = mujoco.MjModel.from_xml_string(PROBE)
    tagged, foreign = mujoco.MjData(model), mujoco.MjData(model)
    native.fill(tagged, 0, 0, [2.0])
    for data in (tagged, foreign):
        data.qvel[0], data.qfrc_passive[0] = 3.0, 0.0
        native.pointer(model._address, data._address)
    assert tagged.qfrc_passive[0] == 8.0 and foreign.qfrc_passive[0] == 0.0
    small = mujoco.MjModel.from_xml_string(PROBE.replace('nuserdata="32"', 'nuserdata="1"'))
    data = mujoco.MjData(small)
    data.userdata[0] = native.tag  # a tag in a too-small userdata is not trusted either
    native.pointer(small._address, data._address)
    assert data.qfrc_passive[0] == 0.0


@pytest.mark.parametrize("path", SCENARIOS, ids=lambda p: p.stem)
def test_compiled_and_python_callbacks_give_identical_runs(path: pathlib.Path,
                                                           monkeypatch: pytest.MonkeyPatch) -> None:
    sc = load_scenario(path, ["simulation.duration=0.3"])
    compiled = run_scenario(sc, "mujoco")
    assert mujoco.get_mjcb_passive() is None and not callbacks._ENTRIES  # restored after the run
    monkeypatch.setenv(ENVIRONMENT_SWITCH, "0")
    python = run_scenario(sc, "mujoco")
    for name in ("x", "x_meas", "u", "adaptive"):
        a, b = getattr(compiled, name), getattr(python, name)
        assert a.shape == b.shape and a.tobytes() == b.tobytes(), name


def test_plants_of_different_terms_share_the_hook(monkeypatch: pytest.MonkeyPatch) -> None:
    """Two plants in use at once with different terms: the Python dispatcher calls each one's
    native callback; both runs equal their runs alone."""
    from qcontrol.assembly import build_plant

    scs = [load_scenario(ROOT / "scenarios" / f"{n}.toml", ["simulation.duration=0.05"])
           for n in ("example1", "example2")]
    plants = [build_plant(sc, "mujoco") for sc in scs]
    assert all(p.native_for_run() is not None for p in plants)
    alone = [run_scenario(sc, "mujoco", plant=p) for sc, p in zip(scs, plants, strict=True)]
    with plants[1]:
        assert mujoco.get_mjcb_passive() is not callbacks._dispatch  # the native callback itself
        together = run_scenario(scs[0], "mujoco", plant=plants[0])
        assert mujoco.get_mjcb_passive() is callbacks._dispatch
    assert mujoco.get_mjcb_passive() is None
    assert together.x.tobytes() == alone[0].x.tobytes()
