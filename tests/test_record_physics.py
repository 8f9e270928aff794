"""Recordings of realistic runs: the applied input beside the command, and the disturbances (an
arrow on the body while one acts, a marker on the time axis, the load beside u)."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import SCENARIOS
from test_record import read_entities, temporal

from qcontrol.assembly import scene
from qcontrol.cli import main
from qcontrol.recording.scene import Scene
from qcontrol.scenario import load_scenario

ARM = SCENARIOS / "example2-arm.toml"

LIMIT = 15.0  # N m: low enough that the arm's controller meets it


@pytest.fixture(scope="module")
def arm_recording(tmp_path_factory) -> dict:
    path = tmp_path_factory.mktemp("arm") / "arm.rrd"
    overrides = ["--set", f"plant.mujoco.torque_limit={LIMIT}", "--duration", "6.5"]
    assert main(["run", str(ARM), *overrides, "-q", "--rrd", str(path)]) == 0
    return read_entities(path)


def test_the_applied_torque_is_the_command_clipped(arm_recording) -> None:
    t_u, u = temporal(arm_recording["signals/input/u"], "Scalars:scalars")
    t_a, applied = temporal(arm_recording["signals/input/u_applied"], "Scalars:scalars")
    np.testing.assert_array_equal(t_u, t_a)
    assert np.abs(u).max() > LIMIT  # the limit was met, so the two series differ somewhere
    np.testing.assert_allclose(applied[:, 0], np.clip(u[:, 0], -LIMIT, LIMIT), rtol=1e-12)  # I = 1


def test_an_arrow_pushes_on_the_bob_while_the_impulse_acts(arm_recording) -> None:
    rows = []  # (time, arrows) of every row logged there
    for batch in arm_recording["world/bodies/arm/disturbance_0"]:
        if "sim_time" in batch.column_names:
            rows += zip(batch.column("sim_time").cast("int64").to_pylist(),
                        batch.column("Arrows3D:vectors").to_pylist(),
                        batch.column("Arrows3D:origins").to_pylist(), strict=True)
    rows.sort(key=lambda row: row[0])
    # one arrow from the start, an empty batch at the end 50 ms later
    assert [(t, len(v)) for t, v, _ in rows] == [(6_000_000_000, 1), (6_050_000_000, 0)]
    vector, origin = np.array(rows[0][1][0]), np.array(rows[0][2][0])
    sc = load_scenario(ARM)
    drawn = scene(sc)
    replay = Scene(drawn.model, drawn.joint)
    tip = replay.tip_positions(np.array([0.0, 1e-6]))
    moving = (tip[1] - tip[0]) / np.linalg.norm(tip[1] - tip[0])  # where the bob goes as x1 grows
    np.testing.assert_allclose(vector / np.linalg.norm(vector), moving, atol=1e-6)  # a positive force
    head = origin + vector  # the arm's frame is the world's at x1 = 0
    assert np.linalg.norm(head - tip[0]) == pytest.approx(replay.tip_radius, rel=1e-6)  # float32


def test_the_time_axis_marks_the_disturbance(arm_recording) -> None:
    times, marks = temporal(arm_recording["signals/error/disturbance"], "Scalars:scalars")
    assert times.tolist() == [6_000_000_000] and marks[:, 0].tolist() == [0.0]
    times, load = temporal(arm_recording["signals/input/disturbance"], "Scalars:scalars")
    assert times.tolist() == [0, 6_000_000_000, 6_050_000_000, 6_500_000_000]
    np.testing.assert_allclose(load[:, 0], [0.0, 20.0, 0.0, 0.0], rtol=1e-12)  # F / I, I = 1 kg m^2
    texts = [str(v) for b in arm_recording["events/disturbances"] if "TextLog:text" in b.column_names
             for v in b.column("TextLog:text").to_pylist()]
    assert any("impulse 20 N m" in t for t in texts) and any("ends" in t for t in texts)
