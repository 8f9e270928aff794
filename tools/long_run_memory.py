"""Peak memory of a long run: 120 s of Example 2 at dt = 1e-4 s (10 kHz), ODE backend.

    python tools/long_run_memory.py [--duration 120] [--dt 1e-4] [--no-rrd]

Each case runs ``qcontrol run`` in its own process and reads that process's peak resident set
size (``ru_maxrss`` from ``os.wait4``): a short run (0.1 s: interpreter, numpy, MuJoCo and, with a
recording, rerun), the long run, and the long run with a ``.rrd`` recording. The difference between
the long and the short run is what the run itself holds. The table also gives what the engine's
arrays should take (every row kept in memory: t, y_d and derivatives, x, x_meas, x_q, z, zbar,
e_z, u and the adaptive state) and what streaming in 2000-row chunks would hold instead.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SCENARIO = ROOT / "scenarios" / "example2.toml"
CHUNK = 2000  # rows per streamed chunk (the engine's observe_every)


def peak_rss(args: list[str], cwd: Path) -> tuple[float, float, int]:
    """Run ``qcontrol`` with ``args`` in a child process: (peak RSS in MiB, wall time in s, status)."""
    started = time.perf_counter()
    proc = subprocess.Popen(
        [sys.executable, "-m", "qcontrol.cli", *args],
        cwd=cwd,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
    )
    _, status, usage = os.wait4(proc.pid, 0)
    proc.returncode = os.waitstatus_to_exitcode(status)
    err = proc.stderr.read().decode() if proc.stderr else ""
    if proc.returncode not in (0, 1):
        raise SystemExit(f"qcontrol {' '.join(args)} failed ({proc.returncode}): {err}")
    return usage.ru_maxrss / 1024.0, time.perf_counter() - started, proc.returncode


def engine_bytes(rows: int, n: int = 2, adaptive: int = 3) -> int:
    """Bytes of the engine's per-row float64 arrays for one run (see qcontrol.sim.simulate)."""
    per_row = (1 + (n + 1) + 6 * n + 1 + adaptive) * 8  # t, yd, x/xm/xq/z/zbar/e_z, u, adaptive
    return rows * per_row


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--duration", type=float, default=120.0)
    parser.add_argument("--dt", type=float, default=1e-4)
    parser.add_argument("--no-rrd", action="store_true", help="skip the recorded run")
    args = parser.parse_args(argv)
    rows = round(args.duration / args.dt) + 1
    common = ["run", str(SCENARIO), "--backend", "ode", "--dt", repr(args.dt), "-q"]
    with tempfile.TemporaryDirectory(prefix="qcontrol-mem-") as tmp:
        env_tmp = Path(tmp)
        os.environ["HOME"] = tmp  # rerun writes analytics under HOME
        os.environ.setdefault("RERUN_TELEMETRY_ENABLED", "false")
        results = []
        short, _, _ = peak_rss([*common, "--duration", "0.1"], env_tmp)
        results.append(("short run (0.1 s): imports only", short, None, None))
        long_, wall, status = peak_rss([*common, "--duration", repr(args.duration)], env_tmp)
        results.append((f"{args.duration:g} s at dt = {args.dt:g} ({rows - 1:,} steps)", long_, wall, status))
        if not args.no_rrd:
            rrd = env_tmp / "long.rrd"
            short_rrd, _, _ = peak_rss(
                [*common, "--duration", "0.1", "--rrd", str(env_tmp / "s.rrd")], env_tmp
            )
            results.append(("short run with --rrd", short_rrd, None, None))
            rec, wall_r, status_r = peak_rss(
                [*common, "--duration", repr(args.duration), "--rrd", str(rrd)], env_tmp
            )
            size = rrd.stat().st_size / 2**20 if rrd.exists() else float("nan")
            results.append((f"the same with --rrd ({size:.0f} MiB file)", rec, wall_r, status_r))
    print(f"{'case':52s} {'peak RSS MiB':>12s} {'wall s':>8s} {'exit':>5s}")
    for label, mib, wall, status in results:
        print(
            f"{label:52s} {mib:12.0f} {'' if wall is None else f'{wall:8.1f}':>8s} "
            f"{'' if status is None else status:>5}"
        )
    held = engine_bytes(rows) / 2**20
    print(f"\nengine arrays, every row kept: {held:.0f} MiB expected ({engine_bytes(1)} bytes a row, n = 2)")
    print(f"long run - short run: {long_ - short:.0f} MiB measured")
    print(
        f"streaming {CHUNK}-row chunks would hold {engine_bytes(CHUNK) / 2**20:.2f} MiB of rows instead "
        f"(plus what the metrics keep: z1 and the running maxima)"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
