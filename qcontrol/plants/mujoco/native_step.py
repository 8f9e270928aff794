"""One MuJoCo copy's observe and step, written once: the Python stepper runs these functions,
the engine's compiled loop compiles the very same functions (their source) with numba.

:func:`read_copy` and :func:`step_copy` are written in the subset of Python numba compiles. In
Python they call MuJoCo's bindings (``mujoco.mj_step`` on ``MjModel``/``MjData``); in the
compiled loop (:class:`MujocoNativeForm`) the names ``mj_step``, ``mj_sensorPos``,
``mj_sensorVel`` are MuJoCo's own C functions, called by symbol from the library the process
loaded with the bindings on ``model._address`` / ``data._address``, without the Python
interpreter. The arrays are the same memory either way (``ctrl``, ``qpos``, ``qvel``,
``sensordata``, and the warning counters of ``mjData.warning``).

Sensors that copy the state (a joint position and velocity sensor without history or cutoff:
the shipped models') read ``qpos``/``qvel`` themselves, so the compiled loop skips the two
sensor calls (``sensed=False``) and brings ``sensordata`` up to date once per call instead;
``sensed`` is one of the copy's integers, not part of the generated text, so one compiled loop
serves both kinds of sensor. The
passive terms run as the native callback, which MuJoCo calls itself; a run with the Python
callback is not compiled. Sensor noise is drawn before the run, by the plant's own streams
(:meth:`.noise.SensorNoise.ahead`: the same values in the same order), and each reading adds its
row, the same float addition the Python form makes; the count of readings taken goes back to the
streams after each call, so the Python loop, where it takes over, reads on from there.
"""

from __future__ import annotations

import ctypes
import inspect
import math
import os
import textwrap
from collections.abc import Callable
from functools import cache

import mujoco
import numpy as np

from ...compiled import CALLED
from ..base import NativeStepper
from .callbacks import mujoco_library_path
from .threaded import UNSTABLE_WARNINGS

# pi: model, data, ctrl, sensordata, qpos, qvel, warning, actuator, p, v, qadr, dof, substeps, dead, read,
# sensed
DEAD = 13
READ = 14  # readings taken (pf holds I / gain, then the run's noise: two values per reading)
SENSED = 15  # 1: the sensors' own readings (history, cutoff, other sensor types); 0: they copy the state
WARNINGS = int(mujoco.mjtWarning.mjNWARNING)
UNSTABLE = tuple(2 * w + 1 for w in UNSTABLE_WARNINGS)  # "unstable" counters in (lastinfo, number) pairs
mj_step, mj_sensorPos, mj_sensorVel = mujoco.mj_step, mujoco.mj_sensorPos, mujoco.mj_sensorVel  # noqa: N816


def read_copy(qpos, qvel, sensordata, qadr, dof, p, v, dead, sensed):  # noqa: ANN001, ANN201 (numba)
    """``(x1, x2, m1, m2)`` of one copy: the joint's ``qpos``/``qvel`` (the true state of eq. (1))
    and the position and velocity sensors' ``sensordata`` (the reading; the state itself when the
    sensors copy it, ``sensed`` False); NaN for a copy MuJoCo had to reset (``dead``)."""
    if dead:
        return math.nan, math.nan, math.nan, math.nan
    x1 = qpos[qadr]
    x2 = qvel[dof]
    if sensed:
        return x1, x2, sensordata[p], sensordata[v]
    return x1, x2, x1, x2


def step_copy(m, d, ctrl, actuator, ctrl_per_u, u, substeps, warning, sensed):  # noqa: ANN001, ANN201
    """One step of one copy with ``u`` held: ``ctrl = (I / gain) u`` (eq. (1)'s input as the motor
    takes it), ``substeps`` calls of ``mj_step``, then (``sensed``) ``mj_sensorPos`` and
    ``mj_sensorVel``, which bring the sensors to the new state (``mj_step`` leaves ``sensordata``
    at the state before its last substep; with a sensor delay they read MuJoCo's history).
    True when MuJoCo found the copy unstable during the step: one of its "unstable" warning
    counters (``warning``, the ``(lastinfo, number)`` pairs of ``mjData.warning``) left 0, which
    is exactly when MuJoCo sends its message (a blow-up always warns; MuJoCo then resets the copy)."""
    ctrl[actuator] = ctrl_per_u * u
    calm = 0
    for i in UNSTABLE:
        if warning[i] == 0:
            calm += 1 << i
    for _ in range(substeps):
        mj_step(m, d)
    if sensed:
        mj_sensorPos(m, d)
        mj_sensorVel(m, d)
    for i in UNSTABLE:
        if (calm >> i) & 1 and warning[i] != 0:
            return True
    return False


def warning_counters(data: mujoco.MjData) -> ctypes.Array:
    """``data.warning`` as its ``(lastinfo, number)`` pairs of int32 (the memory itself)."""
    return (ctypes.c_int32 * (2 * WARNINGS)).from_address(data.warning.lastinfo.ctypes.data)


EXTERNAL = '''from numba import types

mj_step = types.ExternalFunction("mj_step", types.void(types.voidptr, types.voidptr))
mj_sensorPos = types.ExternalFunction("mj_sensorPos", types.void(types.voidptr, types.voidptr))
mj_sensorVel = types.ExternalFunction("mj_sensorVel", types.void(types.voidptr, types.voidptr))
'''


def helpers() -> str:
    """The module text the compiled loop's lines call: MuJoCo's functions by symbol, and
    :func:`read_copy` and :func:`step_copy` themselves (their source, as this module holds them
    now), compiled by numba."""
    return _helpers(globals()["read_copy"], globals()["step_copy"])


@cache
def _helpers(read: Callable, step: Callable) -> str:
    """:func:`helpers` of these two functions (their source read once per process)."""
    functions = (("read_copy", read), ("step_copy", step))
    texts = [textwrap.dedent(inspect.getsource(f)).replace(f"def {f.__name__}(", f"def {name}(", 1)
             for name, f in functions]
    return f"{EXTERNAL}UNSTABLE = {UNSTABLE!r}\n\n" + "".join(f"{CALLED}\n{text}\n" for text in texts)


def setup_lines(at: str = "") -> list[str]:
    """The pointers and views of one copy's arrays, from its integers ``pi[at k]`` (``at`` is
    ``"b, "`` in a batch of copies, whose integers have a row per copy)."""
    return [
        f"mp, dp = as_pointer(pi[{at}0]), as_pointer(pi[{at}1])",
        f"ctrl = carray(as_pointer(pi[{at}2]), pi[{at}7] + 1, dtype=np.float64)",
        f"sensordata = carray(as_pointer(pi[{at}3]), max(pi[{at}8], pi[{at}9]) + 1, dtype=np.float64)",
        f"qpos = carray(as_pointer(pi[{at}4]), pi[{at}10] + 1, dtype=np.float64)",
        f"qvel = carray(as_pointer(pi[{at}5]), pi[{at}11] + 1, dtype=np.float64)",
        f"warning = carray(as_pointer(pi[{at}6]), {2 * WARNINGS}, dtype=np.int32)",
    ]


def observe_lines(noisy: bool, at: str = "") -> list[str]:
    read = [f"x1, x2, m1, m2 = read_copy(qpos, qvel, sensordata, pi[{at}10], pi[{at}11], pi[{at}8], "
            f"pi[{at}9], pi[{at}{DEAD}] != 0, pi[{at}{SENSED}] != 0)"]
    if not noisy:
        return read
    noise = [f"m{i} = m{i} + pf[{i} + 2 * pi[{READ}]]" for i in (1, 2)]  # the Python reading += noise
    return read + noise + [f"pi[{READ}] += 1"]


def step_lines(at: str = "") -> list[str]:
    return [f"if pi[{at}{DEAD}] == 0 and step_copy(mp, dp, ctrl, pi[{at}7], pf[0], u, pi[{at}12], warning, "
            f"pi[{at}{SENSED}] != 0):",
            f"    pi[{at}{DEAD}] = 1"]


def plain_sensors(plant) -> bool:  # noqa: ANN001 (a MujocoPlant)
    """Whether the two sensors are a joint position and velocity sensor that copy ``qpos`` and
    ``qvel`` as they are (no history, no cutoff): the readings are then the state itself (as on
    ``mujoco.batch``, :mod:`.threaded`)."""
    model, ids = plant.model, plant._ids
    p, v = ids.position_sensor, ids.velocity_sensor
    return (not model.nhistory and not model.sensor_cutoff[[p, v]].any()
            and int(model.sensor_type[p]) == int(mujoco.mjtSensor.mjSENS_JOINTPOS)
            and int(model.sensor_type[v]) == int(mujoco.mjtSensor.mjSENS_JOINTVEL)
            and int(model.sensor_objid[p]) == ids.joint == int(model.sensor_objid[v]))


@cache
def load_mujoco_library() -> str:
    """Make MuJoCo's C symbols (``mj_step``, ...) visible to numba's linker: the library the
    bindings loaded, by its path in the mujoco package."""
    import llvmlite.binding as llvm

    path = mujoco_library_path()
    llvm.load_library_permanently(path)
    return os.path.basename(path)


class MujocoNativeForm:
    """The numbers the generated lines read for the copies of ``plant`` (one: a run; every copy:
    a batch of copies, each row of the integers one copy's, the lines indexing them by the copy
    ``b`` the generated batch loop gives): addresses, indices, the substeps per step, ``I / gain``,
    the dead flags (read from and written back to the plant) and, for a run with sensor noise,
    the noise of its ``readings`` readings and how many were taken."""

    def __init__(self, plant, substeps: int, readings: int) -> None:  # noqa: ANN001 (a MujocoPlant)
        self.plant, self.noisy, self.taken = plant, plant._noisy, 0
        self.batched = plant.batch > 1
        ids = plant._ids
        p, v = plant._sadr
        self.plain = plain_sensors(plant)
        self.ints = np.array([[plant.model._address, data._address, data.ctrl.ctypes.data,
                               data.sensordata.ctypes.data, data.qpos.ctypes.data, data.qvel.ctypes.data,
                               data.warning.lastinfo.ctypes.data, ids.actuator, p, v, ids.qpos, ids.dof,
                               substeps, int(dead), 0, int(not self.plain)]
                              for data, dead in zip(plant._datas, plant._dead, strict=True)],
                             dtype=np.int64)
        noise = plant._noise.ahead(readings)[:, 0, :].ravel() if self.noisy else np.zeros(0)
        self.floats = np.concatenate([[plant._ctrl_per_u], noise])
        if self.batched:  # (a batch of copies takes no noise: NativeStepping refuses it)
            self.floats = np.repeat(self.floats[None, :], plant.batch, axis=0)
        else:
            self.ints = self.ints[0]

    def sync_in(self) -> None:
        dead = self.plant._dead
        if self.batched:
            self.ints[:, DEAD] = dead
        else:
            self.ints[DEAD] = int(dead[0])

    def sync_out(self) -> None:
        plant = self.plant
        plant._dead[:] = [bool(d) for d in self.ints[:, DEAD]] if self.batched else [bool(self.ints[DEAD])]
        if self.noisy:  # the readings the compiled loop took, taken from the streams
            plant._noise.skip(int(self.ints[READ]) - self.taken)
            self.taken = int(self.ints[READ])
        if self.plain:  # sensordata as the Python step leaves it
            for data, dead in zip(plant._datas, plant._dead, strict=True):
                if not dead:
                    mujoco.mj_sensorPos(plant.model, data)
                    mujoco.mj_sensorVel(plant.model, data)

    def stepper(self) -> NativeStepper:
        key = f"mujoco {load_mujoco_library()} {mujoco.__version__} noise={self.noisy}"
        at = "b, " if self.batched else ""
        return NativeStepper(key, helpers(), setup_lines(at), observe_lines(self.noisy, at),
                             step_lines(at), self.floats, self.ints,
                             np.zeros((self.plant.batch, 0)) if self.batched else np.zeros(0),
                             self.sync_in, self.sync_out)
