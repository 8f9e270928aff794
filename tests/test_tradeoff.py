"""The linear law u = alphabar_n and the reproduction's trade-off study.

The law against the PD law of its gains computed by hand (the closed loop's characteristic
polynomial (s + c_1)..(s + c_n)), refused outside the chain class; the study on a 3 x 3 grid with
short runs: every law's row and map, the exact hold failing no start where the paper's law fails
some, and the high-gain linear law tracking better while failing from starts the exact hold holds.
"""

from __future__ import annotations

import numpy as np
import pytest
from conftest import SCENARIOS

from qcontrol.controller.linear import LinearLaw
from qcontrol.errors import QcontrolInputError
from qcontrol.quantizer import QuantizedReading
from qcontrol.reproduce.tradeoff_study import (
    ADDED,
    HIGH_GAINS,
    tradeoff_record,
    tradeoff_section,
    tradeoff_study,
)
from qcontrol.scenario import load_scenario

OMEGAS = ["0.100", "0.125", "0.150", "0.175", "0.200"]


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
    sc = load_scenario(SCENARIOS / "example2.toml", ["controller.kind=linear", f"controller.c={HIGH_GAINS}"])
    assert sc.controller.kind == "linear" and sc.controller.c == (20.0, 20.0)
    with pytest.raises(QcontrolInputError) as refused:
        load_scenario(SCENARIOS / "kkk.toml", ["controller.kind=linear"])
    message = str(refused.value)
    assert "\n" not in message and "law 'linear' needs a chain" in message and "plant.phi[0]" in message
    assert "tuning" in message
    with pytest.raises(QcontrolInputError, match="controller.linear.gain"):
        load_scenario(SCENARIOS / "example2.toml", ["controller.kind=linear", "controller.linear.gain=2"])


@pytest.fixture(scope="module")
def small_study() -> dict:
    """Every law of the study on both examples: 3 x 3 starts, 0.1 s grid runs, 0.5 s from x(0)."""
    return tradeoff_study(SCENARIOS, 0.5, lambda line: None, resolution=3, grid_duration=0.1)


def test_every_law_has_its_row_and_its_map(small_study: dict) -> None:
    laws = ["proposed", "proposed:hold=exact", "comparison", *(law.label for law in ADDED)]
    assert [law["law"] for law in small_study["laws"]] == laws
    assert [(r["example"], r["law"]) for r in small_study["rows"]] == [
        (example, law) for example in ("example1", "example2") for law in laws]
    for r in small_study["rows"]:
        assert list(r["error_rate"]) == OMEGAS and all(0.0 <= v <= 1.0 for v in r["error_rate"].values())
        assert r["points_in_box"] == 9 and 0 <= r["failing_in_box"] <= 9 and r["equation"]
    assert [len(maps) for maps in small_study["maps"]] == [6, 6]
    assert all(m.codes.shape == (3, 3) for maps in small_study["maps"] for m in maps)
    tuning = next(r for r in small_study["rows"] if r["example"] == "example1" and r["law"] == "tuning")
    assert tuning["scenario_changes"] == ['plant.phi=["x2**2"]', "plant.theta=[0.1]", "unset plant.psi"]
    assert "maps" not in tradeoff_record(small_study)


def test_the_trade_off_is_there_to_see(small_study: dict) -> None:
    """Example 2: the exact hold fails from no start, the paper's law from some; the high-gain
    linear law tracks far better than the paper's law and fails from starts the exact hold holds."""
    rows = {(r["example"], r["law"]): r for r in small_study["rows"]}
    for example in ("example1", "example2"):
        assert rows[(example, "proposed:hold=exact")]["failing_in_box"] == 0
    paper, high = rows[("example2", "proposed")], rows[("example2", f"linear:c={HIGH_GAINS}")]
    assert paper["failing_in_box"] > 0 and high["failing_in_box"] > 0
    assert high["error_rate"]["0.100"] < paper["error_rate"]["0.100"] / 2
    section = "\n".join(tradeoff_section(small_study))
    assert "| example2 | linear, kp 400, kd 40 | " in section and "study_tradeoff.png" in section
    assert f"it fails from {high['failing_in_box']} of 9 starts" in section


def test_a_law_setting_may_be_a_list() -> None:
    """The study's high-gain law given back on the command line: its label parses to itself."""
    from qcontrol.region import parse_law

    law = parse_law(f"linear:c={HIGH_GAINS}")
    assert law.settings == (("c", HIGH_GAINS),) and parse_law(law.label) == law
    assert law.overrides() == ["controller.kind='linear'", f"controller.c={HIGH_GAINS}"]
    both = parse_law('proposed:r=["1 + q2**2", "1", "1"],hold=exact')
    assert both.settings == (("r", '["1 + q2**2", "1", "1"]'), ("hold", "exact"))
