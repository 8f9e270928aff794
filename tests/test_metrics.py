"""Error rate of Table 1 against hand-computed cases, and the summary's contract."""

import numpy as np
import pytest

from qcontrol.metrics import error_rate, lemma2_max_ratio


def test_error_rate_small_case_by_hand():
    # M = 5 samples over T = 4 at instants 0, 1, 2, 3, 4 where z1 = 0, .1, .2, .3, .4
    t = np.array([0.0, 1.0, 2.0, 3.0, 4.0])
    z1 = np.array([0.0, 0.1, 0.2, 0.3, 0.4])
    rates = error_rate(t, z1, 4.0, omegas=(0.15, 0.25, 0.1), samples=5)
    assert rates == {"0.150": 3 / 5, "0.250": 2 / 5, "0.100": 3 / 5}  # strict '>': 0.1 is not counted


def test_error_rate_uses_absolute_value_and_interpolates():
    t = np.array([0.0, 2.0])
    z1 = np.array([0.0, -2.0])  # |z1(t)| = t, sampled at 0, 0.5, 1, 1.5, 2
    assert error_rate(t, z1, 2.0, omegas=(0.75,), samples=5) == {"0.750": 3 / 5}


def test_error_rate_table1_default_grid():
    t = np.linspace(0, 10, 10001)
    z1 = np.where(t < 1.0, 1.0, 0.0)  # exceeds every omega for t < 1 (and ramps down to 1.001)
    rates = error_rate(t, z1, 10.0)
    instants = np.arange(1302) * 10 / 1301
    expected = np.count_nonzero(np.interp(instants, t, z1) > 0.1) / 1302
    assert rates["0.100"] == expected
    assert set(rates) == {"0.100", "0.125", "0.150", "0.175", "0.200"}
    assert expected == 131 / 1302  # instants i * 10/1301 < 1 for i = 0..130


def test_error_rate_counts_missing_tail_of_diverged_run():
    t = np.linspace(0, 5, 501)
    rates = error_rate(t, np.zeros_like(t), 10.0, omegas=(0.1,), samples=11)
    assert rates["0.100"] == pytest.approx(5 / 11)


def test_lemma2_ratio_ignores_nan_rows():
    e = np.array([[0.01, 0.02], [np.nan, np.nan], [0.005, 0.03]])
    assert lemma2_max_ratio(e, np.array([0.02, 0.04])) == pytest.approx(0.75)


def _reference_values(t, z1, instants):
    """|z1| at the instants by np.interp over the finite rows; inf after the last one."""
    finite = np.isfinite(z1)
    tf, zf = t[finite], np.abs(z1[finite])
    values = np.full(len(instants), np.inf)
    if tf.size:
        covered = instants <= tf[-1]
        values[covered] = np.interp(instants[covered], tf, zf)
    return values


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_batched_stream_in_chunks_equals_np_interp_per_run_bit_for_bit(seed):
    """One ErrorRateStream for a batch of runs fed in random chunks gives every run the values
    np.interp gives on that run's finite rows at once: runs that stop (NaN tails) at different
    rows, one that never starts, a NaN first row, a chunk boundary exactly at an instant."""
    from qcontrol.error_rate import ErrorRateStream

    rng = np.random.default_rng(seed)
    rows, horizon, samples = 2001, 2.0, 57
    t = np.arange(rows) * (horizon / (rows - 1))
    z1 = rng.normal(0.0, 0.3, (rows, 6))
    z1[1500:, 1] = np.nan  # stops at row 1499
    z1[37:, 2] = np.nan  # stops early, inside the first chunk
    z1[:, 3] = np.nan  # never finite
    z1[0, 4] = np.nan  # NaN first row: instants before its first finite row take that value
    z1[900:, 5] = np.nan
    # instants are i / 28 s, rows k / 1000 s: rows 250 and 1000 fall on instants 7 and 28; a chunk
    # starts at row 250 and at row 1000, and another ends at row 1000
    cuts = sorted({*rng.choice(np.arange(1, rows), size=12, replace=False).tolist(), 250, 1000, 1001})
    stream = ErrorRateStream(horizon, samples, batch=6)
    for lo, hi in zip([0, *cuts], [*cuts, rows], strict=True):
        stream.add(t[lo:hi], z1[lo:hi])
    every = stream.every_rate(np.linspace(0.0, 1.0, 41).tolist())  # all runs counted at once
    for run in range(6):
        expected = _reference_values(t, z1[:, run], stream.instants)
        done = stream.done[run]
        np.testing.assert_array_equal(stream.values[:done, run], expected[:done])
        assert np.all(np.isinf(stream.values[done:, run]))
        whole = ErrorRateStream(horizon, samples)
        whole.add(t, z1[:, run])
        omegas = np.linspace(0.0, 1.0, 41).tolist()
        assert stream.rates(omegas, run=run) == whole.rates(omegas) == every[run]
        if run == 3:
            assert stream.rates((0.1,), run=3) == {"0.100": 1.0}
