"""Frames of a run as MuJoCo draws them: the model posed at a recorded joint position, seen from
one of the model's named cameras, with the reference and the quantized reading marked and an
overlay of t, q(x1), u.

The model is posed on private ``MjData`` by kinematics alone (``mj_kinematics``, ``mj_comPos``,
``mj_camlight``): no force, no callback, no step, so rendering cannot touch the plant it draws.
Markers: a translucent red ball where the tip would be at ``y_d``, a small yellow ball where it
would be at the controller's reading ``q(x1)``; a comparison's twin is the same bodies again,
translucent blue (:meth:`FrameRenderer.render`'s ``twin``).
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np

from ..errors import QcontrolInputError
from ..recording.scene import Scene
from .context import open_context

TARGET_RGBA = (0.9, 0.15, 0.15, 0.35)  # where the tip would be at y_d
READING_RGBA = (1.0, 0.85, 0.1, 1.0)  # where the tip would be at q(x1)
TWIN_RGBA = (0.35, 0.6, 1.0, 0.35)  # the ODE twin's bodies
MAX_GEOMS = 500


@dataclass(frozen=True)
class Instant:
    """What one frame shows: the time, the joint position x1 and the reading q(x1), the input u,
    the reference y_d and, in a comparison, the twin's x1."""

    t: float
    x1: float
    q1: float
    u: float
    yd: float
    twin_x1: float | None = None


DEFAULT_CAMERA = -1  # a model without a <camera>: a free camera framing the moving body (:func:`framing`)
DEFAULT_CAMERA_NAME = "default"
FRAMED = 1.25  # the body's reach fills 1 / FRAMED of the default camera's view
KEY_LIGHT = {"diffuse": (0.7, 0.7, 0.7), "ambient": (0.35, 0.35, 0.35), "specular": (0.2, 0.2, 0.2)}


def camera_id(model: mujoco.MjModel, name: str | None, source: str) -> int:
    """The id of the model's camera ``name`` (None: its first camera, or :data:`DEFAULT_CAMERA` for
    a model without one); one line if the model has no camera of that name."""
    if name is None:
        return 0 if model.ncam else DEFAULT_CAMERA
    cid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_CAMERA, name)
    if cid < 0:
        names = [mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_CAMERA, i) for i in range(model.ncam)]
        raise QcontrolInputError(f"--video-camera {name}: the model has no camera of that name; it has "
                                 f"{', '.join(map(repr, names)) or 'none'}")
    return cid


def overlay_input_unit(position: str, order: int, input_gain: float) -> str:
    """The overlay's unit of u: x1's n-th derivative where the input gain is 1 (eq. (1); on MuJoCo
    an unstated gain is the inertia's own scaling); with another gain b, u is the actuator's own
    input (x1's n-th derivative is b u), shown without a unit."""
    return f"{position}/s^{order}" if input_gain == 1.0 else ""


class FrameRenderer:
    """Renders ``width`` x ``height`` RGB frames of ``model`` with ``joint`` at given positions,
    from camera ``camera`` (an id, :func:`camera_id`; :data:`DEFAULT_CAMERA` frames the body over
    the joint ``positions`` the frames will show). Use as a context manager (it holds a GL
    context)."""

    def __init__(self, model: mujoco.MjModel, joint: str, camera: int, width: int, height: int,
                 twin_label: str = "ODE", positions: np.ndarray | None = None, order: int = 2,
                 input_gain: float = 1.0) -> None:
        self.model, self.width, self.height, self.twin_label = model, width, height, twin_label
        self.scene_geometry = Scene(model, joint)
        self.position_unit = "rad" if self.scene_geometry.hinge else "m"  # the overlay's units
        self.input_unit = overlay_input_unit(self.position_unit, order, input_gain)
        self.adr = self.scene_geometry.qpos_adr
        self.marker_radius = min(1.3 * self.scene_geometry.tip_radius, 0.06)
        # the offscreen buffer must hold the frame: a visual setting only, never read by the physics
        model.vis.global_.offwidth = max(int(model.vis.global_.offwidth), width)
        model.vis.global_.offheight = max(int(model.vis.global_.offheight), height)
        self.context = open_context(width, height)
        self.data, self.twin = mujoco.MjData(model), mujoco.MjData(model)
        self.scene = mujoco.MjvScene(model, maxgeom=MAX_GEOMS)
        self.camera = mujoco.MjvCamera()
        if camera == DEFAULT_CAMERA:
            framing(model, self.scene_geometry, positions, self.camera)
        else:
            self.camera.type = mujoco.mjtCamera.mjCAMERA_FIXED
            self.camera.fixedcamid = camera
        self.lit = model.nlight > 0  # a model without lights gets a key light (:meth:`_light`)
        self.option, self.perturb = mujoco.MjvOption(), mujoco.MjvPerturb()
        scale = mujoco.mjtFontScale.mjFONTSCALE_150 if width >= 560 else mujoco.mjtFontScale.mjFONTSCALE_100
        self.mjr = mujoco.MjrContext(model, scale)
        mujoco.mjr_setBuffer(mujoco.mjtFramebuffer.mjFB_OFFSCREEN, self.mjr)
        self.rect = mujoco.MjrRect(0, 0, width, height)
        self.pixels = np.empty((height, width, 3), dtype=np.uint8)

    def __enter__(self) -> FrameRenderer:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        if self.context is not None:
            self.mjr.free()
            self.context.free()
            self.context = None

    def _pose(self, data: mujoco.MjData, position: float) -> None:
        data.qpos[:] = self.model.qpos0
        data.qpos[self.adr] = position
        mujoco.mj_kinematics(self.model, data)
        mujoco.mj_comPos(self.model, data)
        mujoco.mj_camlight(self.model, data)

    def _marker(self, position: float, radius: float, rgba: tuple[float, ...], in_front: bool) -> None:
        if self.scene.ngeom >= self.scene.maxgeom or not np.isfinite(position):
            return
        centre = self.scene_geometry.tip_positions(np.array([position]))[0]
        if in_front:  # moved towards the camera, out of the body it marks
            eye = self._eye()
            toward = (eye - centre) / max(float(np.linalg.norm(eye - centre)), 1e-9)
            centre = centre + toward * (self.scene_geometry.tip_radius + radius)
        mujoco.mjv_initGeom(self.scene.geoms[self.scene.ngeom], int(mujoco.mjtGeom.mjGEOM_SPHERE),
                            np.array([radius, 0.0, 0.0]), centre, np.eye(3).ravel(),
                            np.array(rgba, dtype=np.float32))
        self.scene.ngeom += 1

    def render(self, instant: Instant) -> np.ndarray:
        """One frame (height, width, 3) uint8, top row first; the array is reused by the next call."""
        self._pose(self.data, instant.x1)
        mujoco.mjv_updateScene(self.model, self.data, self.option, self.perturb, self.camera,
                               int(mujoco.mjtCatBit.mjCAT_ALL), self.scene)
        if instant.twin_x1 is not None and np.isfinite(instant.twin_x1):
            self._pose(self.twin, instant.twin_x1)
            first = self.scene.ngeom
            mujoco.mjv_addGeoms(self.model, self.twin, self.option, self.perturb,
                                int(mujoco.mjtCatBit.mjCAT_DYNAMIC), self.scene)
            for i in range(first, self.scene.ngeom):
                self.scene.geoms[i].rgba[:] = TWIN_RGBA
        if not self.lit:
            self._light()
        self._marker(instant.yd, self.marker_radius, TARGET_RGBA, in_front=False)
        self._marker(instant.q1, 0.4 * self.marker_radius, READING_RGBA, in_front=True)
        mujoco.mjr_render(self.rect, self.scene, self.mjr)
        self._overlay(instant)
        mujoco.mjr_readPixels(self.pixels, None, self.rect, self.mjr)
        return np.flipud(self.pixels)

    def _eye(self) -> np.ndarray:
        """Where the camera is (a fixed camera's pose, or the free camera's eye)."""
        if self.camera.type == mujoco.mjtCamera.mjCAMERA_FIXED:
            return self.data.cam_xpos[self.camera.fixedcamid]
        return np.mean([self.scene.camera[i].pos for i in range(2)], axis=0)

    def _light(self) -> None:
        """A directional key light from behind the camera, for a model that has none (MuJoCo's dim
        headlight alone leaves it almost black)."""
        if self.scene.nlight >= len(self.scene.lights):
            return
        light = self.scene.lights[self.scene.nlight]
        forward = np.mean([self.scene.camera[i].forward for i in range(2)], axis=0)
        light.dir[:] = forward + np.array([0.0, 0.0, -0.5])  # from the camera, a little from above
        light.pos[:] = self._eye()
        light.type = int(mujoco.mjtLightType.mjLIGHT_DIRECTIONAL)
        light.headlight, light.castshadow = 0, 0
        for name, rgb in KEY_LIGHT.items():
            getattr(light, name)[:] = rgb
        self.scene.nlight += 1

    def _overlay(self, instant: Instant) -> None:
        labels = "t\nq(x1)\nu"
        values = (f"{instant.t:6.2f} s\n{instant.q1:+.3f} {self.position_unit}\n"
                  f"{instant.u:+.2f} {self.input_unit}")
        font, grid = mujoco.mjtFont.mjFONT_NORMAL, mujoco.mjtGridPos
        mujoco.mjr_overlay(font, grid.mjGRID_TOPLEFT, self.rect, labels, values, self.mjr)
        legend = "red: y_d  yellow: q(x1)"
        if instant.twin_x1 is not None:
            legend += f"  blue: {self.twin_label}"
        mujoco.mjr_overlay(font, grid.mjGRID_BOTTOMLEFT, self.rect, legend, None, self.mjr)


def framing(model: mujoco.MjModel, geometry: Scene, positions: np.ndarray | None,
            camera: mujoco.MjvCamera) -> None:
    """Point the free ``camera`` at the moving body over the joint ``positions`` (None: the model's
    reference position), from the side on which the joint moves it in the image plane: along a
    hinge's axis, across a slide's direction, a little from above."""
    data = mujoco.MjData(model)
    jid = next(j for j in range(model.njnt) if int(model.jnt_qposadr[j]) == geometry.qpos_adr)
    span = np.asarray([model.qpos0[geometry.qpos_adr]] if positions is None else positions, dtype=float)
    span = span[np.isfinite(span)] if np.any(np.isfinite(span)) else np.zeros(1)
    drawn = [g for g in range(model.ngeom) if int(model.geom_type[g]) != int(mujoco.mjtGeom.mjGEOM_PLANE)]
    points, reach = [], [float(model.geom_rbound[g]) for g in drawn]
    for q in np.linspace(span.min(), span.max(), 9):
        data.qpos[:] = model.qpos0
        data.qpos[geometry.qpos_adr] = q
        mujoco.mj_kinematics(model, data)
        points += [data.geom_xpos[g].copy() for g in drawn]
    if not points:
        points, reach = [data.xpos[model.jnt_bodyid[jid]].copy()], [0.1]
    points = np.array(points)
    low, high = points.min(axis=0), points.max(axis=0)
    centre = (low + high) / 2
    radius = float(np.linalg.norm(high - low) / 2 + max(reach)) or 0.5
    axis = data.xaxis[jid] / max(float(np.linalg.norm(data.xaxis[jid])), 1e-12)
    if int(model.jnt_type[jid]) == int(mujoco.mjtJoint.mjJNT_SLIDE):
        across = np.cross(axis, [0.0, 0.0, 1.0])
        axis = across / np.linalg.norm(across) if np.linalg.norm(across) > 1e-6 else np.array([0.0, 1.0,
                                                                                                0.0])
    forward = axis if axis[1] >= 0 else -axis  # look along +y where it is a choice, as the shipped cameras
    forward = forward + np.array([0.0, 0.0, -0.15])
    forward /= np.linalg.norm(forward)
    camera.type = mujoco.mjtCamera.mjCAMERA_FREE
    camera.lookat[:] = centre
    camera.distance = FRAMED * radius / np.tan(np.radians(float(model.vis.global_.fovy)) / 2)
    camera.azimuth = float(np.degrees(np.arctan2(forward[1], forward[0])))
    camera.elevation = float(np.degrees(np.arcsin(np.clip(forward[2], -1.0, 1.0))))
