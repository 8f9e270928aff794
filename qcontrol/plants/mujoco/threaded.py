"""A batch of MuJoCo copies stepped by ``mujoco.batch`` (C loops, no Python per copy).

``mujoco.batch.Batch`` keeps each copy's state in a row of one array and steps the copies in C;
it gives the same numbers as one ``MjData`` per copy (MuJoCo's own promise, and this project's
tests). It refuses a Python physics callback, so it serves a plant whose passive terms run as the
native callback (:mod:`.native`) or which has none; everything else keeps one ``MjData`` per copy.

Per step, as the per-copy path: ``ctrl = (I / gain) u`` for every running copy and ``substeps``
calls of ``mj_step``. The per-copy path then reads the joint sensors at the new state
(``mj_sensorPos``/``mj_sensorVel``), which copy ``qpos``/``qvel``; here the readings are those
state values themselves. (Asking the batch for the velocity stage instead would also run MuJoCo's
state checks one step early: a blow-up would be caught, and the copy reset, a row sooner.) So a
batch runs here only where the sensors are such copies: no ``cutoff``, no history. A copy that
MuJoCo had to reset stops, found from the batch's warning counters (NaN, Inf or huge qpos, qvel,
qacc or ctrl), not from messages.
"""

from __future__ import annotations

from collections.abc import Sequence

import mujoco
import numpy as np
from mujoco import batch as mj_batch

from .mjcf import Ids
from .native import NativeForce

# warnings MuJoCo gives when it resets a copy ("... The simulation is unstable.")
_W = mujoco.mjtWarning
UNSTABLE_WARNINGS = [int(w) for w in (_W.mjWARN_BADQPOS, _W.mjWARN_BADQVEL, _W.mjWARN_BADQACC,
                                      _W.mjWARN_BADCTRL)]
_STAGE_NONE = int(mujoco.mjtStage.mjSTAGE_NONE)
# (consecutive in mjtWarning: their counters are one slice of the batch's warning array, a view)
_UNSTABLE = slice(min(UNSTABLE_WARNINGS), max(UNSTABLE_WARNINGS) + 1)
assert UNSTABLE_WARNINGS == list(range(_UNSTABLE.start, _UNSTABLE.stop))


def threadable(model: mujoco.MjModel, batch: int, native: NativeForce | None, has_force: bool) -> bool:
    """Whether a batch of this plant can run on ``mujoco.batch``: more than one copy, its passive
    terms native (or none), and sensors that read the state as it is: no history (which
    ``mj_initSensorHistory`` fills at reset: a batch has no such call) and no cutoff."""
    plain_sensors = not model.nhistory and not model.sensor_cutoff.any()
    return batch > 1 and (native is not None or not has_force) and plain_sensors


class ThreadedCopies:
    """The copies of a :class:`~.plant.MujocoPlant` as rows of a ``mujoco.batch.Batch``."""

    def __init__(self, model: mujoco.MjModel, ids: Ids, batch: int, ctrl_per_u: float,
                 native: NativeForce | None, userdata: Sequence[Sequence[float]], threads: int = 1) -> None:
        self.model, self.ids, self.ctrl_per_u = model, ids, ctrl_per_u
        self.native = native
        self.userdata = np.array(userdata, dtype=float).reshape(batch, -1)  # each copy's coefficients
        self.sim = mj_batch.Batch(model, batch, nthread=threads)
        sim = self.sim
        # every field is bound before the first call (an output bound later reads zero until the next)
        self.qpos, self.qvel, self.ctrl = sim.bind("qpos"), sim.bind("qvel"), sim.bind("ctrl")
        self.qfrc_applied, self.user = sim.bind("qfrc_applied"), sim.bind("userdata")
        self.counts = sim.warning[:, _UNSTABLE, 1]  # each copy's "unstable" counters (a view)
        self.seen = 0  # how many were nonzero when last looked at (a dead copy's stay as they were)
        self.dead = np.zeros(batch, dtype=bool)
        self.running: np.ndarray | None = None  # ids of the running copies, None for all

    def reset(self, x0: np.ndarray) -> None:
        """Every copy at ``x0`` (``(batch, 2)``), as ``mj_resetData``, the writes and ``mj_forward``."""
        sim, ids = self.sim, self.ids
        sim.reset(stage=_STAGE_NONE)
        self.qpos[:, ids.qpos] = x0[:, 0]
        self.qvel[:, ids.dof] = x0[:, 1]
        if self.native is not None:
            self.native.fill_rows(self.user, ids.qpos, ids.dof, self.userdata)
        sim.forward()
        self.dead[:] = False
        self.running = None
        self.seen = np.count_nonzero(self.counts)

    def disturb(self, force: float) -> None:
        self.qfrc_applied[:, self.ids.dof] = force

    def state(self) -> np.ndarray:
        out = self.readings()
        if self.running is not None:  # (some copy is dead)
            out[self.dead] = np.nan
        return out

    def readings(self) -> np.ndarray:
        """The joint sensors' readings: ``mj_sensorPos``/``mj_sensorVel`` copy qpos and qvel."""
        out = np.empty((len(self.dead), 2))
        out[:, 0] = self.qpos[:, self.ids.qpos]
        out[:, 1] = self.qvel[:, self.ids.dof]
        return out

    def step(self, u: np.ndarray, substeps: int) -> None:
        """Every running copy through ``substeps`` calls of ``mj_step`` with ``u`` held."""
        self.ctrl[:, self.ids.actuator] = self.ctrl_per_u * u
        self.sim.step(self.running, nstep=substeps, stage=_STAGE_NONE)
        seen = np.count_nonzero(self.counts)  # (a running copy's are all 0: a change is a warning)
        if seen == self.seen:
            return
        self.seen = seen
        reset = self.counts.any(axis=1) & ~self.dead
        if reset.any():  # a copy MuJoCo reset: it stops here (its state reads NaN)
            self.dead |= reset
            self.running = np.flatnonzero(~self.dead).astype(np.int32)
