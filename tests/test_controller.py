"""Backstepping coefficients (recursion after eq. (27)), Lemma 2 (Appendix A) and laws (44)-(46)
against independent math."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from numpy.polynomial import Polynomial as P

from qcontrol.controller import (
    Backstepping,
    ComparisonLaw,
    PaperLaw,
    backstepping_coefficients,
    lemma2_bounds,
)
from qcontrol.errors import QcontrolInputError
from qcontrol.expr import compile_expression
from qcontrol.quantizer import UniformQuantizer, quantize

Q2 = ["q1", "q2"]
X2 = ["x1", "x2"]


def _alphas_by_definition(c, x1: P, yd: P):
    """alpha_1 = -c1 z1 + yd', alpha_i = -c_i z_i + d/dt alpha_{i-1}, with exact polynomial
    derivatives along the chain trajectory x_k = x1^(k-1)."""
    n = len(c)
    x = [x1.deriv(k) for k in range(n)]
    alphas = [-c[0] * (x[0] - yd) + yd.deriv(1)]
    for i in range(1, n):
        z = x[i] - alphas[i - 1]
        alphas.append(-c[i] * z + alphas[i - 1].deriv(1))
    return x, alphas


@pytest.mark.parametrize("c", [[2.0, 3.0], [1.5, 0.7, 2.2], [4.0, 3.0, 2.0, 1.0], [0.3, 5.0, 1.1, 2.5]])
def test_coefficients_match_the_definition(c):
    n = len(c)
    rng = np.random.default_rng(n)
    x1 = P(rng.normal(size=n + 4))
    yd = P(rng.normal(size=n + 4))
    x, alphas = _alphas_by_definition(c, x1, yd)
    A, B = backstepping_coefficients(c)
    for t in (-0.7, 0.0, 0.3, 1.9):
        xt = np.array([xk(t) for xk in x])
        ydt = np.array([yd.deriv(j)(t) for j in range(n + 1)])
        for i in range(n):
            assert A[i] @ xt + B[i] @ ydt == pytest.approx(alphas[i](t), rel=1e-10, abs=1e-10)
        assert np.all(A[np.triu_indices(n, 1)] == 0)


def test_n2_closed_form():
    c1, c2 = 2.5, 1.5
    A, B = backstepping_coefficients([c1, c2])
    np.testing.assert_allclose(A[1], [-c1 * c2, -(c1 + c2)])
    np.testing.assert_allclose(B[1], [c1 * c2, c1 + c2, 1.0])
    np.testing.assert_allclose(A[0], [-c1, 0.0])
    np.testing.assert_allclose(B[0], [c1, 1.0, 0.0])


def test_lemma2_n2_closed_form():
    L_z, L_alpha = lemma2_bounds([4.0, 3.0], 0.01 / 2)
    assert L_z[-1] == pytest.approx((1 + 4.0) * 0.01 / 2)  # the paper's L = 0.025
    assert L_alpha[0] == pytest.approx(4.0 * 0.005)


@settings(max_examples=60, deadline=None)
@given(
    n=st.integers(2, 5),
    delta=st.floats(1e-3, 0.5),
    seed=st.integers(0, 2**31 - 1),
)
def test_lemma2_bounds_hold_for_random_states(n, delta, seed):
    """|z_i - zbar_i| <= L_zi and |alpha_i - alphabar_i| <= L_alphai for arbitrary x, y_d."""
    rng = np.random.default_rng(seed)
    c = rng.uniform(0.2, 5.0, size=n)
    bs = Backstepping(c, delta / 2)
    x = rng.uniform(-20, 20, size=(500, n))
    yd = rng.uniform(-3, 3, size=n + 1)
    q = UniformQuantizer(delta)(x)
    z = bs.errors(x, yd)
    zbar, alphabar = bs.quantized_errors(q, yd)
    alpha = x @ bs.A.T + yd @ bs.B.T
    tol = 1e-9 * (1 + np.abs(x).max() * np.abs(bs.A).max())
    assert np.all(np.abs(z - zbar) <= bs.L_z + tol)
    assert np.all(np.abs(alpha - alphabar) <= bs.L_alpha + tol)


def test_quantized_errors_equal_true_errors_on_grid_points():
    bs = Backstepping([2.0, 1.0, 3.0], 0.05)
    x = np.array([[0.3, -0.2, 1.1]])  # already on the 0.1 grid
    yd = np.array([0.1, 0.2, -0.3, 0.4])
    zbar, _ = bs.quantized_errors(x, yd)
    np.testing.assert_allclose(zbar, bs.errors(x, yd), atol=1e-14)


def _proposed(kappa_margin=1.1):
    r = [compile_expression(e, Q2) for e in ("1 + q2**2", "1 + 2*q2**2", "1")]
    return PaperLaw([4.0, 3.0], 0.005, kappa=0.025 + kappa_margin, gamma=1.0, sigma=1.0, r=r)


def test_control_law_44_by_hand():
    ctrl = _proposed()
    q1, q2 = 0.31, -0.42
    yd = np.array([0.2, 1.1, -0.5])
    eps = np.array([[0.7, 1.3, 2.1]])
    out = ctrl.control(quantize(UniformQuantizer(0.01), np.array([[q1, q2]])), yd, tuple(eps.T))
    c1, c2, kappa, L = 4.0, 3.0, 1.125, 0.025
    q1, q2 = 0.31, -0.42  # both on the 0.01 grid
    zb1 = q1 - yd[0]
    ab1 = -c1 * zb1 + yd[1]
    zb2 = q2 - ab1
    ab2 = -c2 * zb2 + (-c1) * q2 + c1 * yd[1] + yd[2]
    r = np.array([1 + q2**2, 1 + 2 * q2**2, 1.0])
    s = zb2**2 / kappa + L
    u = -(zb2 / kappa) / (kappa - L) * s * (eps[0] @ r) + ab2
    assert out.u[0] == pytest.approx(u, rel=1e-13)
    np.testing.assert_allclose([z[0] for z in out.zbar], [zb1, zb2], rtol=1e-13)
    # eq. (45) over h with x_q held: eps' = gamma (s r - sigma eps), exact exponential
    h = 0.01
    target = s * r / 1.0
    expected = target + (eps[0] - target) * np.exp(-1.0 * 1.0 * h)
    np.testing.assert_allclose(np.ravel(ctrl.advancer(h)(tuple(eps.T), out)), expected, rtol=1e-13)


def test_adaptive_law_45_matches_fine_euler():
    ctrl = _proposed()
    reading = quantize(UniformQuantizer(0.01), np.array([[0.5, 0.8]]))
    out = ctrl.control(reading, np.array([0.0, 1.0, 0.0]), tuple(np.zeros((3, 1))))
    eps = np.zeros((1, 3))
    h, m = 0.05, 200000
    s_r = np.column_stack(out.target) * ctrl.sigma
    for _ in range(m):
        eps = eps + (h / m) * ctrl.gamma * (s_r - ctrl.sigma * eps)
    advanced = ctrl.advancer(h)(tuple(np.zeros((3, 1))), out)
    np.testing.assert_allclose(np.column_stack(advanced), eps, rtol=1e-5)


def test_eps_hat_stays_nonnegative():
    ctrl = _proposed()
    rng = np.random.default_rng(1)
    eps = tuple(ctrl.initial_state(50).T)
    quant, advance = UniformQuantizer(0.01), ctrl.advancer(0.01)
    for _ in range(100):
        out = ctrl.control(quantize(quant, rng.normal(size=(50, 2))), rng.normal(size=3), eps)
        eps = advance(eps, out)
    assert np.all(np.column_stack(eps) >= 0)


def test_baseline_law_46_by_hand():
    phi = [compile_expression(e, X2) for e in ("x2", "x2**2*cos(x1)", "sin(x1)")]
    ctrl = ComparisonLaw([4.0, 3.0], 0.005, None, phi)
    q = np.array([[0.2, -0.3]])
    yd = np.array([0.0, 1.5, 0.0])
    theta_hat = np.array([[0.5, -1.0, 2.0]])
    out = ctrl.control(quantize(UniformQuantizer(0.01), q), yd, tuple(theta_hat.T))
    zb1 = 0.2
    ab1 = -4 * zb1 + 1.5
    zb2 = -0.3 - ab1
    ab2 = -3 * zb2 - 4 * (-0.3) + 4 * 1.5
    phi_q = np.array([-0.3, 0.09 * np.cos(0.2), np.sin(0.2)])
    assert out.u[0] == pytest.approx(ab2 - theta_hat[0] @ phi_q, rel=1e-13)
    np.testing.assert_allclose(np.ravel(ctrl.advancer(0.1)(tuple(theta_hat.T), out)),
                               theta_hat[0] + 0.1 * phi_q * zb2)


def test_controller_refuses_unquantized_state():
    ctrl = _proposed()
    with pytest.raises(TypeError, match="QuantizedReading"):
        ctrl.control(np.array([[0.3, 0.3]]), np.zeros(3), tuple(np.zeros((3, 1))))
    with pytest.raises(ValueError, match="Lemma 2"):
        ctrl.control(quantize(UniformQuantizer(0.1), np.zeros((1, 2))), np.zeros(3), tuple(np.zeros((3, 1))))


@pytest.mark.parametrize(
    "kwargs, message",
    [
        (dict(kappa=0.025), "kappa must exceed L"),
        (dict(kappa=0.02), "kappa must exceed L"),
        (dict(gamma=0.0), "gamma"),
        (dict(sigma=-1.0), "sigma"),
        (dict(c=[4.0, 0.0]), "gain"),
        (dict(c=[4.0]), "n must be >= 2"),
        (dict(max_error=0.0), "delta"),
        (dict(expected_terms=2), "uncertain term"),
    ],
)
def test_construction_errors(kwargs, message):
    r = [compile_expression(e, Q2) for e in ("1 + q2**2", "1 + 2*q2**2", "1")]
    args = dict(c=[4.0, 3.0], max_error=0.005, kappa=1.125, gamma=1.0, sigma=1.0, r=r, expected_terms=3)
    args.update(kwargs)
    with pytest.raises(QcontrolInputError, match=message):
        PaperLaw(**args)


def test_coordinates_of_the_same_gains_are_the_first_objects_numbers_in_arrays_of_their_own():
    """A batch of user laws builds the same coordinates once per copy: later objects take the
    first one's numbers (bit for bit, as computed), each in arrays of its own."""
    c, bound, names = [1.5, 0.7, 2.2], 0.025, ("A", "B", "L_z", "L_alpha", "_Wq", "_Wy")
    first = Backstepping(c, bound)
    for name in names:
        getattr(first, name)[...] = 7.0  # (what one object does to its arrays stays its own)
    second, third = Backstepping(c, bound), Backstepping(np.array(c), np.float64(bound))
    A, B = backstepping_coefficients(np.array(c))
    L_z, L_alpha = lemma2_bounds(np.array(c), bound)
    expected = {"A": A, "B": B, "L_z": L_z, "L_alpha": L_alpha}
    for name in names:
        ours, theirs = getattr(second, name), getattr(third, name)
        assert ours is not theirs and ours.tobytes() == theirs.tobytes() and not np.any(ours == 7.0)
        if name in expected:
            assert ours.tobytes() == expected[name].tobytes()
    assert second._steps == third._steps and second.L == float(L_z[-1])
    q = np.array([[0.1, -0.2, 0.3]])
    yd = np.array([[0.05, 0.4, -0.1, 0.2]])
    by_recursion = second.recursion(tuple(q.T), tuple(yd.T))
    zbar, alphabar = second.quantized_errors(q, yd)
    assert np.allclose(zbar, np.column_stack(by_recursion[0]), rtol=0, atol=1e-15)
    assert np.allclose(alphabar, np.column_stack(by_recursion[1]), rtol=0, atol=1e-15)


def test_a_subclass_with_its_own_recursion_derives_its_coordinates_itself():
    class Doubled(Backstepping):
        def recursion(self, q, yd):
            zbar, alphabar = super().recursion(q, yd)
            return [2.0 * z for z in zbar], alphabar

    plain, doubled = Backstepping([2.0, 3.0], 0.01), Doubled([2.0, 3.0], 0.01)
    assert np.array_equal(doubled._Wq[:, :2], 2.0 * plain._Wq[:, :2])
    assert np.array_equal(Backstepping([2.0, 3.0], 0.01)._Wq, plain._Wq)
