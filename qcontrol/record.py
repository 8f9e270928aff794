"""Rerun recordings of closed-loop runs: 3-D motion, every signal, Lemma 2 margins, a default layout.

A :class:`Recording` writes one ``.rrd`` file while runs go on. Each run streams into it through an
engine observer (:meth:`Recording.observer`, see :func:`qcontrol.sim.simulate`): every call sends
the rows that became final as columns (``send_columns``) on the duration timeline ``sim_time`` and
flushes them to disk, so an interrupted or diverged run leaves a readable recording up to its
last chunk.

Entity layout (``{L}`` is a ghost run's label, e.g. ``ode``; ``{a}`` the adaptive state's name,
``eps_hat`` or ``theta_hat``; ``i`` counts from 1)::

    world                          view coordinates (MuJoCo is Z-up), static
    world/fixed/{geom}             geoms of MuJoCo's world body, static
    world/bodies/{body}            Transform3D per row: the body pose from the replayed joint position
    world/bodies/{body}/{geom}     the geom's shape and its pose in the body, static
    world/{L}_ghost/{body}[/{geom}]  the same for a ghost run, translucent
    world/target                   Transform3D per row: where the tip geom would be at y_d
    signals/tracking/y, y_d, y_{L}
    signals/error/z1, z1_{L}
    signals/input/u, u_{L}                    (StepAfter: held over the step)
    signals/adaptive/{a}_i
    signals/state/x{i}/x, signals/state/x{i}/q    (q is StepAfter: the quantized reading)
    theory/lemma2/z{i}             |e_zi| / L_zi, Lemma 2 says <= 1
    theory/lemma2/bound            the constant 1 (two rows per streamed chunk)
    info/scenario, info/constants, info/version   static text

Times are integer nanoseconds ``round(t * 1e9)``. Only ``runs[0]`` of a batch is streamed.

File handling: data goes to ``<path>.part`` while the recording is open. On *any* exit of the
``with`` block (clean, exception, ``KeyboardInterrupt``) the stream is flushed and closed and the
file renamed to ``path``: what was recorded up to the last chunk is kept, no temporary file is
left behind. Only a killed process leaves the ``.part`` file (readable up to its last flush).

``Recording(None)`` (no path, no viewer) is inert: it never imports rerun and its observers do
nothing; callers should simply not pass an observer then.
"""

from __future__ import annotations

import os
import re
import shutil
import sys
import warnings
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from types import TracebackType
from typing import TYPE_CHECKING, Any

import numpy as np

from .sim import Observer, Trajectory

if TYPE_CHECKING:
    import mujoco
    import rerun as rr
    import rerun.blueprint as rrb

TIMELINE = "sim_time"

# Colours (RGB) for the series and the scene.
_BLUE, _ORANGE, _GREY, _GREEN, _RED = (
    (31, 119, 180),
    (255, 127, 14),
    (150, 150, 150),
    (44, 160, 44),
    (214, 39, 40),
)
_GHOST_ALPHA = 70
_MAIN_RUN_TAKEN = "a main (non-ghost) run is already being recorded into this file"

# MuJoCo geom types (mjtGeom) and joint types (mjtJoint) that matter here.
_PLANE, _SPHERE, _CAPSULE, _ELLIPSOID, _CYLINDER, _BOX, _MESH = 0, 2, 3, 4, 5, 6, 7
_SLIDE, _HINGE = 2, 3


def temporary_path(path: Path) -> Path:
    """The name a recording is written under until it is closed: ``<path>.part``."""
    return path.with_name(path.name + ".part")


def time_nanoseconds(t: np.ndarray) -> np.ndarray:
    """The ``sim_time`` values logged for times ``t`` (seconds): ``round(t * 1e9)`` as int64 ns."""
    return np.round(np.asarray(t, dtype=float) * 1e9).astype(np.int64)


def _entity_name(name: str, fallback: str) -> str:
    """A MuJoCo name made safe as one entity-path part."""
    cleaned = re.sub(r"[^A-Za-z0-9_\-]", "_", name)
    return cleaned or fallback


def _label_suffix(label: str) -> str:
    cleaned = re.sub(r"[^A-Za-z0-9_\-]", "_", label)
    if not cleaned:
        raise ValueError("a ghost run needs a non-empty label (it names its entities, e.g. 'ode')")
    return cleaned


# --------------------------------------------------------------------------------------------
# 3-D scene from an MjModel


@dataclass(frozen=True)
class _Geom:
    """One drawable MuJoCo geom: its entity name, the rerun shape, its pose in its body."""

    name: str
    body: int
    shape: Callable[[tuple[int, int, int, int]], Any]  # colour -> rerun archetype
    rgba: tuple[int, int, int, int]
    pos: np.ndarray
    quat_xyzw: np.ndarray


def _geom_shape(model: mujoco.MjModel, g: int) -> Callable[[tuple[int, int, int, int]], Any] | None:
    """A factory for the rerun archetype drawing geom ``g`` centred at its frame, or None."""
    import rerun as rr

    kind, size = int(model.geom_type[g]), model.geom_size[g].astype(float)
    solid = rr.components.FillMode.Solid
    if kind == _SPHERE:
        return lambda c: rr.Ellipsoids3D(half_sizes=[[size[0]] * 3], colors=[c], fill_mode=solid)
    if kind == _ELLIPSOID:
        return lambda c: rr.Ellipsoids3D(half_sizes=[size], colors=[c], fill_mode=solid)
    if kind == _CAPSULE:  # MuJoCo: centred, half-length size[1]; rerun: from z=0 to z=length
        return lambda c: rr.Capsules3D(
            lengths=[2 * size[1]], radii=[size[0]], translations=[[0, 0, -size[1]]], colors=[c]
        )
    if kind == _CYLINDER:
        return lambda c: rr.Cylinders3D(lengths=[2 * size[1]], radii=[size[0]], colors=[c], fill_mode=solid)
    if kind == _BOX:
        return lambda c: rr.Boxes3D(half_sizes=[size], colors=[c], fill_mode=solid)
    if kind == _PLANE and size[0] > 0 and size[1] > 0:  # a finite plane; infinite ones are left out
        return lambda c: rr.Boxes3D(half_sizes=[[size[0], size[1], 1e-3]], colors=[c], fill_mode=solid)
    if kind == _MESH and model.geom_dataid[g] >= 0:
        mesh = int(model.geom_dataid[g])
        v0, nv = int(model.mesh_vertadr[mesh]), int(model.mesh_vertnum[mesh])
        f0, nf = int(model.mesh_faceadr[mesh]), int(model.mesh_facenum[mesh])
        vertices = model.mesh_vert[v0 : v0 + nv].copy()
        faces = model.mesh_face[f0 : f0 + nf].copy()
        return lambda c: rr.Mesh3D(vertex_positions=vertices, triangle_indices=faces, albedo_factor=c)
    return None


def _geom_rgba(model: mujoco.MjModel, g: int) -> tuple[int, int, int, int]:
    rgba = model.mat_rgba[model.geom_matid[g]] if model.geom_matid[g] >= 0 else model.geom_rgba[g]
    r, gr, b, a = (int(round(255 * float(np.clip(v, 0.0, 1.0)))) for v in rgba)
    return r, gr, b, a


def _drawable_geoms(model: mujoco.MjModel) -> list[_Geom]:
    """The geoms MuJoCo's viewer shows by default (groups 0-2, not fully transparent)."""
    import mujoco

    geoms = []
    for g in range(model.ngeom):
        shape = _geom_shape(model, g)
        rgba = _geom_rgba(model, g)
        if shape is None or model.geom_group[g] > 2 or rgba[3] == 0:
            continue
        name = _entity_name(mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_GEOM, g) or "", f"geom{g}")
        geoms.append(
            _Geom(
                name,
                int(model.geom_bodyid[g]),
                shape,
                rgba,
                model.geom_pos[g].copy(),
                model.geom_quat[g][[1, 2, 3, 0]].copy(),
            )
        )
    return geoms


class _Scene:
    """Poses of a MuJoCo model's bodies as one 1-DoF joint moves; a private MjData replays it."""

    def __init__(self, model: mujoco.MjModel, joint: str | None) -> None:
        import mujoco

        self.model = model
        self.data = mujoco.MjData(model)
        jid = self._joint_id(model, joint)
        self.qpos_adr = int(model.jnt_qposadr[jid])
        self.geoms = _drawable_geoms(model)
        self.bodies = sorted({g.body for g in self.geoms if g.body > 0})
        self.body_names = {
            b: _entity_name(mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_BODY, b) or "", f"body{b}")
            for b in self.bodies
        }
        self.tip_geom, self.tip_radius = self._tip(jid)
        self._reference_pose(jid)

    @staticmethod
    def _joint_id(model: mujoco.MjModel, joint: str | None) -> int:
        import mujoco

        if joint is None:
            if model.njnt != 1:
                raise ValueError(f"the model has {model.njnt} joints: name the one that x1 drives")
            jid = 0
        else:
            jid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, joint)
            if jid < 0:
                raise ValueError(f"the model has no joint named {joint!r}")
        if int(model.jnt_type[jid]) not in (_SLIDE, _HINGE):
            raise ValueError("the recorded joint must be a hinge or a slide joint (one position x1)")
        return jid

    def _tip(self, jid: int) -> tuple[int, float]:
        """The moving geom farthest from the joint anchor (the bob, the cart) and its size."""
        import mujoco

        model, data = self.model, self.data
        data.qpos[:] = model.qpos0
        mujoco.mj_kinematics(model, data)
        mujoco.mj_comPos(model, data)  # fills xanchor
        joint_body = int(model.jnt_bodyid[jid])
        moving = [g for g in range(model.ngeom) if self._descends(int(model.geom_bodyid[g]), joint_body)]
        if not moving:
            raise ValueError("no geom moves with the recorded joint: nothing to draw the target for")
        anchor = data.xanchor[jid]
        far = max(moving, key=lambda g: (np.linalg.norm(data.geom_xpos[g] - anchor), g))
        return far, float(model.geom_rbound[far])

    def _descends(self, body: int, ancestor: int) -> bool:
        while body > 0:
            if body == ancestor:
                return True
            body = int(self.model.body_parentid[body])
        return body == ancestor

    def replay(self, position: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Body positions (rows, bodies, 3), quaternions xyzw (rows, bodies, 4) and the tip geom's
        position (rows, 3) with the joint at each of ``position``; NaN where it is not finite.

        One joint moves, so every pose is the reference pose (``qpos0``, from ``mj_kinematics``)
        carried by one rigid motion: a rotation by ``q - q0`` about the hinge's world axis through
        its anchor, or a translation by ``q - q0`` along the slide's axis. Bodies that do not
        descend from the joint's body stay put. Evaluated for all rows at once.
        """
        q = np.asarray(position, dtype=float) - self.q0
        ids, moving = self.bodies, self.moving
        rows = len(q)
        xpos = np.broadcast_to(self.xpos0[ids], (rows, len(ids), 3)).copy()
        xquat = np.broadcast_to(self.xquat0[ids], (rows, len(ids), 4)).copy()
        tip = np.broadcast_to(self.tip0, (rows, 3)).copy()
        axis, anchor = self.axis, self.anchor
        if self.hinge:
            half = 0.5 * q
            turn = np.concatenate([np.cos(half)[:, None], np.sin(half)[:, None] * axis], axis=1)  # wxyz
            rotate = _rotation_matrices(turn)
            moved = self.xpos0[ids][moving] - anchor
            xpos[:, moving] = anchor + np.einsum("rij,bj->rbi", rotate, moved)
            xquat[:, moving] = _quat_multiply(turn[:, None, :], self.xquat0[ids][moving][None])
            if self.tip_moves:
                tip = anchor + np.einsum("rij,j->ri", rotate, self.tip0 - anchor)
        else:
            xpos[:, moving] += q[:, None, None] * axis
            if self.tip_moves:
                tip = tip + q[:, None] * axis
        bad = ~np.isfinite(q)
        xpos[bad], xquat[bad], tip[bad] = np.nan, np.nan, np.nan
        return xpos, xquat[..., [1, 2, 3, 0]], tip

    def _reference_pose(self, jid: int) -> None:
        """Poses at ``qpos0`` and the joint's world axis and anchor, for :meth:`replay`."""
        import mujoco

        model, data = self.model, self.data
        data.qpos[:] = model.qpos0
        mujoco.mj_kinematics(model, data)
        mujoco.mj_comPos(model, data)  # fills xanchor, xaxis
        self.q0 = float(model.qpos0[self.qpos_adr])
        self.hinge = int(model.jnt_type[jid]) == _HINGE
        self.axis = data.xaxis[jid].copy()
        self.anchor = data.xanchor[jid].copy()
        self.xpos0, self.xquat0 = data.xpos.copy(), data.xquat.copy()
        self.tip0 = data.geom_xpos[self.tip_geom].copy()
        joint_body = int(model.jnt_bodyid[jid])
        self.moving = np.array([self._descends(b, joint_body) for b in self.bodies], dtype=bool)
        self.tip_moves = self._descends(int(model.geom_bodyid[self.tip_geom]), joint_body)


def _quat_multiply(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product of wxyz quaternions (broadcasting)."""
    aw, ax, ay, az = np.moveaxis(a, -1, 0)
    bw, bx, by, bz = np.moveaxis(b, -1, 0)
    return np.stack([aw * bw - ax * bx - ay * by - az * bz,
                     aw * bx + ax * bw + ay * bz - az * by,
                     aw * by - ax * bz + ay * bw + az * bx,
                     aw * bz + ax * by - ay * bx + az * bw], axis=-1)


def _rotation_matrices(quat: np.ndarray) -> np.ndarray:
    """Rotation matrices (rows, 3, 3) of unit wxyz quaternions (rows, 4)."""
    w, x, y, z = quat.T
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], axis=-1),
        np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], axis=-1),
        np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], axis=-1),
    ], axis=-2)


# --------------------------------------------------------------------------------------------
# Series styles and the blueprint


@dataclass(frozen=True)
class _Series:
    """One scalar time series: where it goes, how it is drawn, which column of a run it is."""

    path: str
    name: str
    color: tuple[int, int, int]
    step: bool
    values: Callable[[Trajectory], np.ndarray]


def _main_series(run: Trajectory, label: str) -> list[_Series]:
    """The series of the main run (see the module docstring for the paths)."""
    n, a = run.x.shape[1], run.adaptive_name
    tag = f" ({label})" if label else ""
    series = [
        _Series("signals/tracking/y", f"y{tag}", _BLUE, False, lambda r: r.x[:, 0]),
        _Series("signals/tracking/y_d", "y_d", _ORANGE, False, lambda r: r.yd[:, 0]),
        _Series("signals/error/z1", f"z1{tag}", _BLUE, False, lambda r: r.z[:, 0]),
        _Series("signals/input/u", f"u{tag}", _BLUE, True, lambda r: r.u),
    ]
    palette = [_BLUE, _ORANGE, _GREEN, _RED, (148, 103, 189), (140, 86, 75)]
    for j in range(run.adaptive.shape[1]):
        series.append(
            _Series(
                f"signals/adaptive/{a}_{j + 1}",
                f"{a}_{j + 1}",
                palette[j % len(palette)],
                False,
                lambda r, j=j: r.adaptive[:, j],
            )
        )
    for i in range(n):
        base = f"signals/state/x{i + 1}"
        series.append(_Series(f"{base}/x", f"x{i + 1}", _BLUE, False, lambda r, i=i: r.x[:, i]))
        series.append(_Series(f"{base}/q", f"q(x{i + 1})", _RED, True, lambda r, i=i: r.x_q[:, i]))
    for i in range(n):
        series.append(
            _Series(
                f"theory/lemma2/z{i + 1}",
                f"|e_z{i + 1}| / L_z{i + 1}",
                palette[i % len(palette)],
                False,
                lambda r, i=i: r.e_z[:, i] / r.L_z[i],
            )
        )
    return series


def _ghost_series(suffix: str) -> list[_Series]:
    """The series of a ghost run (the ODE twin beside the MuJoCo run)."""
    return [
        _Series(f"signals/tracking/y_{suffix}", f"y ({suffix})", _GREY, False, lambda r: r.x[:, 0]),
        _Series(f"signals/error/z1_{suffix}", f"z1 ({suffix})", _GREY, False, lambda r: r.z[:, 0]),
        _Series(f"signals/input/u_{suffix}", f"u ({suffix})", _GREY, True, lambda r: r.u),
    ]


def default_blueprint(n: int) -> rrb.Blueprint:
    """The layout a recording opens with: motion on the left, tracking and error on the right.

    Left column: the 3-D view (``world``) over tabs with the scenario text, the constants and the
    version. Right column, top to bottom: y with y_d (and the ghost's y), the tracking error z1, the
    input u, and tabs for each x_i beside q(x_i), the adaptive estimates and the Lemma 2 ratios.
    """
    import rerun.blueprint as rrb

    detail = [
        rrb.TimeSeriesView(origin=f"signals/state/x{i + 1}", name=f"x{i + 1} and q(x{i + 1})")
        for i in range(n)
    ]
    detail += [
        rrb.TimeSeriesView(origin="signals/adaptive", name="adaptive estimates"),
        rrb.TimeSeriesView(origin="theory/lemma2", name="Lemma 2: |e_zi| / L_zi <= 1"),
    ]
    left = rrb.Vertical(
        rrb.Spatial3DView(origin="world", name="motion"),
        rrb.Tabs(
            rrb.TextDocumentView(origin="info/scenario", name="scenario"),
            rrb.TextDocumentView(origin="info/constants", name="constants"),
            rrb.TextDocumentView(origin="info/version", name="version"),
        ),
        row_shares=[3, 1],
    )
    right = rrb.Vertical(
        rrb.TimeSeriesView(origin="signals/tracking", name="output y and reference y_d"),
        rrb.TimeSeriesView(origin="signals/error", name="tracking error z1 = y - y_d"),
        rrb.TimeSeriesView(origin="signals/input", name="input u"),
        rrb.Tabs(*detail),
        row_shares=[1, 1, 1, 1.3],
    )
    return rrb.Blueprint(
        rrb.Horizontal(left, right, column_shares=[1, 1]),
        rrb.TimePanel(timeline=TIMELINE, expanded=True),
        rrb.BlueprintPanel(expanded=False),
        rrb.SelectionPanel(expanded=False),
    )


# --------------------------------------------------------------------------------------------
# The recording


def _viewer_executable() -> str | None:
    """The rerun viewer: on PATH, else beside this interpreter (a venv not on PATH), else None."""
    found = shutil.which("rerun")
    if found is None:
        beside = Path(sys.executable).with_name("rerun")
        found = str(beside) if beside.exists() else None
    return found


def _ignore(start: int, stop: int, runs: list[Trajectory]) -> None:
    """The observer of an inert recording."""


class Recording:
    """A rerun recording of one or more closed-loop runs, written while they go on.

    Use as a context manager; see the module docstring for the entity layout and file handling.
    ``path=None`` with ``spawn=False`` gives an inert recording that logs nothing and costs nothing.
    ``spawn=True`` opens a viewer (when one can be started) and streams to it as well.
    """

    def __init__(self, path: Path | None, *, spawn: bool = False, application_id: str = "qcontrol") -> None:
        self.path = None if path is None else Path(path)
        self.spawn = spawn
        self.application_id = application_id
        self._stream: rr.RecordingStream | None = None
        self._main_taken = False
        self._ghosts: set[str] = set()
        self._blueprint_sent = False
        self._fixed_logged = False
        self._flush_failed = False
        if self.path is not None or spawn:
            self._open()

    @property
    def enabled(self) -> bool:
        """Whether this recording logs anything (it is open, with a file, a viewer or both)."""
        return self._stream is not None

    @property
    def part_path(self) -> Path | None:
        """Where the file is written until the recording is closed."""
        return None if self.path is None else temporary_path(self.path)

    def _open(self) -> None:
        import rerun as rr

        stream = rr.RecordingStream(self.application_id)
        sinks: list[Any] = []
        if self.part_path is not None:
            self.part_path.parent.mkdir(parents=True, exist_ok=True)
            sinks.append(rr.FileSink(str(self.part_path)))
        if self.spawn:
            try:
                rr.spawn(connect=False, recording=stream, executable_path=_viewer_executable())
                sinks.append(rr.GrpcSink())
            except Exception as exc:  # no viewer available: keep the file, if any
                warnings.warn(
                    f"could not start a rerun viewer ({exc}); not streaming to a viewer", stacklevel=3
                )
        if not sinks:  # nowhere to write: stay inert rather than buffer the run in memory
            return
        stream.set_sinks(*sinks)
        stream.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
        self._stream = stream

    def __enter__(self) -> Recording:
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.close()

    def close(self) -> None:
        """Flush and close the stream, then rename the file to its final name (idempotent)."""
        if self._stream is None:
            return
        try:
            self.flush()
            self._stream.disconnect()  # closes the file: writes rerun's footer
        finally:
            self._stream = None
            part = self.part_path
            if part is not None and part.exists():
                os.replace(part, self.path)

    def flush(self) -> None:
        """Block until everything logged so far is written; a failure (e.g. a viewer that went
        away) is reported once as a warning and does not stop the run."""
        if self._stream is None:
            return
        try:
            self._stream.flush()
        except RuntimeError as exc:
            if not self._flush_failed:
                warnings.warn(f"rerun could not flush the recording: {exc}", stacklevel=2)
            self._flush_failed = True

    # -- static content -------------------------------------------------------------------

    def log_static(
        self, scenario_text: str, constants: Mapping[str, float | Sequence[float]], version: str
    ) -> None:
        """Log the scenario file's text, the controller constants and the package version."""
        if self._stream is None:
            return
        import rerun as rr

        markdown = rr.components.MediaType.MARKDOWN
        self._stream.log(
            "info/scenario",
            rr.TextDocument(f"```toml\n{scenario_text}\n```", media_type=markdown),
            static=True,
        )
        rows = "\n".join(f"| {key} | {_format_constant(value)} |" for key, value in constants.items())
        values = {key: np.atleast_1d(np.asarray(value, dtype=float)) for key, value in constants.items()}
        self._stream.log(
            "info/constants",
            rr.TextDocument(f"| constant | value |\n|---|---|\n{rows}\n", media_type=markdown),
            rr.AnyValues(**values),
            static=True,
        )
        self._stream.log(
            "info/version", rr.TextDocument(f"qcontrol {version}"), rr.AnyValues(version=version), static=True
        )

    # -- runs ------------------------------------------------------------------------------

    def observer(
        self,
        label: str,
        model: mujoco.MjModel | None = None,
        joint: str | None = None,
        ghost: bool = False,
    ) -> Observer:
        """An engine observer streaming ``runs[0]`` of a :func:`~qcontrol.sim.simulate` call.

        ``label`` names the run ("mujoco", "ode"): it tags the main run's series names and, for a
        ghost, its entity paths (``world/{label}_ghost``, ``signals/tracking/y_{label}``, ...).
        With ``model`` the bodies are drawn and posed by replaying x1 into ``joint`` (a hinge or
        slide; may be omitted when the model has one joint). One main run per recording; a ghost
        run adds the translucent twin and its y, z1, u.
        """
        if self._stream is None:
            return _ignore
        if ghost:
            suffix = _label_suffix(label)
            if suffix in self._ghosts:
                raise ValueError(f"a ghost run labelled {label!r} is already being recorded")
            self._ghosts.add(suffix)
            world = f"world/{suffix}_ghost"
        else:
            if self._main_taken:
                raise ValueError(_MAIN_RUN_TAKEN)
            self._main_taken = True
            suffix, world = "", "world/bodies"
        scene = None if model is None else _Scene(model, joint)
        if scene is not None:
            self._log_scene(scene, world, ghost)
        return _RunStreamer(self, label, suffix, ghost, scene, world)

    def _log_scene(self, scene: _Scene, world: str, ghost: bool) -> None:
        """The static geometry: shapes in their bodies, world-body geoms, the target marker."""
        import rerun as rr

        stream = self._stream
        for geom in scene.geoms:
            if geom.body == 0 and self._fixed_logged:
                continue
            parent = "world/fixed" if geom.body == 0 else f"{world}/{scene.body_names[geom.body]}"
            rgba = (*geom.rgba[:3], _GHOST_ALPHA) if ghost else geom.rgba
            stream.log(
                f"{parent}/{geom.name}",
                rr.Transform3D(translation=geom.pos, quaternion=rr.Quaternion(xyzw=geom.quat_xyzw)),
                geom.shape(rgba),
                static=True,
            )
        self._fixed_logged = True
        if not ghost:
            radius = 1.3 * max(scene.tip_radius, 0.01)
            stream.log(
                "world/target",
                rr.Ellipsoids3D(
                    half_sizes=[[radius] * 3],
                    colors=[(*_RED, 255)],
                    fill_mode=rr.components.FillMode.MajorWireframe,
                ),
                static=True,
            )

    def _send_blueprint(self, n: int) -> None:
        if not self._blueprint_sent:
            self._stream.send_blueprint(default_blueprint(n), make_active=False, make_default=True)
            self._blueprint_sent = True


def _format_constant(value: float | Sequence[float]) -> str:
    values = np.atleast_1d(np.asarray(value, dtype=float))
    text = ", ".join(f"{v:.6g}" for v in values)
    return text if np.ndim(value) == 0 else f"[{text}]"


class _RunStreamer:
    """The observer of one run: sends each batch of final rows as columns and flushes them."""

    def __init__(
        self, recording: Recording, label: str, suffix: str, ghost: bool, scene: _Scene | None, world: str
    ) -> None:
        self.recording = recording
        self.label = label
        self.suffix = suffix
        self.ghost = ghost
        self.scene = scene
        self.world = world
        self.series: list[_Series] | None = None

    def __call__(self, start: int, stop: int, runs: list[Trajectory]) -> None:
        stream = self.recording._stream
        if stream is None or not runs:
            return
        run = runs[0]
        stop = min(stop, len(run.t))
        if start >= stop:
            return
        if self.series is None:
            self._start(run)
        rows = slice(start, stop)
        times = self._time_column(run.t[rows])
        import rerun as rr

        for s in self.series:
            stream.send_columns(
                s.path, indexes=[times], columns=rr.Scalars.columns(scalars=s.values(run)[rows])
            )
        if not self.ghost:
            ends = self._time_column(run.t[[start, stop - 1]])
            stream.send_columns(
                "theory/lemma2/bound", indexes=[ends], columns=rr.Scalars.columns(scalars=[1.0, 1.0])
            )
        if self.scene is not None:
            self._send_poses(run, rows, times)
        self.recording.flush()

    @staticmethod
    def _time_column(t: np.ndarray) -> rr.TimeColumn:
        import rerun as rr

        return rr.TimeColumn(TIMELINE, duration=time_nanoseconds(t).view("timedelta64[ns]"))

    def _start(self, run: Trajectory) -> None:
        """On the first rows: the series styles (static) and, once per file, the blueprint."""
        import rerun as rr

        stream = self.recording._stream
        self.series = _ghost_series(self.suffix) if self.ghost else _main_series(run, self.label)
        for s in self.series:
            mode = "StepAfter" if s.step else "Linear"
            stream.log(
                s.path, rr.SeriesLines(names=s.name, colors=[s.color], interpolation_mode=mode), static=True
            )
        if not self.ghost:
            stream.log("theory/lemma2/bound", rr.SeriesLines(names="bound 1", colors=[_RED]), static=True)
        self.recording._send_blueprint(run.x.shape[1])

    def _send_poses(self, run: Trajectory, rows: slice, times: rr.TimeColumn) -> None:
        import rerun as rr

        stream, scene = self.recording._stream, self.scene
        pos, quat, _ = scene.replay(run.x[rows, 0])
        for j, body in enumerate(scene.bodies):
            stream.send_columns(
                f"{self.world}/{scene.body_names[body]}",
                indexes=[times],
                columns=rr.Transform3D.columns(translation=pos[:, j], quaternion=quat[:, j]),
            )
        if not self.ghost:
            _, _, target = scene.replay(run.yd[rows, 0])
            stream.send_columns(
                "world/target", indexes=[times], columns=rr.Transform3D.columns(translation=target)
            )
