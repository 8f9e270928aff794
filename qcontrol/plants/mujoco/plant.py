"""The MuJoCo-backed plant of eq. (1) with n = 2: one joint of an MJCF model.

How the ODE maps to the model. The plant of eq. (1),

    x1' = x2,    x2' = u + psi(x) + theta^T phi(x),

is one scalar joint with x1 = its position (``qpos``) and x2 = its velocity (``qvel``). MuJoCo
integrates ``I qacc = tau + qfrc_bias + qfrc_passive`` where ``I`` is the joint's generalized
inertia. So:

* ``u`` is acceleration-level (the ODE's unit input gain); the actuator command is ``I * u``
  (divided by the motor's gain), with ``I`` read from the model by ``mujoco.mj_fullM``. A scenario
  that states ``plant.input_gain = b`` instead commands the actuator with u itself: the model then
  realises ``x2' = (gear / I) u + ...``, and b must be that ``gear / I`` (checked at load).
* Terms MuJoCo's own physics produces (``native_terms``, e.g. joint damping for ``theta1 * x2``
  and gravity for ``theta3 * sin(x1)`` in Example 2) are left to MuJoCo; every other term is
  added by the passive callback (:mod:`.callbacks`): compiled code (:mod:`.native`) where numba
  is available, the same arithmetic in Python otherwise.
* The controller reads ``sensordata`` (jointpos, jointvel sensors), never ``qpos``/``qvel``.

Realism options (each off by default) make the model differ from eq. (1) as hardware would; the
actuator gain and the callback keep using the nominal inertia, so armature and rod mass act as
unmodelled dynamics. ``sensor_noise`` is added by the plant (MuJoCo's sensor ``noise`` attribute
is metadata only), seeded by ``noise_seed``, each copy of a batch from its own seed's stream
(:mod:`.noise`); ``sensor_delay`` and ``sensor_period`` use MuJoCo's
sensor history (``nsample``/``delay``/``interval``); the readings before t = delay are x(0).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import mujoco
import numpy as np

from ... import compiled as compiled_paths
from ...compiled.traced import TRACED, TracedForm
from ...errors import QcontrolInputError
from ...timegrid import whole_steps
from ..base import NativeStepper, PlantTerms
from . import native_step
from .callbacks import (
    GeneralizedForce,
    collect_warnings,
    kept_aside,
    passive_forces,
    python_callback_installed,
    untimed,
)
from .consistency import consistency_report, filter_consistency_report
from .mjcf import CompiledModel, check_input_gain, compiled
from .native import NativeForce, native_force
from .native_step import MujocoNativeForm, warning_counters
from .noise import SensorNoise
from .options import MujocoOptions
from .threaded import ThreadedCopies, threadable


class MujocoPlant:
    """Batch of ``batch`` MuJoCo copies of the plant of eq. (1), n = 2 (see the module docstring).

    ``timestep`` is the scenario's dt: ``model.opt.timestep`` is set to it, so ``step(u, dt)`` is
    one ``mj_step``; a step ``h`` that is a multiple of it takes several. After construction,
    ``consistency_report`` holds the measured agreement of MuJoCo's acceleration with eq. (1).
    ``copies`` (one per copy, default ``terms`` for all) may differ from ``terms`` in theta: each
    copy's coefficients of the terms the passive callback adds are its own (the model's own
    physics, which makes the native terms, is shared); ``noise_seeds``: each copy's seed of its
    sensor noise (default ``options.noise_seed`` for all).
    """

    def __init__(self, options: MujocoOptions, terms: PlantTerms, batch: int = 1,
                 timestep: float | None = None, copies: Sequence[PlantTerms] | None = None,
                 noise_seeds: Sequence[int | None] | None = None) -> None:
        where = options.where
        if terms.order != (2 if options.activation_sensor is None else 3):
            raise QcontrolInputError(
                f"{where}: the MuJoCo backend models one joint (plant order 2), or one driven through a "
                f"filter actuator read by activation_sensor (order 3), but the plant has order "
                f"{terms.order}; "
                "use backend = \"ode\" for this scenario"
            )
        if batch < 1:
            raise QcontrolInputError(f"{where}: batch must be >= 1, got {batch}")
        if timestep is not None and not (math.isfinite(timestep) and timestep > 0):
            raise QcontrolInputError(f"{where}: timestep must be a finite number > 0, got {timestep!r}")
        self.n, self.batch, self.options = terms.order, int(batch), options
        built = compiled(options, timestep)
        self.model, self._ids, self.inertia = built.model, built.ids, built.inertia
        self.timestep = float(self.model.opt.timestep)
        for key, value in (("sensor_delay", options.sensor_delay), ("sensor_period", options.sensor_period)):
            if value > 0:
                whole_steps(value, self.timestep, f"{where}.{key}", "the scenario's dt")
        check_input_gain(built, terms, where)
        self._ctrl_per_u = built.ctrl_per_u(terms)
        self._ctrl_range = _ctrl_range(self.model, self._ids.actuator)  # (low, high) or None
        self.actuator_limited = self._ctrl_range is not None
        native = tuple(name in options.native_terms for name in terms.names)
        copies = _copies(terms, copies, self.batch, where)
        applied = [e for e, n in zip(terms.expressions, native, strict=True) if not n]
        coefficients = [tuple(c for c, n in zip(t.coefficients, native, strict=True) if not n)
                        for t in copies]
        self._forces = _forces(applied, coefficients, self.inertia) if applied else None
        self._applied, self._built_native = tuple(applied), None  # (native_for_run)
        # a batch decides its stepping here (mujoco.batch needs the native callback); a single
        # copy at each run, where the engine says whether compiled code pays (__enter__)
        self._native = self.native_for_run() if self.batch > 1 else None
        # each copy's products I c_i, the numbers the Python force uses (theta per copy)
        self._userdata = [[self.inertia * c for c in row] for row in coefficients]
        self._datas = [mujoco.MjData(self.model) for _ in range(self.batch)]
        self._views = [(d.ctrl, d.sensordata, d.qpos, d.qvel) for d in self._datas]
        self._sadr = (int(self.model.sensor_adr[self._ids.position_sensor]),
                      int(self.model.sensor_adr[self._ids.velocity_sensor]))
        self._activation = _Activation(built) if self.n == 3 else None
        self._dead = [False] * self.batch
        self._steppers: dict[float, list[CopyStepper]] = {}  # h -> one per copy
        seeds = list(noise_seeds) if noise_seeds is not None else [options.noise_seed] * self.batch
        if len(seeds) != self.batch:
            raise ValueError(f"{where}: {len(seeds)} noise seeds for {self.batch} copies")
        self._noise = SensorNoise(options.sensor_noise, seeds)
        self._noisy = bool(self._noise.std.any())
        self._entered: list[Any] = []
        eligible = self.n == 2 and threadable(self.model, self.batch, self._native, self._forces is not None)
        self._threaded = (ThreadedCopies(self.model, self._ids, self.batch, self._ctrl_per_u, self._native,
                                         self._userdata) if eligible and compiled_paths.requested() else None)
        self._threads = False  # whether this run steps the copies on the batch (set at __enter__)
        self.warnings: list[str] = []  # MuJoCo's warnings during the last run
        with kept_aside():  # the model check's warnings, outside any run
            force = None if self._forces is None else self._forces[0]
            self.consistency_report = (consistency_report(built, options, terms, native, force) if self.n == 2
                                       else filter_consistency_report(built, options, terms))

    # ---- context manager: the process-global passive callback, and the run's warnings
    def __enter__(self) -> MujocoPlant:
        if self._entered:
            raise RuntimeError("MujocoPlant is already in use by a 'with' block")
        self.warnings = []
        self._steppers = {}  # (they hold the warnings list)
        if self.batch == 1:
            self._native = self.native_for_run()
        if self._native is not None:
            for data, userdata in zip(self._datas, self._userdata, strict=True):
                self._native.fill(data, self._ids.qpos, self._ids.dof, userdata)
        self._entered = [passive_forces(self.model, self._datas, self._ids.qpos, self._ids.dof, self._forces,
                                        self._native),
                         collect_warnings(self.warnings), untimed()]
        for manager in self._entered:
            manager.__enter__()
        self._threads = self._threaded is not None and not python_callback_installed()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def native_for_run(self) -> NativeForce | None:
        """The passive terms as the native callback (:mod:`.native`), compiled or loaded once per
        plant, where compiled paths are requested now (the engine turns them off for a single run
        too short to pay for numba's start, :func:`qcontrol.compiled.not_needed`); None: the
        Python callback (the same numbers)."""
        if not self._applied or not compiled_paths.requested():
            return None
        if self._built_native is None:
            self._built_native = native_force(self._applied)
        return self._built_native

    def close(self) -> None:
        """Remove the passive callback's entries and stop collecting warnings (the end of a run)."""
        managers, self._entered = self._entered, []
        for manager in reversed(managers):
            manager.__exit__(None, None, None)

    # ---- Plant protocol
    def reset(self, x0: np.ndarray) -> None:
        """Put every copy at ``x0`` (shape ``(batch, n)``; for n = 3 the activation ``x3 / (gear /
        I)``); sensor histories are filled with it."""
        x0 = np.broadcast_to(np.asarray(x0, dtype=float), (self.batch, self.n))
        self._noise.reset()
        if self._threads:
            self._threaded.reset(x0)
            return
        model, ids = self.model, self._ids
        for b, data in enumerate(self._datas):
            mujoco.mj_resetData(model, data)
            if self._native is not None:  # (reset zeroes userdata)
                self._native.fill(data, ids.qpos, ids.dof, self._userdata[b])
            data.qpos[ids.qpos] = x0[b, 0]
            data.qvel[ids.dof] = x0[b, 1]
            if self._activation is not None:
                data.act[ids.act] = x0[b, 2] / self._activation.per_act
            mujoco.mj_forward(model, data)
            for sid, value in ((ids.position_sensor, x0[b, 0]), (ids.velocity_sensor, x0[b, 1])):
                nsample = int(model.sensor_history[sid, 0])
                if nsample > 0:  # the sensor has read x(0) for all t < 0
                    mujoco.mj_initSensorHistory(model, data, sid, None, np.full((nsample, 1), value), 0.0)
            if model.nhistory:
                mujoco.mj_forward(model, data)
        self._dead[:] = [False] * self.batch  # in place: the steppers hold this list

    def disturb(self, d: float) -> None:
        """The external load d (u's units) as the generalized force ``I d`` in ``qfrc_applied``
        (``I`` the nominal inertia, as for u), held until changed; ``mj_resetData`` clears it."""
        force = self.inertia * float(d)
        if self._threads:
            self._threaded.disturb(force)
            return
        for data in self._datas:
            data.qfrc_applied[self._ids.dof] = force

    def actuator(self, u: np.ndarray) -> np.ndarray:
        """u as the motor applies it: MuJoCo clamps the command ``ctrl = (I / gain) u`` to the
        actuator's ctrlrange (``+-torque_limit``), so where ``ctrl`` leaves the range the applied
        input is the range's end divided by ``I / gain``; elsewhere u itself."""
        if self._ctrl_range is None:
            return u
        low, high = self._ctrl_range
        u = np.asarray(u, dtype=float)
        ctrl = self._ctrl_per_u * u  # the very product the step writes into ctrl
        return np.where(ctrl < low, low / self._ctrl_per_u, np.where(ctrl > high, high / self._ctrl_per_u, u))

    def state(self) -> np.ndarray:
        """The true ``(qpos, qvel)`` of every copy, and for n = 3 the scaled activation (NaN for a copy
        MuJoCo had to reset)."""
        return self._threaded.state() if self._threads else self._copies_read()[:, :self.n]

    def read_sensors(self) -> np.ndarray:
        """``sensordata`` of the position and velocity sensors (plus noise, if configured)."""
        return self.observe()[1]

    def sensor_noise(self) -> np.ndarray:
        """The noise of one reading of every copy, ``(batch, 2)``: one draw per reading from each
        copy's seeded stream (:mod:`.noise`, the one place it is drawn, whichever form reads the
        sensors)."""
        return self._noise.draw()

    def observe(self) -> tuple[np.ndarray, np.ndarray]:
        """The true state and the sensors' reading (plus noise, if configured) of every copy, NaN
        for a copy MuJoCo had to reset: without threads, one pass over the copies (two views of
        one array)."""
        if self._threads:
            x, reading, dead = self._threaded.state(), self._threaded.readings(), self._threaded.dead
        else:
            both = self._copies_read()
            x, reading, dead = both[:, :self.n], both[:, self.n:], None  # (a dead copy's row is NaN already)
        if self._noisy:
            reading += self.sensor_noise()
        if dead is not None:
            reading[dead] = np.nan
        return x, reading

    def _copies_read(self) -> np.ndarray:
        """``(qpos, qvel, position sensor, velocity sensor)`` of every copy, ``(batch, 4)``; for
        n = 3 ``(qpos, qvel, x3, the three readings)``, ``(batch, 6)``; NaN for a copy MuJoCo had to
        reset."""
        q, dof = self._ids.qpos, self._ids.dof
        p, v = self._sadr
        views, dead, read_copy = self._views, self._dead, native_step.read_copy
        rows = np.array([read_copy(qpos, qvel, data, q, dof, p, v, dead[b], True)
                         for b, (_, data, qpos, qvel) in enumerate(views)])
        return rows if self._activation is None else self._activation.read(rows, self._datas, dead)

    def step(self, u: np.ndarray, h: float) -> None:
        """Hold ``u`` for ``h`` seconds: ``h / timestep`` calls of ``mj_step`` per copy.

        ``mj_step`` leaves ``sensordata`` at the state before its last substep, so
        ``mj_sensorPos``/``mj_sensorVel`` then bring the (joint position and velocity) sensors to
        the new state; with a sensor delay they read MuJoCo's history buffer instead.
        """
        if not self._entered and self._forces is not None:
            raise RuntimeError("use MujocoPlant in a 'with' block: its passive callback is installed there")
        if self._threads:
            substeps = whole_steps(h, self.timestep, f"{self.options.where}: step", "the model timestep")
            self._threaded.step(np.broadcast_to(np.asarray(u, dtype=float).ravel(), (self.batch,)), substeps)
            return
        steppers = self._steppers.get(h) or self._make_steppers(h)
        values = (u if isinstance(u, np.ndarray) else np.asarray(u, dtype=float)).ravel().tolist()
        if len(values) != self.batch:
            values = values * self.batch if len(values) == 1 else list(np.broadcast_to(values, (self.batch,)))
        for stepper, value in zip(steppers, values):  # noqa: B905 (one value per copy)
            stepper.step(value)

    def _make_steppers(self, h: float) -> list[CopyStepper]:
        """One :class:`CopyStepper` per copy for steps of ``h``, made once per step length and
        ``with`` block (they hold its list of MuJoCo warnings)."""
        substeps = whole_steps(h, self.timestep, f"{self.options.where}: step", "the model timestep")
        steppers = self._steppers[h] = [CopyStepper(self, b, substeps) for b in range(self.batch)]
        return steppers

    def native_stepper(self, h: float, readings: int = 0, form: TracedForm = TRACED) -> NativeStepper | None:
        """The copies as source text for the engine's compiled loop (:mod:`.native_step`; a batch
        of one in :data:`TRACED`, a batch of copies in ``TracedForm(batch)``, each copy its own
        ``MjData``), where compiled code can give the Python loop's numbers: order 2, and the passive
        terms, if any, in the native callback MuJoCo calls itself; with sensor noise, a batch of one
        whose ``readings`` readings' noise is drawn ahead (None without that count). A batch that
        was to step on ``mujoco.batch`` (the same numbers) moves to its ``MjData`` here, at the state
        it was reset to."""
        if (not self._entered or form.batch != self.batch or self.n != 2
                or (self._noisy and (readings <= 0 or self.batch != 1))):
            return None
        if python_callback_installed() or (self._forces is not None and self._native is None):
            return None
        substeps = whole_steps(h, self.timestep, f"{self.options.where}: step", "the model timestep")
        if self._threads:
            start = self._threaded.state()
            self._threads = False
            self.reset(start)
        return MujocoNativeForm(self, substeps, readings).stepper()


class FilteredJointPlant(MujocoPlant):
    """The plant of order 3 (a joint driven through a filter actuator), which takes no external
    load: a load torque on the joint enters x2', not the last equation x3' where eq. (1)'s matched
    load, and so the ODE twin's, enters; a ``[[disturbance]]`` is refused before a run starts."""

    disturb = None  # type: ignore[assignment]  (not Disturbable)


class CopyStepper:
    """Copy ``b`` of a :class:`MujocoPlant` through ``substeps`` calls of ``mj_step`` with u held;
    a copy MuJoCo reported unstable is marked dead and no longer stepped."""

    def __init__(self, plant: MujocoPlant, b: int, substeps: int) -> None:
        self.b, self.substeps = b, substeps
        self.model, self.data, self.ctrl = plant.model, plant._datas[b], plant._views[b][0]
        self.dead, self.warning = plant._dead, warning_counters(self.data)
        self.actuator, self.ctrl_per_u = plant._ids.actuator, plant._ctrl_per_u
        self.activation = plant._activation is not None

    def step(self, u: float) -> None:
        """:func:`~.native_step.step_copy`, the one definition the compiled loop compiles too; for
        n = 3 the actuator's force and the acceleration-stage sensors (its actuatorfrc sensor) are
        then brought to the new activation too (``mj_fwdActuation``, ``mj_sensorAcc``)."""
        b = self.b
        if not self.dead[b] and native_step.step_copy(self.model, self.data, self.ctrl, self.actuator,
                                                      self.ctrl_per_u, u, self.substeps, self.warning, True):
            self.dead[b] = True
        elif self.activation:
            mujoco.mj_fwdActuation(self.model, self.data)
            mujoco.mj_sensorAcc(self.model, self.data)


class _Activation:
    """Order 3: x3 and its reading from a filter actuator's activation. MuJoCo integrates ``act``
    with the joint (its RK4 too); x3 = (gear / I) act makes x2' = x3 + ..., and the actuatorfrc
    sensor reads the actuator's force ``gain act``, so the reading of x3 is gear / I times it."""

    def __init__(self, built: CompiledModel) -> None:
        self.per_act, self.per_reading = built.x3_per_act, built.x3_per_reading
        self.act = built.ids.act
        self.sensor = int(built.model.sensor_adr[built.ids.activation_sensor])

    def read(self, rows: np.ndarray, datas: Sequence[mujoco.MjData], dead: Sequence[bool]) -> np.ndarray:
        """``(x1, x2, x3, m1, m2, m3)`` from ``read_copy``'s rows ``(x1, x2, m1, m2)``."""
        third = np.array([[math.nan, math.nan] if dead[b] else
                          [self.per_act * d.act[self.act], self.per_reading * d.sensordata[self.sensor]]
                          for b, d in enumerate(datas)]).reshape(-1, 2)
        return np.column_stack([rows[:, :2], third[:, 0], rows[:, 2:], third[:, 1]])


def _copies(terms: PlantTerms, copies: Sequence[PlantTerms] | None, batch: int,
            where: str) -> list[PlantTerms]:
    """Each copy's terms: ``copies`` (variants that differ at most in theta), else ``terms`` for all."""
    if copies is None:
        return [terms] * batch
    copies = list(copies)
    form = _form(terms)
    same_form = all(_form(t) == form for t in copies)
    if len(copies) != batch or not same_form:
        raise ValueError(f"{where}: a batch's copies must be {batch} variants of one plant, "
                         "differing at most in theta")
    return copies


def _form(terms: PlantTerms) -> tuple:
    return (terms.order, None if terms.psi is None else terms.psi.source, tuple(p.source for p in terms.phi),
            terms.input_gain)


def _forces(applied: Sequence, coefficients: Sequence[tuple[float, ...]],
            inertia: float) -> list[GeneralizedForce]:
    """One Python force per copy (copies with the same coefficients share one)."""
    made: dict[tuple[float, ...], GeneralizedForce] = {}
    for row in coefficients:
        if row not in made:
            made[row] = GeneralizedForce(list(zip(row, applied, strict=True)), inertia)
    return [made[row] for row in coefficients]


def _ctrl_range(model: mujoco.MjModel, actuator: int) -> tuple[float, float] | None:
    """The range MuJoCo clamps the actuator's ctrl to, or None when it does not clamp."""
    clamping = not model.opt.disableflags & int(mujoco.mjtDisableBit.mjDSBL_CLAMPCTRL)
    if not (clamping and model.actuator_ctrllimited[actuator]):
        return None
    low, high = model.actuator_ctrlrange[actuator]
    return float(low), float(high)
