"""The 3-D scene of a recording: a MuJoCo model's drawable geoms, and the poses of its bodies as
the one joint moves (replayed from the recorded joint position, all rows at once).

Entity layout (``{L}`` a twin run's label, e.g. ``ode``)::

    world                          view coordinates (MuJoCo is Z-up), static
    world/fixed/{geom}             geoms of MuJoCo's world body, static
    world/bodies/{body}            Transform3D per row: the body pose from the replayed joint position
    world/bodies/{body}/{geom}     the geom's shape and its pose in the body, static
    world/{L}_ghost/{body}[/{geom}]  the same for a ghost run: a twin as an outline (a wireframe 15 %
                                   larger than the body, so it shows around the body where the two
                                   coincide), another run as a tinted translucent body
    world/target                   Transform3D per row: where the tip geom would be at y_d
"""

from __future__ import annotations

import re
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    import mujoco

# MuJoCo geom types (mjtGeom) and joint types (mjtJoint) that matter here.
_PLANE, _SPHERE, _CAPSULE, _ELLIPSOID, _CYLINDER, _BOX, _MESH = 0, 2, 3, 4, 5, 6, 7
_SLIDE, _HINGE = 2, 3


def entity_name(name: str, fallback: str) -> str:
    """A MuJoCo name made safe as one entity-path part."""
    cleaned = re.sub(r"[^A-Za-z0-9_\-]", "_", name)
    return cleaned or fallback


RGBA = tuple[int, int, int, int]
OUTLINE_SCALE = 1.15  # a twin's outline is this much larger than the body it may coincide with


@dataclass(frozen=True)
class Geom:
    """One drawable MuJoCo geom: its entity name, the rerun shape, its pose in its body."""

    name: str
    body: int
    shape: Callable[[RGBA, bool], Any]  # (colour, outline) -> rerun archetype
    rgba: RGBA
    pos: np.ndarray
    quat_xyzw: np.ndarray


def _geom_shape(model: mujoco.MjModel, g: int) -> Callable[[RGBA, bool], Any] | None:
    """A factory ``(colour, outline) -> rerun archetype`` drawing geom ``g`` centred at its frame
    (solid, or with ``outline`` a wireframe ``OUTLINE_SCALE`` times larger), or None."""
    import rerun as rr

    kind, size = int(model.geom_type[g]), model.geom_size[g].astype(float)

    def fill(outline: bool) -> rr.components.FillMode:
        mode = rr.components.FillMode
        return mode.TransparentFillMajorWireframe if outline else mode.Solid

    def grown(outline: bool) -> float:
        return OUTLINE_SCALE if outline else 1.0

    if kind == _SPHERE:
        return lambda c, o: rr.Ellipsoids3D(half_sizes=[[size[0] * grown(o)] * 3], colors=[c],
                                            fill_mode=fill(o))
    if kind == _ELLIPSOID:
        return lambda c, o: rr.Ellipsoids3D(half_sizes=[size * grown(o)], colors=[c], fill_mode=fill(o))
    if kind == _CAPSULE:  # MuJoCo: centred, half-length size[1]; rerun: from z=0 to z=length
        return lambda c, o: rr.Capsules3D(lengths=[2 * size[1]], radii=[size[0] * grown(o)],
                                          translations=[[0, 0, -size[1]]], colors=[c], fill_mode=fill(o))
    if kind == _CYLINDER:
        return lambda c, o: rr.Cylinders3D(lengths=[2 * size[1] * grown(o)], radii=[size[0] * grown(o)],
                                           colors=[c], fill_mode=fill(o))
    if kind == _BOX:
        return lambda c, o: rr.Boxes3D(half_sizes=[size * grown(o)], colors=[c], fill_mode=fill(o))
    if kind == _PLANE and size[0] > 0 and size[1] > 0:  # a finite plane; infinite ones are left out
        return lambda c, o: rr.Boxes3D(half_sizes=[[size[0], size[1], 1e-3]], colors=[c], fill_mode=fill(o))
    if kind == _MESH and model.geom_dataid[g] >= 0:  # no wireframe for meshes: translucent instead
        mesh = int(model.geom_dataid[g])
        v0, nv = int(model.mesh_vertadr[mesh]), int(model.mesh_vertnum[mesh])
        f0, nf = int(model.mesh_faceadr[mesh]), int(model.mesh_facenum[mesh])
        vertices = model.mesh_vert[v0 : v0 + nv].copy()
        faces = model.mesh_face[f0 : f0 + nf].copy()
        return lambda c, o: rr.Mesh3D(vertex_positions=vertices * grown(o), triangle_indices=faces,
                                      albedo_factor=(*c[:3], min(c[3], 110)) if o else c)
    return None


def _geom_rgba(model: mujoco.MjModel, g: int) -> tuple[int, int, int, int]:
    rgba = model.mat_rgba[model.geom_matid[g]] if model.geom_matid[g] >= 0 else model.geom_rgba[g]
    r, gr, b, a = (int(round(255 * float(np.clip(v, 0.0, 1.0)))) for v in rgba)
    return r, gr, b, a


def _drawable_geoms(model: mujoco.MjModel) -> list[Geom]:
    """The geoms MuJoCo's viewer shows by default (groups 0-2, not fully transparent)."""
    import mujoco

    geoms = []
    for g in range(model.ngeom):
        shape = _geom_shape(model, g)
        rgba = _geom_rgba(model, g)
        if shape is None or model.geom_group[g] > 2 or rgba[3] == 0:
            continue
        name = entity_name(mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_GEOM, g) or "", f"geom{g}")
        geoms.append(
            Geom(
                name,
                int(model.geom_bodyid[g]),
                shape,
                rgba,
                model.geom_pos[g].copy(),
                model.geom_quat[g][[1, 2, 3, 0]].copy(),
            )
        )
    return geoms


class Scene:
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
            b: entity_name(mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_BODY, b) or "", f"body{b}")
            for b in self.bodies
        }
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

    def _tip(self, moving: list[int]) -> tuple[int, float]:
        """Of the geoms that move with the joint (at the reference pose), the one farthest from
        the joint's anchor (the bob, the cart), and its size."""
        if not moving:
            raise ValueError("no geom moves with the recorded joint: nothing to draw the target for")
        far = max(moving, key=lambda g: (np.linalg.norm(self.data.geom_xpos[g] - self.anchor), g))
        return far, float(self.model.geom_rbound[far])

    def _descends(self, body: int, ancestor: int) -> bool:
        while body > 0:
            if body == ancestor:
                return True
            body = int(self.model.body_parentid[body])
        return body == ancestor

    def replay(self, position: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Body positions (rows, bodies, 3) and quaternions xyzw (rows, bodies, 4) with the joint
        at each of ``position``; NaN where it is not finite.

        One joint moves, so every pose is the reference pose (``qpos0``, from ``mj_kinematics``)
        carried by one rigid motion: a rotation by ``q - q0`` about the hinge's world axis through
        its anchor, or a translation by ``q - q0`` along the slide's axis. Bodies that do not
        descend from the joint's body stay put. Evaluated for all rows at once, from terms
        prepared once (:meth:`_turn_terms`): per row only a cosine and a sine are new.
        """
        q = np.asarray(position, dtype=float) - self.q0
        ids, moving = self.bodies, self.moving
        rows = len(q)
        xpos = np.broadcast_to(self.xpos0[ids], (rows, len(ids), 3)).copy()
        xquat = np.broadcast_to(self.xquat0[ids][:, [1, 2, 3, 0]], (rows, len(ids), 4)).copy()
        if self.hinge:
            xpos[:, moving] = self._turned(self.body_turn, q[:, None, None])
            half = 0.5 * q[:, None, None]
            fixed, turning = self.quat_turn
            xquat[:, moving] = np.cos(half) * fixed + np.sin(half) * turning
        else:
            xpos[:, moving] += q[:, None, None] * self.axis
        bad = ~np.isfinite(q)
        xpos[bad], xquat[bad] = np.nan, np.nan
        return xpos, xquat

    def tip_positions(self, position: np.ndarray) -> np.ndarray:
        """The tip geom's position (rows, 3) with the joint at each of ``position`` (the rigid
        motion of :meth:`replay` applied to the tip); NaN where it is not finite."""
        q = np.asarray(position, dtype=float)[:, None] - self.q0
        if not self.hinge:
            return self.tip0 + q * self.axis
        return self._turned(self.tip_turn, q)

    def _turn_terms(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Rodrigues' formula for ``points`` (..., 3) turned by an angle about the hinge's axis
        through its anchor, ``still + across cos + normal sin``: its three constant terms."""
        arm, axis = points - self.anchor, self.axis
        along = (arm @ axis)[..., None] * axis
        return self.anchor + along, arm - along, np.cross(axis, arm)

    @staticmethod
    def _turned(terms: tuple[np.ndarray, np.ndarray, np.ndarray], angle: np.ndarray) -> np.ndarray:
        still, across, normal = terms
        return still + across * np.cos(angle) + normal * np.sin(angle)

    def _reference_pose(self, jid: int) -> None:
        """Poses at ``qpos0``, the joint's world axis and anchor, and the tip (:meth:`_tip`), for
        :meth:`replay` and :meth:`tip_positions`."""
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
        joint_body = int(model.jnt_bodyid[jid])
        self.moving = np.array([self._descends(b, joint_body) for b in self.bodies], dtype=bool)
        drawn = [g for g in range(model.ngeom) if self._descends(int(model.geom_bodyid[g]), joint_body)]
        self.tip_geom, self.tip_radius = self._tip(drawn)
        self.tip0 = data.geom_xpos[self.tip_geom].copy()
        self.moving_centres = data.geom_xpos[drawn].copy()  # at qpos0, for framing the motion
        self.moving_radii = model.geom_rbound[drawn].astype(float)
        self.body_turn = self._turn_terms(self.xpos0[self.bodies][self.moving])
        self.tip_turn = self._turn_terms(self.tip0)
        # a turn by angle a is the quaternion cos(a/2) + sin(a/2) (0, axis): linear in both
        reference = self.xquat0[self.bodies][self.moving]
        about_axis = _quat_multiply(np.concatenate([[0.0], self.axis])[None], reference)
        self.quat_turn = (reference[:, [1, 2, 3, 0]], about_axis[:, [1, 2, 3, 0]])


def _quat_multiply(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product of wxyz quaternions (broadcasting)."""
    aw, ax, ay, az = np.moveaxis(a, -1, 0)
    bw, bx, by, bz = np.moveaxis(b, -1, 0)
    return np.stack([aw * bw - ax * bx - ay * by - az * bz,
                     aw * bx + ax * bw + ay * bz - az * by,
                     aw * by - ax * bz + ay * bw + az * bx,
                     aw * bz + ax * by - ay * bx + az * bw], axis=-1)
