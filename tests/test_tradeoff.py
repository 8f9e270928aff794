"""The linear law u = alphabar_n: against the PD law of its gains computed by hand (the closed
loop's characteristic polynomial (s + c_1)..(s + c_n)), refused outside the chain class."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import SCENARIOS

from qcontrol.controller.linear import LinearLaw
from qcontrol.errors import QcontrolInputError
from qcontrol.quantizer import QuantizedReading
from qcontrol.scenario import load_scenario


@pytest.mark.parametrize("c", [[4.0, 3.0], [20.0, 20.0], [2.0, 5.0, 7.0], [1.5, 2.0, 2.5, 3.0]])
def test_the_linear_law_is_the_pd_law_of_its_gains(c: list[float]) -> None:
    """u = y_d^(n) - sum_k a_(n-k) (q_(k+1) - y_d^(k)), a the coefficients of (s + c_1)..(s + c_n):
    for n = 2, kp = c1 c2 and kd = c1 + c2 (so c = [20, 20] is kp = 400, kd = 40)."""
    n = len(c)
    rng = np.random.default_rng(11)
    q = rng.uniform(-3.0, 3.0, size=(4, n))  # four copies at once
    yd = rng.uniform(-2.0, 2.0, size=n + 1)
    out = LinearLaw(c, 0.005).control(QuantizedReading(q, 0.005), tuple(yd), ())
    a = np.poly(-np.array(c))  # [1, a_1, .., a_n]
    e = q - yd[:n]
    by_hand = yd[n] - sum(a[n - k] * e[:, k] for k in range(n))
    np.testing.assert_allclose(out.u, by_hand, rtol=1e-12, atol=1e-12)
    if n == 2:
        assert (a[2], a[1]) == (c[0] * c[1], c[0] + c[1])
    assert out.target == () and LinearLaw(c, 0.005).initial_state(3).shape == (3, 0)


def test_the_linear_law_runs_as_a_kind_and_is_refused_outside_the_chain() -> None:
    sc = load_scenario(SCENARIOS / "example2.toml", ["controller.kind=linear", "controller.c=[20.0, 20.0]"])
    assert sc.controller.kind == "linear" and sc.controller.c == (20.0, 20.0)
    with pytest.raises(QcontrolInputError) as refused:
        load_scenario(SCENARIOS / "kkk.toml", ["controller.kind=linear"])
    message = str(refused.value)
    assert "\n" not in message and "law 'linear' needs a chain" in message and "plant.phi[0]" in message
    assert "tuning" in message
    with pytest.raises(QcontrolInputError, match="controller.linear.gain"):
        load_scenario(SCENARIOS / "example2.toml", ["controller.kind=linear", "controller.linear.gain=2"])
