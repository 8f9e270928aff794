"""One MuJoCo copy's observe and step as numba source, for the engine's compiled loop.

The same calls as :class:`~.plant.CopyStepper` and :meth:`~.plant.MujocoPlant.observe`, made from
compiled code without the Python interpreter: ``ctrl = (I / gain) u``, ``mj_step`` ``substeps``
times, ``mj_sensorPos``, ``mj_sensorVel``, all called by symbol from MuJoCo's own library (which
the process has loaded with the bindings) on ``model._address`` / ``data._address``; the readings
are the two sensors' ``sensordata`` and the state ``qpos``/``qvel``, read at the addresses the
bindings report. Sensors that copy the state (a joint position and velocity sensor without
history or cutoff: the shipped models') read ``qpos``/``qvel`` themselves, so the loop skips the
two sensor calls and brings ``sensordata`` up to date once per call instead. A copy is dead (NaN
from then on, no longer stepped) when one of MuJoCo's "unstable" warning counters goes from 0 to
nonzero during a step: exactly when MuJoCo sends the message the Python stepper reads. The
passive terms run as the native callback, which MuJoCo calls itself; a run with the Python
callback, or with sensor noise, is not compiled.
"""

from __future__ import annotations

import glob
import os
from functools import cache

import mujoco
import numpy as np

from ..base import NativeStepper
from .threaded import UNSTABLE_WARNINGS

DEAD = 13  # pi: model, data, ctrl, sensordata, qpos, qvel, warning, actuator, p, v, qadr, dof, substeps, dead

HELPERS = '''from numba import types

mj_step = types.ExternalFunction("mj_step", types.void(types.voidptr, types.voidptr))
mj_sensorPos = types.ExternalFunction("mj_sensorPos", types.void(types.voidptr, types.voidptr))
mj_sensorVel = types.ExternalFunction("mj_sensorVel", types.void(types.voidptr, types.voidptr))
'''
SETUP = [
    "mp, dp = as_pointer(pi[0]), as_pointer(pi[1])",
    "ctrl = carray(as_pointer(pi[2]), pi[7] + 1, dtype=np.float64)",
    "sensordata = carray(as_pointer(pi[3]), max(pi[8], pi[9]) + 1, dtype=np.float64)",
    "qpos = carray(as_pointer(pi[4]), pi[10] + 1, dtype=np.float64)",
    "qvel = carray(as_pointer(pi[5]), pi[11] + 1, dtype=np.float64)",
    f"warning = carray(as_pointer(pi[6]), {2 * max(UNSTABLE_WARNINGS) + 1}, dtype=np.int32)",
]
OBSERVE = [
    "if pi[13] != 0:",
    "    x1 = math.nan",
    "    x2 = math.nan",
    "    m1 = math.nan",
    "    m2 = math.nan",
    "else:",
    "    x1 = qpos[pi[10]]",
    "    x2 = qvel[pi[11]]",
    "    m1 = sensordata[pi[8]]",
    "    m2 = sensordata[pi[9]]",
]
# sensors that copy the state (no history, no cutoff): their reading is qpos/qvel itself
OBSERVE_PLAIN = [*OBSERVE[:-2], "    m1 = x1", "    m2 = x2"]
_NEWLY = " or ".join(f"(calm{w} and warning[{2 * w}] != 0)" for w in UNSTABLE_WARNINGS)
STEP = [
    "if pi[13] == 0:",
    "    ctrl[pi[7]] = pf[0] * u",
    *[f"    calm{w} = warning[{2 * w}] == 0" for w in UNSTABLE_WARNINGS],
    "    for _ in range(pi[12]):",
    "        mj_step(mp, dp)",
    "    mj_sensorPos(mp, dp)",
    "    mj_sensorVel(mp, dp)",
    f"    if {_NEWLY}:",
    "        pi[13] = 1",
]


def step_lines(plain: bool) -> list[str]:
    """:data:`STEP`; with ``plain`` sensors without the sensor calls (their reading is the state,
    :data:`OBSERVE_PLAIN`; ``sensordata`` is brought up to date after each call instead)."""
    return [line for line in STEP if not (plain and "mj_sensor" in line)]


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

    found = sorted(glob.glob(os.path.join(os.path.dirname(mujoco.__file__), "libmujoco.so*"))
                   + glob.glob(os.path.join(os.path.dirname(mujoco.__file__), "libmujoco*.dylib"))
                   + glob.glob(os.path.join(os.path.dirname(mujoco.__file__), "mujoco*.dll")))
    if not found:
        raise LookupError("MuJoCo's C library was not found beside its Python bindings")
    llvm.load_library_permanently(found[0])
    return os.path.basename(found[0])


class MujocoNativeForm:
    """The numbers the generated lines read for copy 0 of ``plant``: addresses, indices, the
    substeps per step, ``I / gain``, and the dead flag (read from and written back to the plant)."""

    def __init__(self, plant, substeps: int) -> None:  # noqa: ANN001 (a MujocoPlant: no import cycle)
        self.plant = plant
        data, ids = plant._datas[0], plant._ids
        p, v = plant._sadr
        self.ints = np.array([plant.model._address, data._address, data.ctrl.ctypes.data,
                              data.sensordata.ctypes.data, data.qpos.ctypes.data, data.qvel.ctypes.data,
                              data.warning.number.ctypes.data, ids.actuator, p, v, ids.qpos, ids.dof,
                              substeps, int(plant._dead[0])], dtype=np.int64)
        self.floats = np.array([plant._ctrl_per_u], dtype=float)
        self.plain = plain_sensors(plant)

    def sync_in(self) -> None:
        self.ints[DEAD] = int(self.plant._dead[0])

    def sync_out(self) -> None:
        plant = self.plant
        plant._dead[0] = bool(self.ints[DEAD])
        if self.plain and not plant._dead[0]:  # sensordata as the Python step leaves it
            mujoco.mj_sensorPos(plant.model, plant._datas[0])
            mujoco.mj_sensorVel(plant.model, plant._datas[0])

    def stepper(self) -> NativeStepper:
        key = f"mujoco {load_mujoco_library()} {mujoco.__version__} plain sensors={self.plain}"
        observe = OBSERVE_PLAIN if self.plain else OBSERVE
        return NativeStepper(key, HELPERS, SETUP, observe, step_lines(self.plain), self.floats, self.ints,
                             np.zeros(0), self.sync_in, self.sync_out)
