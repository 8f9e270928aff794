"""A fixed 3-D camera for a recording, from the MuJoCo model and the run's range of motion.

The viewer's own camera re-fits the scene's bounds as the bodies move (the view jumps every frame,
the bob leaves the picture). A recording instead sends one eye (position, look target, up) in its
layout:

* **direction**: MuJoCo's free camera, from the model's ``<visual><global azimuth elevation>``
  (``vis.global_``), turned onto the plane of motion when it is far from it: a hinge is seen
  along its axis (within 20 degrees), a slide from across its axis;
* **what is framed**: the circle the arm's geoms sweep about the hinge, whatever the run did; or
  the interval a slide travelled (the recorded positions and the reference's), swept by the
  moving geoms, with a margin of 10 % of its length on each side, not the whole rail;
* **distance**: the nearest at which that fits the viewer's field of view, plus 10 %;
* a run with no finite position falls back to MuJoCo's default free camera: ``stat.center``
  seen from ``1.5 stat.extent``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .scene import Scene

FIELD_OF_VIEW_Y = np.radians(55.0)  # the rerun viewer's vertical field of view
VIEW_WIDTH_PER_HEIGHT = 1.6  # width / height of the 3-D view in the default layout (at 1600 x 1000)
MAX_TILT = np.radians(20.0)  # how far the model's view direction may be off the plane of motion
FRAME_MARGIN = 1.1  # the framed shape fills 1 / FRAME_MARGIN of the view
TRAVEL_MARGIN = 0.1  # a slide's travelled interval is widened by this fraction of its length per side
UP = np.array([0.0, 0.0, 1.0])  # MuJoCo is Z-up


@dataclass(frozen=True)
class Camera:
    """An eye for rerun's ``EyeControls3D``: where it is, what it looks at, its up direction (the
    world's, so that orbiting the view keeps the floor level)."""

    position: tuple[float, float, float]
    look_target: tuple[float, float, float]
    eye_up: tuple[float, float, float] = (0.0, 0.0, 1.0)


def model_direction(scene: Scene) -> np.ndarray:
    """The unit direction MuJoCo's free camera looks along (``vis.global_`` azimuth, elevation),
    turned onto the plane of motion of the recorded joint if it is more than ``MAX_TILT`` off."""
    azimuth = np.radians(float(scene.model.vis.global_.azimuth))
    elevation = np.radians(float(scene.model.vis.global_.elevation))
    forward = np.array([np.cos(elevation) * np.cos(azimuth), np.cos(elevation) * np.sin(azimuth),
                        np.sin(elevation)])
    along_axis = float(forward @ scene.axis)
    if scene.hinge:  # the plane of motion is normal to the axis: look along it
        if abs(along_axis) >= np.cos(MAX_TILT):
            return forward
        return scene.axis * (1.0 if along_axis >= 0 else -1.0)
    if abs(along_axis) <= np.sin(MAX_TILT):  # a slide: look across its axis
        return forward
    across = forward - along_axis * scene.axis
    if np.linalg.norm(across) < 1e-9:
        across = np.cross(scene.axis, UP) if abs(scene.axis @ UP) < 0.99 else np.array([0.0, 1.0, 0.0])
    return across / np.linalg.norm(across)


def motion_points(scene: Scene, low: float, high: float) -> np.ndarray:
    """Points whose bounding box the camera frames: the moving geoms' bounding spheres swept over
    the arm's full circle, or over the slide positions ``[low, high]`` widened by the margin."""
    centres, radii = scene.moving_centres, scene.moving_radii
    offsets = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], dtype=float)
    corners = (centres[:, None, :] + radii[:, None, None] * offsets[None]).reshape(-1, 3)
    if scene.hinge:  # the circle in the plane of motion through the anchor
        reach = float(np.max(np.linalg.norm(centres - scene.anchor, axis=1) + radii))
        first = np.cross(scene.axis, UP if abs(scene.axis @ UP) < 0.99 else np.array([1.0, 0.0, 0.0]))
        first /= np.linalg.norm(first)
        second = np.cross(scene.axis, first)
        angles = np.linspace(0.0, 2 * np.pi, 73)
        return scene.anchor + reach * (np.cos(angles)[:, None] * first + np.sin(angles)[:, None] * second)
    margin = TRAVEL_MARGIN * (high - low)
    shifts = np.array([low - margin, high + margin]) - scene.q0
    return (corners[None, :, :] + shifts[:, None, None] * scene.axis).reshape(-1, 3)


def frame(points: np.ndarray, forward: np.ndarray) -> Camera:
    """The eye looking along ``forward`` at the centre of ``points``' bounding box, from the
    nearest distance at which every point is inside the field of view (times ``FRAME_MARGIN``)."""
    right = np.cross(forward, UP)
    if np.linalg.norm(right) < 1e-9:  # looking straight up or down
        right = np.array([1.0, 0.0, 0.0])
    right /= np.linalg.norm(right)
    up = np.cross(right, forward)
    target = 0.5 * (points.min(axis=0) + points.max(axis=0))
    relative = points - target
    half_width = np.max(np.abs(relative @ right))
    half_height = np.max(np.abs(relative @ up))
    nearest_depth = np.max(-(relative @ forward))  # how far points stand out towards the eye
    tangent = np.tan(FIELD_OF_VIEW_Y / 2)
    fit = max(half_height / tangent, half_width / (tangent * VIEW_WIDTH_PER_HEIGHT))
    distance = FRAME_MARGIN * fit + nearest_depth
    position = target - distance * forward
    return Camera(tuple(map(float, position)), tuple(map(float, target)))


def fixed_camera(scene: Scene, low: float, high: float) -> Camera:
    """The recording's camera for a run whose joint positions (and reference) span ``[low, high]``
    (see the module docstring); MuJoCo's default free camera if they are not finite."""
    forward = model_direction(scene)
    if not (np.isfinite(low) and np.isfinite(high)):
        stat = scene.model.stat
        centre = np.asarray(stat.center, dtype=float)
        position = centre - 1.5 * float(stat.extent) * forward
        return Camera(tuple(map(float, position)), tuple(map(float, centre)))
    return frame(motion_points(scene, low, high), forward)
