"""Runs from several threads of one process: MuJoCo's passive callback and warning handler belong
to the whole process, so the plants take turns on them (``plants/mujoco/callbacks.py``'s lock).
Each concurrent ``qcontrol.run``, ``compare`` and ``sweep`` must give, bit for bit, what it gives
alone, and no callback may be left installed after the threads end."""

from __future__ import annotations

import json
import sys
import threading

import mujoco
import numpy as np
import pytest

import qcontrol
from qcontrol.assembly import build_plant

SHORT = {"simulation.duration": 0.15}


def _job(i: int) -> tuple:
    """Each thread's work: runs on both MuJoCo examples (Python and native callbacks), a comparison
    and a MuJoCo sweep; everything it returns must equal the serial run's."""
    name = ("example2", "example1", "example2-arm", "example1")[i % 4]
    sc = qcontrol.load_scenario(name, overrides=SHORT)
    if i % 4 == 2:
        c = qcontrol.compare(sc)
        return c.mujoco.x.tobytes(), c.ode.x.tobytes(), c.summary["max_abs_dx"]
    if i % 4 == 3:
        rows = qcontrol.sweep(sc, {"controller.kappa_margin": [0.1, 0.5]}, backend="mujoco")
        return (json.dumps(rows, sort_keys=True, default=str),)
    r = qcontrol.run(sc, "mujoco")
    return r.x.tobytes(), r.u.tobytes(), r.typed_summary.physics_warnings


def _in_threads(count: int) -> dict[int, object]:
    """``_job(i)`` for each i in its own thread, all started at once; an exception is a result."""
    results: dict[int, object] = {}
    start = threading.Barrier(count)

    def work(i: int) -> None:
        start.wait()
        try:
            results[i] = _job(i)
        except Exception as exc:  # a failure in a thread is a wrong result
            results[i] = exc

    threads = [threading.Thread(target=work, args=(i,)) for i in range(count)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    return results


@pytest.fixture
def short_switch_interval():
    before = sys.getswitchinterval()
    sys.setswitchinterval(1e-6)  # threads switch every few bytecodes: races show up
    yield
    sys.setswitchinterval(before)


def test_concurrent_runs_give_what_each_gives_alone(short_switch_interval):
    serial = [_job(i) for i in range(4)]
    for _ in range(3):  # trials
        results = _in_threads(4)
        for i in range(4):
            assert results[i] == serial[i], (i, results[i] if isinstance(results[i], Exception) else "differ")
        assert mujoco.get_mjcb_passive() is None  # nothing left installed
        assert mujoco.get_mju_user_warning() is None


def test_a_run_waits_while_another_threads_plant_holds_the_callback():
    """While one thread's plant is open (its passive callback installed), another thread's MuJoCo
    run does not step under that callback: it starts when the plant closes, with its own."""
    sc = qcontrol.load_scenario("example2", overrides=SHORT)
    alone = qcontrol.run(sc, "mujoco").x
    plant = build_plant(qcontrol.load_scenario("example1", overrides=SHORT), "mujoco")
    opened, release, finished = threading.Event(), threading.Event(), threading.Event()
    got: list[np.ndarray] = []

    def hold() -> None:
        with plant:
            opened.set()
            release.wait(timeout=60)

    def other() -> None:
        got.append(qcontrol.run(sc, "mujoco").x)
        finished.set()

    holder = threading.Thread(target=hold)
    holder.start()
    opened.wait(timeout=60)
    runner = threading.Thread(target=other)
    runner.start()
    ran_while_open = finished.wait(timeout=1.0)  # not a timing assertion: it must not happen at all
    release.set()
    holder.join()
    runner.join()
    assert not ran_while_open
    assert np.array_equal(got[0], alone)
    assert mujoco.get_mjcb_passive() is None
