"""What the benchmark scripts share: best-of-N timing, and a block on the engine's Python loop."""

from __future__ import annotations

import os
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager


def best_of(repeat: int, fn: Callable[[], object]) -> float:
    """The shortest of ``repeat`` wall times of ``fn()`` (the machine may be shared)."""
    best = float("inf")
    for _ in range(repeat):
        start = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - start)
    return best


def best_of_both(repeat: int, fn: Callable[[], object]) -> tuple[float, float]:
    """The shortest wall time and the shortest CPU time (this process) of ``repeat`` runs of ``fn()``."""
    wall = cpu = float("inf")
    for _ in range(repeat):
        start, start_cpu = time.perf_counter(), time.process_time()
        fn()
        wall, cpu = min(wall, time.perf_counter() - start), min(cpu, time.process_time() - start_cpu)
    return wall, cpu


@contextmanager
def python_loop() -> Iterator[None]:
    """``QCONTROL_COMPILE=0`` inside the block: runs and plants made there use the Python paths
    (the compiled loop serves only built-in laws anyway)."""
    saved = os.environ.get("QCONTROL_COMPILE")
    os.environ["QCONTROL_COMPILE"] = "0"
    try:
        yield
    finally:
        if saved is None:
            del os.environ["QCONTROL_COMPILE"]
        else:
            os.environ["QCONTROL_COMPILE"] = saved
