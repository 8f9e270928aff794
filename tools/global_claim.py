"""How "global" is the proposed law in practice?

    python tools/global_claim.py [--dt 0.001] [--duration 10] [--examples example1 example2]
                                                 [--max-scale 1000] [--bisect 8]

For each example and each of eight directions d (the axes and the diagonals) the initial state
x0 = s d is scaled up (s = 0.5, 1, 2, 5, 10, ... up to --max-scale), then bisected between the last
scale that works and the first that fails. "Works" means what the theorem promises, on the ideal
ODE plant at the scenario's step: the run does not diverge (no NaN/Inf, |x_i| <= state_bound) and
max |e_zi| / L_zi <= 1 at every step. Then the comparison law (controller.kind = comparison) is run from
the largest working x0 and from the first failing one. One row per direction:

    example  direction  largest s that works  first s that fails  how the proposed law fails there
             baseline at the largest working s   baseline at the first failing s
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from qcontrol.assembly import run_scenario  # noqa: E402
from qcontrol.engine import Trajectory  # noqa: E402
from qcontrol.scenario import load_scenario  # noqa: E402

DIRECTIONS = [(1, 0), (0, 1), (1, 1), (1, -1), (-1, 0), (0, -1), (-1, -1), (-1, 1)]
GRID = [0.5, 1, 2, 3, 5, 10, 20, 50, 100, 200, 500, 1000, 2000, 5000, 1e4]
LEMMA2_TOLERANCE = 1e-9


@dataclass
class Outcome:
    ok: bool
    how: str  # "ok", "diverged at t = ...", "Lemma 2 ratio ..."
    max_abs_x: float
    max_abs_u: float


def run(example: str, x0: tuple[float, ...], dt: float, duration: float, kind: str = "proposed") -> Outcome:
    """One ODE run from ``x0``; ok when it stays bounded and Lemma 2 holds at every step."""
    overrides = [
        f"plant.x0=[{', '.join(repr(float(v)) for v in x0)}]",
        f"simulation.dt={dt!r}",
        f"simulation.duration={duration!r}",
        "simulation.backend='ode'",
    ]
    if kind != "proposed":
        overrides.append(f"controller.kind='{kind}'")
    sc = load_scenario(ROOT / "scenarios" / f"{example}.toml", overrides)
    traj: Trajectory = run_scenario(sc, "ode")
    with np.errstate(all="ignore"):
        rows = slice(None, -1) if traj.diverged else slice(None)  # the offending row is not a step it took
        ratio = float(np.nanmax(traj.e_z[rows] / traj.L_z)) if len(traj.e_z[rows]) else 0.0
        max_x = float(np.nanmax(np.abs(traj.x)))
        max_u = float(np.nanmax(np.abs(traj.u)))
    if traj.diverged:
        return Outcome(False, f"diverged at t = {traj.diverged_time:.4g} s", max_x, max_u)
    if not ratio <= 1 + LEMMA2_TOLERANCE:
        return Outcome(False, f"Lemma 2 ratio {ratio:.4g}", max_x, max_u)
    return Outcome(True, "ok", max_x, max_u)


def largest(example: str, d: tuple[int, int], dt: float, duration: float, max_scale: float,
            bisect: int) -> tuple[float, float, Outcome | None]:
    """(largest working scale, first failing scale or inf, the failing outcome)."""
    good, bad, failure = 0.0, math.inf, None
    for s in [s for s in GRID if s <= max_scale]:
        outcome = run(example, tuple(s * v for v in d), dt, duration)
        if outcome.ok:
            good = s
        else:
            bad, failure = s, outcome
            break
    if math.isfinite(bad):
        for _ in range(bisect):
            mid = math.sqrt(max(good, bad / 10) * bad) if good == 0 else 0.5 * (good + bad)
            outcome = run(example, tuple(mid * v for v in d), dt, duration)
            if outcome.ok:
                good = mid
            else:
                bad, failure = mid, outcome
    return good, bad, failure


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--dt", type=float, default=1e-3)
    parser.add_argument("--duration", type=float, default=10.0)
    parser.add_argument("--examples", nargs="+", default=["example1", "example2"])
    parser.add_argument("--max-scale", type=float, default=1000.0)
    parser.add_argument("--bisect", type=int, default=8)
    args = parser.parse_args(argv)
    started = time.perf_counter()
    print(f"ODE backend, dt = {args.dt:g} s, {args.duration:g} s runs; x0 = s * direction")
    print(f"{'example':9s} {'direction':>9s} {'largest s ok':>12s} {'first s fails':>13s}  "
          f"{'proposed at first fail':28s} {'comparison at largest ok':24s} {'comparison at first fail':24s}")
    for example in args.examples:
        for d in DIRECTIONS:
            good, bad, failure = largest(example, d, args.dt, args.duration, args.max_scale, args.bisect)
            baseline = []
            for s in (good, bad):
                if s > 0 and math.isfinite(s):
                    base = run(example, tuple(s * v for v in d), args.dt, args.duration, "comparison")
                    baseline.append("ok" if base.ok else base.how)
                else:
                    baseline.append("-")
            how = failure.how if failure is not None else "ok up to the grid's end"
            print(f"{example:9s} {str(d):>9s} {good:12.4g} {bad:13.4g}  {how:28s} {baseline[0]:24s} "
                  f"{baseline[1]:24s}", flush=True)
    print(f"({time.perf_counter() - started:.0f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
