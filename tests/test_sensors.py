"""Sensors as the literature models them: a quantizer per channel (uniform with a step per channel
and a range, hysteresis, logarithmic), Lemma 2 with one bound per channel, the input's quantizer,
and time in the plant's terms (the forced Duffing oscillator).

Each quantizer is checked against its definition computed independently (hand-computed levels, or
the levels enumerated), Lemma 2's bounds against the recursion written out and against the worst
case over the quantization cell's corners, and the runs against the theory's promises."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

import qcontrol
from qcontrol.assembly import build_quantizer, run_scenario, run_spec, run_variants
from qcontrol.controller.backstepping import Backstepping, lemma2_bounds, lemma2_L
from qcontrol.engine.loop import ClosedLoop
from qcontrol.metrics import LEMMA2_TOLERANCE, backend_deviation, run_summary
from qcontrol.quantizers import ChannelQuantizer, HysteresisQuantizer, LogarithmicQuantizer
from qcontrol.recording.series import run_series

SHORT = {"simulation.duration": 3.0}


def scenario(name: str = "example2", **quantizer: object) -> qcontrol.Scenario:
    """A shipped scenario with ``[quantizer]`` keys in place of controller.delta."""
    keys = {f"quantizer.{k.replace('__', '.')}": v for k, v in quantizer.items()}
    return qcontrol.load_scenario(name, SHORT | keys, unset=["controller.delta"])


def summary(sc: qcontrol.Scenario, backend: str = "ode") -> dict:
    return run_summary(run_scenario(sc, backend=backend, record="metrics"), sc.name, backend).to_json()


# ---- the quantizers against their definitions --------------------------------------------------


def test_uniform_per_channel_levels_by_hand() -> None:
    q = ChannelQuantizer([0.1, 0.5], 2)
    x = np.array([[0.04, 0.26], [0.05, -0.25], [-0.151, 1.3], [-0.049, -0.2501]])
    # l delta for (2l - 1) delta / 2 <= x < (2l + 1) delta / 2, per channel
    expected = np.array([[0.0, 0.5], [0.1, 0.0], [-0.2, 1.5], [0.0, -0.5]])
    np.testing.assert_allclose(q(x), expected, rtol=0, atol=1e-15)
    assert q.worst_case_error == q.max_error == (0.05, 0.25)


def test_uniform_range_saturates_at_the_levels_of_plus_minus_R() -> None:
    q = ChannelQuantizer([0.1, 1.0], 2, [0.3, 2.0])
    x = np.array([[5.0, -7.0], [0.29, 1.4], [-0.36, 2.6], [np.nan, 0.0]])
    out = q(x)
    np.testing.assert_allclose(out[:3], [[0.3, -2.0], [0.3, 1.0], [-0.3, 2.0]], rtol=0, atol=1e-15)
    np.testing.assert_array_equal(q.saturated(x)[:3], [1.0, 0.0, 1.0])
    assert math.isnan(q.saturated(x)[3])
    # within the range the error is the step's half, beyond it grows with x
    assert np.all(np.abs(out[1] - x[1]) <= np.array(q.max_error))
    assert abs(out[0, 0] - x[0, 0]) > 4.0


def test_hysteresis_keeps_its_level_until_a_whole_step_away() -> None:
    q = HysteresisQuantizer(1.0, 1)
    signal = [0.4, 0.9, 1.2, 1.45, 0.6, 0.01, -0.2, -0.51, 2.0, 1.01, 0.99]
    by_hand = [0.0, 0.0, 1.0, 1.0, 1.0, 1.0, 0.0, 0.0, 2.0, 2.0, 1.0]
    got = [float(q(np.array([[x]]))[0, 0]) for x in signal]
    assert got == by_hand
    assert all(abs(g - x) <= q.worst_case_error[0] for g, x in zip(got, signal, strict=True))
    q.reset()  # a new run starts from the uniform reading
    assert float(q(np.array([[1.45]]))[0, 0]) == 1.0


def test_hysteresis_copies_of_a_batch_keep_their_own_levels() -> None:
    rng = np.random.default_rng(5)
    walks = np.cumsum(rng.normal(0, 0.3, size=(200, 3, 2)), axis=0)
    batch = HysteresisQuantizer([0.5, 0.2], 2)
    alone = [HysteresisQuantizer([0.5, 0.2], 2) for _ in range(3)]
    for row in walks:
        together = batch(row)
        for b in range(3):
            np.testing.assert_array_equal(together[b], alone[b](row[b : b + 1])[0])


def _log_by_enumeration(x: float, rho: float, u_min: float) -> float:
    """The logarithmic quantizer's definition with its levels listed one by one."""
    xi = (1 - rho) / (1 + rho)
    if abs(x) <= u_min / (1 + xi):
        return 0.0
    for j in range(400):
        level = u_min * rho ** (-j)
        if level / (1 + xi) < abs(x) <= level / (1 - xi):
            return math.copysign(level, x)
    raise AssertionError("beyond the listed levels")


def test_logarithmic_levels_against_their_enumeration() -> None:
    rho, u_min = 0.8, 0.01
    q = LogarithmicQuantizer(rho, u_min, 1)
    rng = np.random.default_rng(7)
    x = np.sign(rng.normal(size=3000)) * 10 ** rng.uniform(-4, 3, size=3000)
    x = np.concatenate([x, [0.0, u_min, u_min / (1 + q.sector), -u_min * 1.25]])
    got = q(x[:, None])[:, 0]
    expected = np.array([_log_by_enumeration(v, rho, u_min) for v in x])
    np.testing.assert_allclose(got, expected, rtol=1e-12, atol=0)
    outside = np.abs(x) > u_min / (1 + q.sector)
    assert np.all(np.abs(got - x)[outside] <= q.sector * np.abs(x[outside]) * (1 + 1e-12))
    assert q.sector == pytest.approx((1 - rho) / (1 + rho)) and q.worst_case_error == (math.inf,)
    assert q.lemma2_applies is False


# ---- Lemma 2 with one bound per channel --------------------------------------------------------


def test_lemma2_per_channel_is_the_recursion_written_out() -> None:
    c1, c2, c3 = 4.0, 3.0, 2.0
    m1, m2, m3 = 0.001, 0.02, 0.3
    L_z, _ = lemma2_bounds([c1, c2], [m1, m2])
    assert L_z.tolist() == pytest.approx([m1, m2 + c1 * m1], rel=1e-15)  # n = 2: L = m_2 + c_1 m_1
    L_z3, _ = lemma2_bounds([c1, c2, c3], [m1, m2, m3])
    L_alpha2 = c2 * (m2 + c1 * m1) + c1 * m2  # |a[1][1]| = c_1
    assert L_z3.tolist() == pytest.approx([m1, m2 + c1 * m1, m3 + L_alpha2], rel=1e-15)
    # one bound on every channel is the paper's Lemma 2, bit for bit
    assert lemma2_bounds([c1, c2, c3], 0.005)[0][-1] == lemma2_L([c1, c2, c3], 0.01)
    assert lemma2_bounds([c1, c2], 0.005)[0][-1] == (1 + c1) * 0.005
    # the API takes the uniform quantizer's steps, one number or one per channel
    assert qcontrol.lemma2_bounds([c1, c2], [2 * m1, 2 * m2]).tolist() == pytest.approx([m1, m2 + c1 * m1])


def test_lemma2_per_channel_bounds_the_worst_corner_of_the_cell() -> None:
    """|z_i - zbar_i| is linear in the quantization errors: its largest value over the box
    |e_k| <= m_k is at a corner, and every corner stays within L_zi."""
    c, m = [4.0, 3.0, 2.0], np.array([0.001, 0.02, 0.3])
    coordinates = Backstepping(c, tuple(m))
    rng = np.random.default_rng(11)
    x, yd = rng.normal(size=3), rng.normal(size=4)
    worst = np.zeros(3)
    for signs in itertools.product((-1.0, 1.0), repeat=3):
        q = x + np.array(signs) * m
        e_z = np.abs(coordinates.errors(x, yd) - coordinates.quantized_errors(q, yd)[0])
        worst = np.maximum(worst, e_z)
    assert np.all(worst <= coordinates.L_z * (1 + 1e-12))
    assert worst[-1] > 0.5 * coordinates.L_z[-1]  # the bound is of the right size, not loose


@pytest.mark.parametrize(("name", "keys"), [
    ("example2", {"delta": [0.0015, 0.05]}),
    ("example2", {"kind": "hysteresis", "delta": [0.002, 0.02]}),
    ("chain3", {"delta": [0.002, 0.01, 0.05]}),
])
def test_online_lemma2_check_holds_with_per_channel_steps(name: str, keys: dict) -> None:
    sc = scenario(name, **keys)
    s = summary(sc)
    coordinates = Backstepping(sc.controller.c, build_quantizer(sc).max_error)
    assert s["L"] == coordinates.L and s["L_z"] == coordinates.L_z.tolist()
    assert s["lemma2_applies"] is True and not s["diverged"]
    assert 0.5 < s["lemma2_max_ratio"] <= 1 + LEMMA2_TOLERANCE


def test_online_lemma2_check_holds_on_mujoco_with_per_channel_steps() -> None:
    s = summary(scenario(delta=[0.0015, 0.05]), "mujoco")
    assert s["lemma2_applies"] is True and s["L"] == 0.05 / 2 + 4.0 * 0.0015 / 2
    assert 0.5 < s["lemma2_max_ratio"] <= 1 + LEMMA2_TOLERANCE


def test_a_logarithmic_quantizer_reports_its_sector_instead_of_lemma2() -> None:
    s = summary(scenario(kind="logarithmic", rho=0.9, u_min=0.001))
    assert s["lemma2_applies"] is False
    assert s["quantizer_sector"] == pytest.approx(0.1 / 1.9)
    assert "reading_saturated_fraction" not in s and "max_abs_input_quantization_error" not in s


def test_the_uniform_table_with_one_step_is_controller_delta_bit_for_bit() -> None:
    old = run_scenario(qcontrol.load_scenario("example2", SHORT), backend="ode")
    new = run_scenario(scenario(delta=0.01), backend="ode")
    for name in ("x", "x_q", "u", "adaptive"):
        np.testing.assert_array_equal(getattr(old, name), getattr(new, name))


# ---- range, input quantization, batches -----------------------------------------------------------


def test_a_finite_range_reports_the_share_of_saturated_readings() -> None:
    sc = scenario(delta=[0.0015, 0.05], range=[0.6, 20.0])
    traj = run_scenario(sc, backend="ode")
    s = run_summary(traj, sc.name, "ode").to_json()
    beyond = np.abs(0.0015 * np.floor(traj.x_meas[:, 0] / 0.0015 + 0.5)) > 0.6
    assert s["reading_saturated_fraction"] == pytest.approx(beyond.mean(), abs=1e-12)
    assert 0 < s["reading_saturated_fraction"] < 1
    assert np.max(np.abs(traj.x_q[:, 0])) <= 0.6 + 1e-12
    assert any("saturated" in w and "Lemma 2" in w for w in s["warnings"])
    assert s["lemma2_applies"] is False and s["lemma2_max_ratio"] > 1  # beyond the range it fails, as it must


def test_input_quantization_is_applied_and_reported() -> None:
    sc = qcontrol.load_scenario("example2", SHORT | {"quantizer.delta": 0.01, "quantizer.input.delta": 0.5},
                                unset=["controller.delta"])
    traj = run_scenario(sc, backend="ode")
    s = run_summary(traj, sc.name, "ode").to_json()
    q_u = 0.5 * np.floor(traj.u / 0.5 + 0.5)
    np.testing.assert_array_equal(traj.u_applied, q_u)
    assert s["max_abs_input_quantization_error"] == pytest.approx(np.max(np.abs(q_u - traj.u)))
    assert 0 < s["max_abs_input_quantization_error"] <= 0.25
    assert s["input_quantized_fraction"] == pytest.approx(np.mean(q_u != traj.u))
    # the plant was stepped with q_u(u): one RK4 step from row 0 with the quantized input
    plant = qcontrol.assembly.build_plant(sc, "ode")
    with plant:
        plant.reset(np.array([sc.x0]))
        plant.step(np.array([q_u[0]]), sc.simulation.dt)
        np.testing.assert_array_equal(plant.state()[0], traj.x[1])


def test_hysteresis_in_a_batch_gives_each_single_run() -> None:
    variants = [scenario(kind="hysteresis", delta=[0.002, 0.02]).with_overrides({"plant.x0": x0})
                for x0 in ([0.3, 0.3], [-0.2, 0.5])]
    batch = run_variants(variants, "ode")
    for sc, together in zip(variants, batch, strict=True):
        alone = run_scenario(sc, backend="ode")
        np.testing.assert_array_equal(together.x_q, alone.x_q)
        np.testing.assert_array_equal(together.x, alone.x)


def test_a_sweep_over_per_channel_steps() -> None:
    rows = qcontrol.sweep(scenario(delta=[0.0015, 0.05]),
                          {"quantizer.delta": [[0.0015, 0.05], [0.01, 0.01]]}, backend="ode")
    assert len(rows) == 2 and all(r["lemma2_max_ratio"] <= 1 + LEMMA2_TOLERANCE for r in rows)


@pytest.mark.parametrize("keys", [  # (hysteresis and a uniform input quantizer are compiled)
    {"quantizer.kind": "logarithmic", "quantizer.rho": 0.9, "quantizer.u_min": 0.001},
    {"quantizer.delta": 0.01, "quantizer.input.kind": "logarithmic", "quantizer.input.rho": 0.9,
     "quantizer.input.u_min": 0.001},
    {"quantizer.delta": 0.01, "plant.input_gain": 2.0},
])
def test_the_compiled_loop_declines_what_it_does_not_know(keys: dict) -> None:
    sc = qcontrol.load_scenario("example2", {"simulation.duration": 60.0} | keys, unset=["controller.delta"])
    assert ClosedLoop(run_spec(sc, qcontrol.assembly.build_plant(sc, "ode"),
                               qcontrol.assembly.build_controller(sc), [sc.x0], None)).compiled is None


# ---- time in the plant's terms: the forced Duffing oscillator --------------------------------------


@pytest.mark.usefixtures("python_loop")
def test_forced_duffing_agrees_on_both_backends() -> None:
    sc = qcontrol.load_scenario("duffing")
    assert sc.terms.timed and sc.psi == "2.1*cos(1.8*t)"
    physics, ideal = run_scenario(sc, backend="mujoco"), run_scenario(sc, backend="ode")
    deviation = backend_deviation(physics, ideal)
    assert deviation["max_abs_dy"] < 1e-12 and max(deviation["max_abs_dx"]) < 1e-12
    assert not physics.diverged and not ideal.diverged
    # the forcing is there: without it the run differs
    unforced = run_scenario(sc.with_overrides({"plant.psi": "0*x1"}), backend="ode")
    assert np.max(np.abs(unforced.x[:, 1] - ideal.x[:, 1])) > 0.01


def test_the_ode_evaluates_a_term_in_t_at_each_stage_time() -> None:
    """x2' = cos(t) alone (u = 0) from rest: RK4 with the stage times integrates it to x2 = sin(t)
    to RK4's accuracy; evaluated at the step's start only it would lag by about h / 2."""
    plant = qcontrol.plants.ode.ChainPlant(2, qcontrol.expression("cos(t)", ("x1", "x2", "t")), (), ())
    with plant:
        plant.reset(np.zeros((1, 2)))
        for _ in range(1000):
            plant.step(np.zeros(1), 0.001)
        assert plant.state()[0, 1] == pytest.approx(math.sin(1.0), abs=1e-12)


def test_recordings_draw_q_u_of_u_beside_u_only_with_an_input_quantizer() -> None:
    keys = {"quantizer.delta": 0.01, "quantizer.input.delta": 0.5, "simulation.duration": 0.5}
    quantized = run_scenario(qcontrol.load_scenario("example2", keys, unset=["controller.delta"]),
                             backend="ode")
    plain = run_scenario(qcontrol.load_scenario("example2", {"simulation.duration": 0.5}), backend="ode")
    paths = {s.path: s for s in run_series(quantized, "ode")}
    assert "signals/input/u" in paths and "signals/input/u_quantized" in paths
    assert paths["signals/input/u_quantized"].labels == ("q_u(u)",)
    assert "signals/input/u_quantized" not in {s.path for s in run_series(plain, "ode")}


def test_the_sensor_study_states_the_theory_per_row(tmp_path) -> None:
    import json

    from qcontrol.reproduce.sensor_study import (
        ROWS,
        fig_sensors,
        sensor_markdown,
        sensor_record,
        sensor_study,
    )
    from qcontrol.resources import shipped_dir
    study = sensor_study(shipped_dir("scenarios"), 2.0, lambda line: None)
    rows = study["rows"]
    assert len(rows) == len(ROWS)
    theory = [row["theory"] for row in rows]
    assert theory[0] == "Lemma 2 applies, L = 0.025: held"
    assert rows[1]["summary"].L == pytest.approx(0.05 / 2 + 4.0 * (2 * math.pi / 4096) / 2, rel=1e-15)
    assert "does not hold where readings saturated" in theory[3]
    assert "does not apply (logarithmic" in theory[5]
    assert "outside the theory" in theory[6] and "held" in theory[6]
    json.dumps(sensor_record(study))  # sensors.json is plain JSON
    table = sensor_markdown(study)
    assert sum(line.startswith("| ") for line in table) == len(ROWS) + 1
    assert fig_sensors(study, tmp_path / "s.png").stat().st_size > 10_000
