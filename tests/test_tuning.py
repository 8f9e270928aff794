"""Strict-feedback plants and the tuning-function law.

The symbolic derivative against central finite differences (nested, as the design needs it); the
design against the n = 2 law written out by hand from the textbook's formulas; the Lyapunov
identity V' = -sum c_i z_i^2 along closed loops of order 2, 3 and 4 without quantization; the
shipped example's tracking with and without quantization; the plant's right-hand side; the class
check of the chain laws; and the bad inputs of the new keys.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from conftest import SCENARIOS

import qcontrol
from qcontrol.cli import main
from qcontrol.controller.tuning import TuningLaw
from qcontrol.expr import compile_expression, derivative, expression
from qcontrol.expr.calculus import Program, differentiate
from qcontrol.plants.ode import ChainPlant

KKK = SCENARIOS / "kkk.toml"
XY = ("x1", "x2", "x3")


@pytest.mark.parametrize("source", [
    "x2**2*cos(x1)", "sin(x1)/(1 + x2**2)", "spow(x1, 1/3)*exp(x2)", "max(x1, x2, 0.3)*tanh(x1)",
    "sqrt(1 + x1**2)*log(2 + x2**2)", "cbrt(x1) + x1**x2", "abs(x1)*tan(x2) - x3**3/(1 + x1*x3)",
    "min(x1*x2, x3) + pi*sign(x1)", "2 - x1*(x2 - 3*x3)"])
def test_derivative_matches_central_differences(source: str) -> None:
    e = expression(source, XY)
    rng = np.random.default_rng(7)
    points = rng.uniform(0.2, 1.3, size=(20, 3))
    points[:, 1] *= rng.choice([-1.0, 1.0], size=20)  # away from the kinks of abs, sign, min, max
    h = 1e-6
    for i, name in enumerate(XY):
        d = derivative(e, name)
        step = np.zeros(3)
        step[i] = h
        fd = (e(points + step) - e(points - step)) / (2 * h)
        ok = np.abs(np.abs(points[:, 0] * points[:, 1]) - points[:, 2]) > 1e-3  # min's tie
        ok &= np.abs(points[:, 0] - points[:, 1]) > 1e-3
        assert np.allclose(d(points)[ok], fd[ok], rtol=1e-6, atol=1e-6), (source, name)
        again = expression(d.source, XY)  # its source text is the same function
        assert np.allclose(again(points), d(points), rtol=1e-12, atol=1e-12)


def test_nested_derivatives_and_shared_evaluation() -> None:
    """Second derivatives (what alpha_3 needs of alpha_1) against differences of first ones, and a
    Program of shared trees against each tree's own evaluation, on floats and on arrays."""
    e = expression("x1**3*sin(x2) + exp(x1*x2)", XY)
    memo: dict = {}
    dx = differentiate(e._tree, 0, memo)
    dxy = differentiate(dx, 1, memo)
    first = compile_expression("0", XY)  # an Expression shell to evaluate the trees with numpy
    program = Program([dx, dxy])
    x = np.array([0.7, -0.4, 0.0])
    h = 1e-6
    d1 = derivative(e, "x1")
    fd = (d1(x + [0, h, 0]) - d1(x - [0, h, 0])) / (2 * h)
    value_dx, value_dxy = program([float(v) for v in x])
    assert value_dxy == pytest.approx(float(fd), rel=1e-6)
    assert value_dx == pytest.approx(float(d1(x)), rel=1e-14)
    arrays = program([np.array([0.7, 0.1]), np.array([-0.4, 0.9]), np.zeros(2)])
    assert arrays[1][0] == pytest.approx(value_dxy, rel=1e-13)
    assert first(x) == 0.0


def _law(rows: list[list[str]], c: list[float], gamma: float = 1.0, sigma: float = 0.0) -> TuningLaw:
    names = [f"x{i + 1}" for i in range(len(rows))]
    compiled = [[compile_expression(t, names) for t in row] for row in rows]
    return TuningLaw(c, 1e-12, compiled, gamma=gamma, sigma=sigma)


def test_a_program_on_copies_is_each_copys_float_evaluation() -> None:
    """What a batch of copies computes (numpy's own exp, tanh, log may round otherwise): each
    copy's values are the float evaluation's of that copy alone, also where math refuses one copy
    (log of a negative number: that copy takes numpy's answer, NaN, the others keep math's)."""
    e = expression("exp(x1)*tanh(x2) + log(1 + x1**2)*x3 + sqrt(x3)", XY)
    program = Program([e._tree, differentiate(e._tree, 0, {})])
    rng = np.random.default_rng(3)
    columns = [rng.uniform(-2.0, 2.0, 50), rng.uniform(-2.0, 2.0, 50), rng.uniform(0.0, 2.0, 50)]
    refusing = [columns[0], columns[1], np.where(np.arange(50) == 7, -1.0, columns[2])]
    for cols in (columns, refusing):
        copies = program.on_copies(cols)
        for b in range(50):
            alone = program([float(c[b]) for c in cols])
            assert np.array([v[b] for v in copies]).tobytes() == np.array(alone).tobytes()
    first = program.on_copies(refusing)[0]
    assert np.isnan(first[7]) and np.isfinite(first).sum() == 49
    numpy = program(columns)[0]  # numpy's exp and tanh: not every copy's float value
    assert not np.array_equal(numpy, program.on_copies(columns)[0])


def test_n2_design_equals_the_law_written_by_hand() -> None:
    """x1' = x2 + theta x1^2, x2' = u: the tuning-function law of the textbook, term by term."""
    c1, c2, g = 2.0, 3.0, 0.7
    law = _law([["x1**2"], ["0"]], [c1, c2], gamma=g)
    rng = np.random.default_rng(3)
    for x1, x2, th, y0, y1, y2 in rng.normal(size=(25, 6)):
        z1 = x1 - y0
        a1 = -c1 * z1 - th * x1**2
        tau1 = x1**2 * z1
        z2 = x2 - y1 - a1
        da1_dx1, da1_dyd, da1_dth = -c1 - 2 * th * x1, c1, -x1**2
        w2 = -da1_dx1 * x1**2
        tau2 = tau1 + w2 * z2
        a2 = -z1 - c2 * z2 - w2 * th + da1_dx1 * x2 + da1_dyd * y1 + da1_dth * g * tau2
        u, tau, e1, e2 = law.values([x1, x2], [th], [y0, y1, y2])
        assert u == pytest.approx(a2 + y2, rel=1e-12, abs=1e-12)
        assert tau == pytest.approx(tau2, rel=1e-12, abs=1e-12)
        assert (e1, e2) == pytest.approx((z1, z2), rel=1e-12, abs=1e-12)


PLANTS = {  # order: (regressor rows, theta, c, x0)
    2: ([["x1**2"], ["0"]], [1.0], [2.0, 2.0], [0.5, 0.0]),
    3: ([["x1", "0"], ["0", "sin(x1)*x2"], ["x2", "x3**2/(1 + x3**2)"]], [0.5, -0.8], [2.0, 2.0, 2.0],
        [0.3, 0.0, 0.1]),
    4: ([["0.5*x1**2"], ["sin(x2)"], ["0"], ["x4*cos(x1)"]], [0.8], [2.0, 2.0, 2.0, 2.0],
        [0.2, 0.0, 0.0, 0.0]),
}


def _reference(t: float, n: int) -> list[float]:
    """y_d = 0.5 sin t and its n derivatives."""
    return [0.5 * [np.sin(t), np.cos(t), -np.sin(t), -np.cos(t)][k % 4] for k in range(n + 1)]


def _closed_loop_identity(n: int, h: float = 5e-4, duration: float = 4.0) -> tuple[float, float, float]:
    """The continuous-time closed loop of the order-n plant (u evaluated at every RK4 stage, exact
    states), integrated here; returns the largest |V' + sum c z^2| (V' by central differences of V
    along the run), the largest sum c z^2, and max |z1| over the last quarter."""
    rows, theta, c, x0 = PLANTS[n]
    law = _law(rows, c, gamma=1.0)
    names = [f"x{i + 1}" for i in range(n)]
    phi = [[compile_expression(t, names) for t in row] for row in rows]
    theta, m = np.array(theta), len(theta)

    def rate(t: float, s: np.ndarray) -> tuple[np.ndarray, list[float]]:
        """The closed loop's s' at (t, s), and the law's values there (u, tau, z)."""
        x, th = s[:n], s[n:]
        values = law.values([float(v) for v in x], [float(v) for v in th], _reference(t, n))
        u, tau = values[0], np.array(values[1:1 + m])
        dx = np.array([(x[i + 1] if i < n - 1 else u) + sum(theta[j] * float(phi[i][j](x)) for j in range(m))
                       for i in range(n)])
        return np.concatenate([dx, law.gamma * tau]), values

    s, t, states = np.array([*x0, *np.zeros(m)], dtype=float), 0.0, []
    for _ in range(int(round(duration / h)) + 1):
        k1, values = rate(t, s)  # (z at the state: V's, below)
        states.append((t, s.copy(), values[1 + m:]))
        k2 = rate(t + h / 2, s + h / 2 * k1)[0]
        k3 = rate(t + h / 2, s + h / 2 * k2)[0]
        k4 = rate(t + h, s + h * k3)[0]
        s, t = s + h / 6 * (k1 + 2 * (k2 + k3) + k4), t + h
    V, dissipation, z1 = [], [], []
    for _, s, z in states:
        V.append(0.5 * sum(zi * zi for zi in z) + float(np.sum((theta - s[n:]) ** 2)) / (2 * law.gamma))
        dissipation.append(sum(ci * zi * zi for ci, zi in zip(c, z, strict=True)))
        z1.append(z[0])
    V, dissipation = np.array(V), np.array(dissipation)
    dV = (V[2:] - V[:-2]) / (2 * h)
    residual = float(np.max(np.abs(dV + dissipation[1:-1])))
    return residual, float(dissipation.max()), float(np.max(np.abs(z1[-len(z1) // 4:])))


@pytest.mark.parametrize("n", [2, 3, 4])
def test_lyapunov_identity_without_quantization(n: int) -> None:
    """V = sum z_i^2 / 2 + |theta - theta_hat|^2 / (2 gamma) has V' = -sum c_i z_i^2 along the
    run (sigma = 0): any wrong term of the design (a derivative, a tuning function) breaks it."""
    coarse, scale, _ = _closed_loop_identity(n, h=1e-3, duration=1.0)
    fine, _, _ = _closed_loop_identity(n, h=5e-4, duration=1.0)
    assert fine < 5e-6 * max(1.0, scale), (n, fine, scale)
    # what is left is the integration's and the differences' error, O(h^2): a wrong term would not shrink
    assert fine < 0.3 * coarse or fine < 1e-9 * max(1.0, scale), (n, coarse, fine)
    # z1 -> 0: a claim about the loop, not the integration, so a 4 ms RK4 step (z1 the same as at
    # 1 ms to 1e-9 here) at a quarter of the cost
    _, _, late = _closed_loop_identity(n, h=4e-3, duration=4.0)
    assert late < 0.05


def test_kkk_tracks_with_and_without_quantization() -> None:
    """The shipped example: max |z1| over the last half about 0.011 exact and 0.010 with delta =
    0.01 (the textbook's design at 1 kHz), bounded with delta = 0.05."""
    sc = qcontrol.load_scenario("kkk")
    assert sc.terms.first_nonzero_row == 1
    quantized = qcontrol.run(sc, backend="ode").summary
    exact = qcontrol.run(sc.with_overrides({"controller.delta": 1e-12}), backend="ode").summary
    coarse = qcontrol.run(sc.with_overrides({"controller.delta": 0.05}), backend="ode").summary
    assert 0.008 < exact["max_abs_z1_last_half"] < 0.014
    assert 0.008 < quantized["max_abs_z1_last_half"] < 0.014
    assert not coarse["diverged"] and coarse["max_abs_z1_last_half"] < 0.05
    assert exact["adaptive_state"] == "theta_hat" and 0.5 < exact["final_theta_hat"][0] < 1.5
    assert exact["lemma2_applies"] is False  # Lemma 2's bounds are the chain's


def test_plant_rows_and_chain_rows() -> None:
    """x1' = x2 + theta phi_1, x2' = u + theta phi_2: the rows' terms where they are, and a plant
    whose rows before the last are "0" computes the chain's numbers bit for bit."""
    v = ["x1", "x2"]
    e = [compile_expression(t, v) for t in ("x1**2", "0", "x2", "sin(x1)")]
    plant = ChainPlant(2, None, [e[2], e[3]], [2.0, -1.0], batch=2, rows=[[e[0], e[1]]])
    x = np.array([[0.5, 0.3], [-1.0, 2.0]])
    assert np.array_equal(plant.rhs(x, np.array([1.0, 0.0])),
                          [[0.3 + 2.0 * 0.25, 1.0 + 2.0 * 0.3 - np.sin(0.5)],
                           [2.0 + 2.0, 0.0 + 4.0 - np.sin(-1.0)]])
    chain = ChainPlant(2, None, [e[2], e[3]], [2.0, -1.0], batch=2)
    zeros = ChainPlant(2, None, [e[2], e[3]], [2.0, -1.0], batch=2, rows=[[e[1], e[1]]])
    for p in (chain, zeros):
        p.reset(x)
        for _ in range(50):
            p.step(np.array([0.3, -0.2]), 1e-3)
    assert np.array_equal(chain.state(), zeros.state())


def _scenario(tmp_path: Path, old: str, new: str) -> Path:
    """kkk.toml with ``old`` replaced by ``new`` (several edits: separated by ``|``)."""
    text = KKK.read_text(encoding="utf-8")
    for a, b in zip(old.split("|"), new.split("|"), strict=True):
        assert a in text
        text = text.replace(a, b, 1)
    path = tmp_path / "bad.toml"
    path.write_text(text, encoding="utf-8")
    return path


@pytest.mark.parametrize(("old", "new", "fragments"), [
    ('phi = [["x1**2"], ["0"]]', 'phi = [["x1**2"], ["0", "x2"]]', ("plant.phi[0]", "the last row has 2")),
    ('phi = [["x1**2"], ["0"]]', 'phi = [["x1*x2"], ["0"]]', ("plant.phi[0][0]", "x2", "row 1")),
    ('phi = [["x1**2"], ["0"]]', 'phi = [["x1**2"]]', ("plant.phi", "rows")),
    ('phi = [["x1**2"], ["0"]]|theta = [1.0]', 'phi = []|theta = []', ("plant.phi", "tuning")),
    ("gamma = 1.0", "gamma = 0.0", ("controller.tuning.gamma", "> 0")),
    ("sigma = 0.0", "sigma = -0.1", ("controller.tuning.sigma", ">= 0")),
    ('kind = "tuning"', 'kind = "proposed"', ("controller.kind", "plant.phi[0]", "tuning")),
    ('kind = "tuning"', 'kind = "comparison"', ("controller.kind", "plant.phi[0]", "tuning")),
])
def test_bad_input(tmp_path: Path, capsys: pytest.CaptureFixture[str], old: str, new: str,
                   fragments: tuple[str, ...]) -> None:
    path = _scenario(tmp_path, old, new)
    out = tmp_path / "out"
    assert main(["run", str(path), "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("qcontrol: error: ") and "; " in err[0], err
    assert "bad.toml" in err[0] or "--set" in err[0], err
    for fragment in fragments:
        assert fragment in err[0], (fragment, err[0])
    assert not out.exists()


def test_the_plant_class_in_the_law_context() -> None:
    """A user law sees the regressor rows; the chain's rows are "0"."""
    ctx = qcontrol.load_scenario("kkk").law_context
    assert [[e.source for e in row] for row in ctx.regressor_rows] == [["x1**2"], ["0"]]
    chain = qcontrol.load_scenario("chain3").law_context
    assert chain.first_nonzero_row is None
    assert [[e.source for e in row] for row in chain.regressor_rows] == [["0", "0"], ["0", "0"],
                                                                         ["x2**3", "sin(x1)"]]


def test_a_batch_of_the_tuning_law_is_compiled_and_each_copy_is_its_run_alone(monkeypatch) -> None:
    """The design's program with exp and tanh (numpy's round otherwise): the compiled batch, the
    Python batch and each copy's run alone give the same numbers to the last bit."""
    import qcontrol.engine.compiled_loop as compiled_loop
    from qcontrol.assembly import assemble
    from qcontrol.engine import ClosedLoop

    monkeypatch.setattr(compiled_loop, "MIN_ROWS", 0)
    monkeypatch.setattr(compiled_loop, "COLD_MIN_ROWS", 0)
    keys = ['controller.kind="tuning"', 'plant.phi=["x2", "exp(x1)*x2", "tanh(x1)"]',
            "simulation.duration=0.3"]
    scs = [qcontrol.load_scenario(SCENARIOS / "example2.toml", [*keys, f"plant.x0=[{a!r}, 0.0]"])
           for a in (-1.5, -0.5, 0.25, 1.0, 2.0)]
    loop = ClosedLoop(assemble(scs, "ode").spec)
    compiled = loop.run()
    assert loop.handover is None  # compiled from row 0 to the end
    monkeypatch.setenv("QCONTROL_COMPILE", "0")
    python = assemble(scs, "ode").run()
    alone = [assemble([sc], "ode").run()[0] for sc in scs]
    for a, b, c in zip(compiled, python, alone, strict=True):
        for name in ("x", "x_q", "u", "adaptive"):
            values = np.asarray(a.signals[name]).tobytes()
            assert values == np.asarray(b.signals[name]).tobytes() == np.asarray(c.signals[name]).tobytes()
