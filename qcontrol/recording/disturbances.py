"""The scenario's disturbances in a recording: an arrow on the body while each one acts, a marker
on the time axis where it starts, the load beside u, and a line of text per event.

Entity layout (``{body}`` the body of the moving tip geom, ``{i}`` the disturbance's index)::

    world/bodies/{body}/disturbance_{i}   Arrows3D in the body's frame while it acts (empty after),
                                          pushing on the tip along the joint's positive direction
                                          for a positive force; its label says kind and size
    signals/input/disturbance             the load in u's units, d = F / I (step series)
    signals/error/disturbance             a marker at z1 = 0 at each start (SeriesPoints)
    events/disturbances                   TextLog at each start and end

Everything is known before the run (the schedule is data), so it is logged once, with explicit
``sim_time`` columns, when the recording starts.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

from ..disturbance import Disturbance
from .scene import Scene
from .series import PURPLE, TIMELINE
from .streamer import time_column, time_nanoseconds

if TYPE_CHECKING:
    from ..assembly import Assembly
    from .recording import Recording

ARROW_SHARE = 0.8  # the strongest disturbance's arrow: this share of the joint-to-tip distance


def arrow_in_body(drawn: Scene, force: float, largest: float) -> tuple[str, np.ndarray, np.ndarray]:
    """The body entity's name, and the arrow (origin, vector) in that body's frame: its head touches
    the tip geom and it points along the joint's positive direction there (the tangent of the
    hinge's circle, or the slide's axis) for a positive force; its length is proportional to
    |force|."""
    model = drawn.model
    body = int(model.geom_bodyid[drawn.tip_geom])
    tip = drawn.tip0
    if drawn.hinge:
        direction = np.cross(drawn.axis, tip - drawn.anchor)
    else:
        direction = np.asarray(drawn.axis, dtype=float)
    direction = direction / np.linalg.norm(direction)
    reach = max(float(np.linalg.norm(tip - drawn.anchor)), 4.0 * drawn.tip_radius)
    vector_world = math.copysign(ARROW_SHARE * reach * abs(force) / largest, force) * direction
    rotation = _matrix(drawn.xquat0[body])  # body frame -> world at the reference pose
    touch = tip - math.copysign(drawn.tip_radius, force) * direction  # on the tip geom's surface
    end = rotation.T @ (touch - drawn.xpos0[body])
    vector = rotation.T @ vector_world
    return drawn.body_names[body], end - vector, vector


def _matrix(quat_wxyz: np.ndarray) -> np.ndarray:
    w, x, y, z = quat_wxyz
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                     [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                     [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


def log_disturbances(recording: Recording, run: Assembly) -> None:
    """Log the disturbances of the run's scenario (nothing without any, or when the recording is
    closed)."""
    sc = run.scenario
    stream = recording.stream
    if stream is None or not sc.disturbances:
        return
    import rerun as rr

    grid = run.spec.grid
    drawn = run.scene
    unit = "" if drawn is None else "N m" if drawn.hinge else "N"  # else generalized force units
    if drawn is not None:
        _arrows(stream, recording.scene_of(drawn.model, drawn.joint), sc.disturbances, unit, grid.duration)
    changes = run.loads  # d = F / I where the load changes
    times = [k * grid.dt for k, _ in changes] + [grid.duration]
    values = [d for _, d in changes] + [changes[-1][1]]
    stream.log("signals/input/disturbance", rr.SeriesLines(names="disturbance d = F / I", colors=[PURPLE],
                                                          interpolation_mode="StepAfter"), static=True)
    stream.send_columns("signals/input/disturbance", indexes=[time_column(times)],
                        columns=rr.Scalars.columns(scalars=values))
    starts = [d.start for d in sc.disturbances if d.start <= grid.duration]
    stream.log("signals/error/disturbance", rr.SeriesPoints(names="disturbance starts", colors=[PURPLE],
                                                           markers="Down", marker_sizes=[6.0]), static=True)
    if starts:
        stream.send_columns("signals/error/disturbance", indexes=[time_column(starts)],
                            columns=rr.Scalars.columns(scalars=[0.0] * len(starts)))
    _events(stream, sc.disturbances, unit, grid.duration)
    recording.flush()


def _arrows(stream, drawn: Scene, items: tuple[Disturbance, ...], unit: str, duration: float) -> None:
    import rerun as rr

    largest = max(abs(d.force) for d in items) or 1.0
    for i, item in enumerate(items):
        if item.start > duration or item.force == 0.0:
            continue
        body, origin, vector = arrow_in_body(drawn, item.force, largest)
        path = f"world/bodies/{body}/disturbance_{i}"
        stops = [item.start] + ([] if item.lasting or item.end > duration else [item.end])
        columns = rr.Arrows3D.columns(origins=[origin], vectors=[vector],
                                      labels=[item.describe(unit)], colors=[PURPLE],
                                      radii=[0.01 * float(np.linalg.norm(vector)) + 0.004])
        lengths = [1] + [0] * (len(stops) - 1)  # shown from the start, an empty batch at the end
        stream.send_columns(path, indexes=[time_column(stops)], columns=columns.partition(lengths))


def _events(stream, items: tuple[Disturbance, ...], unit: str, duration: float) -> None:
    import rerun as rr

    for item in items:
        if item.start > duration:
            continue
        stream.set_time(TIMELINE, duration=np.timedelta64(int(time_nanoseconds(item.start)), "ns"))
        stream.log("events/disturbances", rr.TextLog(f"{item.describe(unit)}: starts", level="WARN"))
        if not item.lasting and item.end <= duration:
            stream.set_time(TIMELINE, duration=np.timedelta64(int(time_nanoseconds(item.end)), "ns"))
            stream.log("events/disturbances", rr.TextLog(f"{item.kind} ends", level="INFO"))
    stream.reset_time()
