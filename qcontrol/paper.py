"""The paper's published numbers our outputs are compared with: Table 1's error rates on Example 2,
and the row of Table 1 a run of each controller kind is compared with."""

from __future__ import annotations

from .metrics import TABLE1_OMEGAS, omega_key

OMEGA_KEYS = [omega_key(w) for w in TABLE1_OMEGAS]
PAPER_HORIZON = 10.0  # s: the paper's runs (Table 1's 1302 samples); other horizons are not compared

# Sun et al. (2022), Table 1: error rate E(omega) on Example 2 (M = 1302 samples over T = 10 s).
PAPER_TABLE1: dict[str, dict[str, float]] = {
    "proposed": dict(zip(OMEGA_KEYS, (0.0253, 0.0223, 0.0200, 0.0177, 0.0161), strict=True)),
    "comparison": dict(zip(OMEGA_KEYS, (0.9570, 0.9339, 0.9132, 0.8925, 0.8679), strict=True)),
}
METHOD_LABELS = {"proposed": "proposed (44)-(45)", "comparison": "comparison [20], eq. (46)"}
# The row of Table 1 that a run of each controller kind is compared with.
PAPER_TABLE1_ROWS = {"proposed": "proposed", "comparison": "comparison"}
