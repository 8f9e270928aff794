"""Outputs that never destroy data: every case of the output guarantees (docs/reliability.md).

Devices are made with ``mknod`` and a full disk is a 64 KiB tmpfs when the tests run as root
(skipped otherwise, with the reason); the same write errors are also injected into the writer, so
every machine checks ENOSPC, EIO and EACCES. Runs are short (0.05-0.5 s simulated).
"""

from __future__ import annotations

import errno
import json
import os
import pty
import signal
import socket
import stat
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
from conftest import (
    EX2,
    ROOT,
    busy,
    children_of,
    drain_terminal,
    forks_of,
    process_fields,
    progress_past_zero,
)

import qcontrol
from qcontrol import outputs
from qcontrol.cli import main
from qcontrol.errors import QcontrolInputError, QcontrolOutputError
from qcontrol.outputs import AtomicFile, partial_path, write_json, write_text
from qcontrol.recording.rrd_file import rrd_problem
from qcontrol.scenario import load_scenario
from qcontrol.sweep.grid import parse_grid
from qcontrol.workers import worker_count

SHORT = ["--backend", "ode", "--duration", "0.05", "-q"]
ROOT_ONLY = pytest.mark.skipif(os.geteuid() != 0, reason="mknod and mount need root; the injected "
                               "write errors below cover the same paths")


def _temporaries(folder: Path) -> list[Path]:
    return [p for p in folder.rglob("*") if p.name.endswith((".tmp", ".part"))]


def _one_line(capsys: pytest.CaptureFixture[str], *expected: str) -> str:
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1, err
    for text in expected:
        assert text in err, err
    assert "Traceback" not in err and "\x1b[" not in err  # no traceback, no coloured log line
    return err


def _cli(*args: str, cwd: Path, timeout: float = 120) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "qcontrol.cli", *args], cwd=cwd, capture_output=True,
                          text=True, timeout=timeout, env={**os.environ, "HOME": str(cwd)})


def _run_here(capfd: pytest.CaptureFixture[str], *args: str) -> subprocess.CompletedProcess:
    """``qcontrol ARGS`` in this process: its exit status and what reached file descriptors 1 and 2
    (a library's own lines included). For a write that involves no recording: the rerun SDK's
    lines come from its threads and its flush at exit, which only a process of its own shows."""
    capfd.readouterr()
    status = main(list(args))
    out, err = capfd.readouterr()
    return subprocess.CompletedProcess(args, status, out, err)


# --------------------------------------------------------------------------------------------
# 1. regular files only, refused before the run


def _special(tmp_path: Path, kind: str) -> Path:
    path = tmp_path / f"special-{kind}"
    if kind == "device":
        os.mknod(path, stat.S_IFCHR | 0o666, os.makedev(1, 3))  # a copy of /dev/null
    elif kind == "fifo":
        os.mkfifo(path)
    elif kind == "socket":
        sock = socket.socket(socket.AF_UNIX)
        sock.bind(str(path))
        sock.close()
    else:
        path.mkdir()
    return path


@ROOT_ONLY
@pytest.mark.parametrize("kind, words", [("device", "a character device"), ("fifo", "a FIFO"),
                                         ("socket", "a socket"), ("folder", "a folder")])
@pytest.mark.parametrize("option", ["--rrd", "--save", "--plot"])
def test_a_special_file_at_an_output_name_is_refused_and_kept(tmp_path, capsys, kind, words, option):
    path = _special(tmp_path, kind)
    target = path.with_suffix(".png" if option == "--plot" else ".npz" if option == "--save" else ".rrd")
    path.rename(target)
    before = os.lstat(target)
    assert main(["run", str(EX2), *SHORT, option, str(target)]) == 2
    _one_line(capsys, option, words, "not a regular file", f"such as run{target.suffix}")
    after = os.lstat(target)
    assert (after.st_mode, after.st_ino, after.st_rdev) == (before.st_mode, before.st_ino, before.st_rdev)
    assert not _temporaries(tmp_path)


@ROOT_ONLY
def test_dev_null_is_never_replaced(capsys):
    before = os.stat("/dev/null")
    assert main(["run", str(EX2), *SHORT, "--rrd", "/dev/null"]) == 2
    _one_line(capsys, "--rrd /dev/null: is a character device")
    after = os.stat("/dev/null")
    assert stat.S_ISCHR(after.st_mode) and after.st_rdev == before.st_rdev


@ROOT_ONLY
def test_out_with_a_device_as_summary_json(tmp_path, capsys):
    out = tmp_path / "out"
    out.mkdir()
    os.mknod(out / "summary.json", stat.S_IFCHR | 0o666, os.makedev(1, 3))
    assert main(["run", str(EX2), *SHORT, "--out", str(out)]) == 2
    _one_line(capsys, "summary.json: is a character device")
    assert stat.S_ISCHR(os.lstat(out / "summary.json").st_mode)


def test_a_link_loop_is_named(tmp_path, capsys):
    (tmp_path / "a.rrd").symlink_to(tmp_path / "b.rrd")
    (tmp_path / "b.rrd").symlink_to(tmp_path / "a.rrd")
    assert main(["run", str(EX2), *SHORT, "--rrd", str(tmp_path / "a.rrd")]) == 2
    _one_line(capsys, "a symbolic link loop")


def test_temporaries_are_unique_exclusive_and_never_follow_a_link(tmp_path, monkeypatch):
    """A user's file at the old fixed name (r.rrd.part) is never touched; a link planted at the
    temporary name is not written through: the name is taken, another one is made."""
    theirs = tmp_path / "r.rrd.part"
    theirs.write_text("the user's own file\n")
    victim = tmp_path / "victim.txt"
    victim.write_text("not qcontrol's\n")
    names = iter(["planted", "planted", "fresh"])
    monkeypatch.setattr(outputs.secrets, "token_hex", lambda n: next(names))
    (tmp_path / ".result.json.planted.tmp").symlink_to(victim)
    write_json(tmp_path / "result.json", {"ok": 1})
    monkeypatch.undo()
    assert victim.read_text() == "not qcontrol's\n"
    assert json.loads((tmp_path / "result.json").read_text()) == {"ok": 1}
    assert (tmp_path / ".result.json.planted.tmp").is_symlink()  # not ours: left alone
    assert theirs.read_text() == "the user's own file\n"
    assert main(["run", str(EX2), *SHORT, "--rrd", str(tmp_path / "r.rrd")]) == 0
    assert theirs.read_text() == "the user's own file\n"
    assert rrd_problem(tmp_path / "r.rrd") is None


def test_files_are_fsynced_before_they_are_moved(tmp_path, monkeypatch):
    synced: list[int] = []
    real = os.fsync
    monkeypatch.setattr(outputs.os, "fsync", lambda fd: (synced.append(fd), real(fd))[1])
    write_text(tmp_path / "a.txt", "x")
    assert synced


def test_two_runs_at_once_into_one_recording_both_verify(tmp_path):
    """Two runs with the same --rrd at once: each writes its own temporary; the file under the
    final name is one whole recording (the last one moved)."""
    rrd = tmp_path / "r.rrd"
    argv = [sys.executable, "-m", "qcontrol.cli", "run", str(EX2), "--backend", "ode", "--duration", "0.5",
            "-q", "--rrd", str(rrd)]
    env = {**os.environ, "HOME": str(tmp_path)}
    procs = [subprocess.Popen(argv, cwd=tmp_path, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                              text=True) for _ in range(2)]
    for proc in procs:
        _, err = proc.communicate(timeout=120)
        assert proc.returncode == 0, err
    assert rrd_problem(rrd) is None
    assert not _temporaries(tmp_path)


# --------------------------------------------------------------------------------------------
# 2. write errors are errors: exit 3, one line, the previous file intact


def test_a_full_disk_keeps_the_previous_recording(small_disk, tmp_path):
    old = small_disk / "r.rrd"
    old.write_bytes(b"a previous complete recording" * 500)
    before = old.read_bytes()
    proc = _cli("run", str(EX2), "--backend", "ode", "--duration", "2", "-q", "--rrd", str(old), cwd=tmp_path)
    assert proc.returncode == 3, proc.stderr
    err = proc.stderr.strip()
    assert len(err.splitlines()) == 1 and "no space left" in err and "r.partial.rrd" in err, err
    assert "\x1b[" not in err and "ERROR" not in err  # rerun's own log lines are not shown
    assert "wrote" not in proc.stdout
    assert old.read_bytes() == before
    assert (small_disk / "r.partial.rrd").stat().st_size > 0  # what was recorded, under its partial name
    assert not _temporaries(small_disk)


@pytest.mark.filterwarnings("ignore:RRD file has no footer")  # the file given up on is read as it is
@pytest.mark.parametrize("disk_full, cause", [(True, "no space left on the device"),
                                              (False, "rerun's writer took nothing for 0.05 s")])
def test_a_sink_that_never_answers_ends_the_recording(tmp_path, monkeypatch, disk_full, cause):
    """rerun's file sink whose writer died on a write error (a full disk) while a flush was queued
    behind the failed write never answers that flush (nor any later flush or close of the stream):
    rerun's flush then only returns at its timeout, as simulated here. The run still ends, with one
    error naming the cause; the previous file is kept, nothing half-written replaces it, and the
    stream is never touched again (rerun's exit hook, which would close it, is turned off). A full
    disk gives up at the first slice without progress; otherwise after the stall limit. A flush
    that waited without bound would leave the worker thread running at the join below."""
    from qcontrol.recording import recording as recording_module
    from qcontrol.recording.rrd_file import RrdFile

    rr = pytest.importorskip("rerun")
    never = threading.Event()

    def unanswered(self, *, timeout_sec=1e38):
        if timeout_sec:  # rerun waits until its timeout, then raises
            never.wait(min(timeout_sec, 3600.0))
            raise RuntimeError("Flush timed out - not all log messages were sent.")

    turned_off: list[int] = []
    monkeypatch.setattr(rr.RecordingStream, "flush", unanswered)
    monkeypatch.setattr(rr, "unregister_shutdown", lambda: turned_off.append(1))
    monkeypatch.setattr(recording_module, "FLUSH_SLICE", 0.01)
    monkeypatch.setattr(recording_module, "FLUSH_STALL", 3600.0 if disk_full else 0.05)
    monkeypatch.setattr(RrdFile, "space_left", lambda self: not disk_full)
    monkeypatch.setenv("QCONTROL_COMPILE", "0")
    old = tmp_path / "r.rrd"
    old.write_bytes(b"previous")
    sc = load_scenario(EX2, {"simulation.duration": 0.2})
    raised: list[BaseException] = []
    worker = threading.Thread(target=lambda: _catch(raised, qcontrol.run, sc, "ode", rrd=old), daemon=True)
    worker.start()
    worker.join(20)
    never.set()  # a worker still waiting ends now
    assert not worker.is_alive(), "the recording waited on a sink that never answers"
    assert len(raised) == 1 and isinstance(raised[0], QcontrolOutputError), raised
    message = str(raised[0])
    assert f"cannot write the recording ({cause})" in message and "r.rrd is unchanged" in message, message
    assert "\n" not in message
    assert old.read_bytes() == b"previous"
    assert turned_off == [1]
    assert not _temporaries(tmp_path)


def _catch(raised: list[BaseException], call, *args, **kwargs) -> None:
    try:
        call(*args, **kwargs)
    except BaseException as exc:  # the test's thread reports what the run raised
        raised.append(exc)


@pytest.mark.parametrize("option, name", [("--save", "x.npz"), ("--save", "x.csv"), ("--plot", "x.png"),
                                          ("--out", "o")])
def test_a_full_disk_for_each_format(small_disk, capfd, option, name):
    (small_disk / "ballast").write_bytes(b"\0" * 40_000)
    target = small_disk / name
    if option == "--out":
        target.mkdir()
        (target / "summary.json").write_text('{"previous": true}\n')
        (small_disk / "more").write_bytes(b"\0" * 20_000)
    else:
        target.write_bytes(b"previous")
    proc = _run_here(capfd, "run", str(EX2), "--backend", "ode", "--duration", "1", "-q", option, str(target))
    assert proc.returncode == 3, proc.stderr
    err = proc.stderr.strip()
    assert len(err.splitlines()) == 1 and "no space left" in err, err
    if option == "--out":
        assert (target / "summary.json").read_text() == '{"previous": true}\n'
    else:
        assert target.read_bytes() == b"previous"
    assert not _temporaries(small_disk)


@pytest.mark.parametrize("code, words", [(errno.ENOSPC, "no space left"), (errno.EIO, "input/output error"),
                                         (errno.EACCES, "ermission denied")])
def test_injected_write_errors(tmp_path, capsys, monkeypatch, code, words):
    """The writer fails as a full disk, a failing disk or a revoked permission would: exit 3, one
    line naming the file and the cause, the previous file as it was, no temporary left."""
    out = tmp_path / "out"
    out.mkdir()
    (out / "summary.json").write_text('{"previous": true}\n')

    def failing(fd: int) -> None:
        raise OSError(code, os.strerror(code))

    monkeypatch.setattr(outputs.os, "fsync", failing)
    assert main(["run", str(EX2), *SHORT, "--out", str(out)]) == 3
    _one_line(capsys, "summary.json", words, "nothing was replaced")
    assert (out / "summary.json").read_text() == '{"previous": true}\n'
    assert not _temporaries(tmp_path)


def test_exit_statuses_are_documented():
    from qcontrol.cli.dispatch import build_parser

    text = " ".join(build_parser().format_help().split())
    assert "3 an output could not be written" in text and "4 a control law written in Python failed" in text
    assert "QCONTROL_DEBUG=1" in text and "143 terminated" in text
    readme = (ROOT / "README.md").read_text()
    assert all(f"| {code} |" in readme for code in (0, 1, 2, 3, 4, 130, 143))


# --------------------------------------------------------------------------------------------
# 3. an interrupted run never replaces a complete output


def _interrupted(tmp_path: Path, argv: list[str], sig: int) -> subprocess.CompletedProcess:
    """``qcontrol argv`` sent ``sig`` once its loop runs (its progress, on a pseudo-terminal, past
    0 %): its exit status and what it printed on stderr."""
    master, terminal = pty.openpty()
    proc = subprocess.Popen([sys.executable, "-m", "qcontrol.cli", *argv], cwd=tmp_path, text=True,
                            stdout=subprocess.DEVNULL, stderr=terminal,
                            # the Python loop: this is about the outputs, and a compiled 600 s ODE run can
                            # end before the signal lands (its own tests interrupt it)
                            env={**os.environ, "HOME": str(tmp_path), "QCONTROL_COMPILE": "0"},
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    os.close(terminal)
    try:
        shown = progress_past_zero(master, proc)
        assert proc.poll() is None, proc.communicate()
        proc.send_signal(sig)
        proc.wait(timeout=20)
        return subprocess.CompletedProcess(proc.args, proc.returncode, "", shown + drain_terminal(master))
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        os.close(master)


@pytest.mark.parametrize("sig, status", [(signal.SIGINT, 130), (signal.SIGTERM, 143)])
def test_an_interrupted_recording_keeps_the_complete_one(tmp_path, sig, status):
    rrd = tmp_path / "r.rrd"
    assert main(["run", str(EX2), *SHORT, "--rrd", str(rrd)]) == 0
    before = rrd.read_bytes()
    argv = ["run", str(EX2), "--backend", "ode", "--duration", "600", "--rrd", str(rrd)]
    proc = _interrupted(tmp_path, argv, sig)
    assert proc.returncode == status, proc.stderr
    assert "Traceback" not in proc.stderr and "r.partial.rrd" in proc.stderr
    assert rrd.read_bytes() == before
    assert rrd_problem(partial_path(rrd)) is None  # the partial one reads back too
    assert not _temporaries(tmp_path)


def test_an_interrupted_sweep_leaves_the_complete_one(tmp_path, ctrl_c_on_second_chunk):
    out = tmp_path / "sw"
    grid = ["--grid", "controller.gamma=1,2,3", "--set", "simulation.duration=0.05", "--backend", "ode", "-q",
            "--out", str(out)]
    assert main(["sweep", str(EX2), *grid]) == 0
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    ctrl_c_on_second_chunk()
    assert main(["sweep", str(EX2), *grid]) == 130
    assert {p.name: p.read_bytes() for p in out.iterdir() if p.name in before} == before
    record = json.loads((out / "sweep.partial.json").read_text())
    assert record["interrupted"] and record["runs_finished"] == 1 and record["csv"] == "sweep.partial.csv"
    assert not _temporaries(tmp_path)


def test_a_staged_set_is_all_or_nothing(tmp_path):
    for name in ("a.json", "b.json"):
        write_json(tmp_path / name, {"old": name})
    with pytest.raises(KeyboardInterrupt), outputs.staged():
        write_json(tmp_path / "a.json", {"new": 1})
        raise KeyboardInterrupt
    assert json.loads((tmp_path / "a.json").read_text()) == {"old": "a.json"}
    (tmp_path / "c.json").mkdir()  # in the way of the third file: none of the three is moved
    with pytest.raises(QcontrolOutputError, match="none of the new files"), outputs.staged():
        write_json(tmp_path / "a.json", {"new": 1})
        write_json(tmp_path / "b.json", {"new": 2})
        write_json(tmp_path / "c.json", {"new": 3})
    assert json.loads((tmp_path / "a.json").read_text()) == {"old": "a.json"}
    assert json.loads((tmp_path / "b.json").read_text()) == {"old": "b.json"}
    with outputs.staged():
        write_json(tmp_path / "a.json", {"new": 1})
        write_json(tmp_path / "b.json", {"new": 2})
        assert json.loads((tmp_path / "a.json").read_text()) == {"old": "a.json"}  # not yet
    assert json.loads((tmp_path / "b.json").read_text()) == {"new": 2}
    assert not _temporaries(tmp_path)


def test_an_atomic_file_discarded_leaves_nothing(tmp_path):
    file = AtomicFile(tmp_path / "x.bin")
    assert file.temporary.exists()
    file.discard()
    assert list(tmp_path.iterdir()) == []


# --------------------------------------------------------------------------------------------
# 4. output clashes are input errors, before the run


@pytest.mark.parametrize("args, words", [
    (["--rrd", "a.npz", "--save", "a.npz"], "the same file as --rrd"),
    (["--save", "a.csv", "--plot", "a.csv"], "unknown figure format '.csv'"),
    (["--plot", "a.jpg"], "unknown figure format '.jpg'"),
    (["--out", "x", "--rrd", "x"], "the folder would be where --rrd x is written"),
    (["--out", "o", "--rrd", "o/summary.json"], "the same file as --rrd o/summary.json"),
    (["--rrd", "scenario.toml"], "is the scenario file"),
])
def test_clashing_outputs_are_refused_before_the_run(tmp_path, capsys, monkeypatch, args, words):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "scenario.toml").write_text(EX2.read_text().replace('"../models/', f'"{ROOT}/models/'))
    before = (tmp_path / "scenario.toml").read_text()
    assert main(["run", "scenario.toml", *SHORT, *args]) == 2
    _one_line(capsys, words)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["scenario.toml"]
    assert (tmp_path / "scenario.toml").read_text() == before


def test_a_summary_json_folder_is_refused_before_the_run(tmp_path, capsys):
    (tmp_path / "o" / "summary.json").mkdir(parents=True)
    assert main(["run", str(EX2), *SHORT, "--out", str(tmp_path / "o")]) == 2
    _one_line(capsys, "summary.json: is a folder")


def test_a_sweep_png_folder_is_refused_before_the_run(tmp_path, capsys):
    (tmp_path / "sw" / "sweep.png").mkdir(parents=True)
    argv = ["sweep", str(EX2), "--grid", "controller.gamma=1,2", "--backend", "ode", "-q", "--out",
            str(tmp_path / "sw")]
    assert main(argv) == 2
    _one_line(capsys, "sweep.png: is a folder")
    assert [p.name for p in (tmp_path / "sw").iterdir()] == ["sweep.png"]


@pytest.mark.parametrize("suffix, magic", [(".pdf", b"%PDF"), (".svg", b"<?xml"), (".png", b"\x89PNG")])
def test_a_figure_is_written_in_the_format_its_name_says(tmp_path, suffix, magic):
    path = tmp_path / f"run{suffix}"
    assert main(["run", str(EX2), *SHORT, "--plot", str(path)]) == 0
    assert path.read_bytes().startswith(magic)


# --------------------------------------------------------------------------------------------
# 5. workers die with their parent


def _alive(pid: int) -> bool:
    fields = process_fields(pid)
    return fields is not None and fields[0] != "Z"


def _outliving(workers: list[int], seconds: float = 2.0) -> list[int]:
    """The workers still alive ``seconds`` after their parent ended (asked until then: a test
    whose workers are gone at once goes on at once)."""
    deadline = time.monotonic() + seconds
    while (alive := [w for w in workers if _alive(w)]) and time.monotonic() < deadline:
        time.sleep(0.05)
    return alive


@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="reads the process table from /proc")
@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGKILL, signal.SIGINT])
def test_workers_die_with_their_parent(tmp_path, sig):
    argv = [sys.executable, "-m", "qcontrol.cli", "sweep", str(EX2), "--grid",
            "controller.c=[4.0, 3.0],[5.0, 3.0]", "--set", "simulation.duration=600", "--backend", "ode",
            "--workers", "2", "-q", "--out", str(tmp_path / "sw")]
    proc = subprocess.Popen(argv, cwd=tmp_path, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                            env={**os.environ, "HOME": str(tmp_path)},
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    try:
        deadline = time.monotonic() + 60
        workers: list[int] = []
        while not workers and time.monotonic() < deadline:  # (two workers: this process and a fork)
            workers = forks_of(proc.pid)
            time.sleep(0.02)
        assert len(workers) == 1, "the sweep did not fork its second worker"
        assert busy(workers[0]), "the forked worker never ran"
        proc.send_signal(sig)
        proc.wait(timeout=20)
        assert not _outliving(workers), "a worker outlived its parent"
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        for w in children_of(proc.pid):
            os.kill(w, signal.SIGKILL)


@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="reads the process table from /proc")
def test_reproduces_workers_die_with_it(tmp_path):
    """``qcontrol reproduce`` itself, killed with SIGTERM and with SIGKILL while its robustness study
    runs on two workers: no worker is left 2 s later. The two reproductions run at once (each
    reaches its workers after its examples and studies; the examples on the ODE only, as the
    workers are the study's whatever the examples' backend). Its 0.5 s runs are short (the study's
    248 of them still keep both workers busy for a while), so this pins the contract for the
    command; that a worker busy with a long run dies at once is shown by the sweep's test above
    (600 s runs)."""
    procs = {}
    for sig in (signal.SIGTERM, signal.SIGKILL):
        argv = [sys.executable, "-m", "qcontrol.cli", "reproduce", "--duration", "0.5", "--workers", "2",
                "-q", "--backend", "ode", "--out", str(tmp_path / sig.name)]
        procs[sig] = subprocess.Popen(argv, cwd=tmp_path, stdout=subprocess.DEVNULL,
                                      stderr=subprocess.DEVNULL, env={**os.environ, "HOME": str(tmp_path)})
    try:
        workers: dict[signal.Signals, list[int]] = {}
        deadline = time.monotonic() + 240
        while len(workers) < len(procs) and time.monotonic() < deadline:
            for sig, proc in procs.items():  # each signalled as soon as its two workers run
                found = [] if sig in workers else forks_of(proc.pid)
                if len(found) == 2:
                    workers[sig] = found
                    proc.send_signal(sig)
            time.sleep(0.1)
        assert sorted(workers) == sorted(procs), "reproduce did not start its two workers"
        for proc in procs.values():
            proc.wait(timeout=20)
        left = _outliving([w for sig in procs for w in workers[sig]])
        for sig in procs:
            assert not set(workers[sig]) & set(left), f"a worker outlived reproduce ({sig.name})"
    finally:
        for proc in procs.values():
            if proc.poll() is None:
                proc.kill()
                proc.wait()
            for w in children_of(proc.pid):
                os.kill(w, signal.SIGKILL)


def test_workers_are_capped_at_the_work_and_the_cores():
    cores = os.cpu_count() or 1
    assert worker_count(64, 1000) == cores
    assert worker_count(64, 3) == min(3, cores)
    assert worker_count(1, 1000) == 1


# --------------------------------------------------------------------------------------------
# 6. bounds, refused at load: check and run agree


BIG = "1" + "0" * 400


@pytest.mark.parametrize("overrides, words", [
    (["metrics.samples=100000000000"], "--set metrics.samples=100000000000: must be at most"),
    ([f"controller.proposed.gamma={BIG}"], "an integer of 401 digits is beyond the limit 2**63 - 1"),
    ([f"plant.x0=[{BIG}, 0.0]"], "plant.x0[0]: an integer of 401 digits is beyond"),
    (['disturbance=[{kind = "step", start = 1e306, value = 1.0}]'], "disturbance[0].start: must be at most"),
    (["plant.x0=[" + ", ".join(["0.0"] * 100_001) + "]"], "more than 100000"),
])
def test_bounds_are_refused_by_check_and_run_alike(capsys, overrides, words):
    sets = [a for o in overrides for a in ("--set", o)]
    assert main(["check", str(EX2), *sets]) == 2
    first = _one_line(capsys, words)
    assert main(["run", str(EX2), *SHORT, *sets]) == 2
    assert _one_line(capsys, words) == first
    assert first.startswith("qcontrol: error: --set ")  # the command line is named, not the file
    assert BIG not in first and len(first) < 400  # a long literal is not echoed back whole


def test_bounds_in_a_file_and_in_an_api_dict(tmp_path):
    for depth in (12, 500):  # deeper than any key takes; deep enough for a recursive reader to fail
        deep = tmp_path / f"deep{depth}.toml"
        deep.write_text(EX2.read_text() + "\n[extra]\nx = " + "[" * depth + "]" * depth + "\n")
        with pytest.raises(QcontrolInputError, match="nested"):
            load_scenario(deep)
    with pytest.raises(QcontrolInputError, match=r"^override plant.x0=\[1000.*: plant.x0\[0\]: an integer "
                       "of 401 digits is beyond the limit") as refused:
        qcontrol.load_scenario(EX2, {"plant.x0": [10**400, 0.0]})
    assert BIG not in str(refused.value)
    (tmp_path / "big.toml").write_text(EX2.read_text().replace("x0 = [", f"x0 = [{BIG}, ", 1).replace(
        '"qcontrol:models/', f'"{ROOT}/models/'))
    with pytest.raises(QcontrolInputError, match="big.toml: plant.x0") as refused:
        load_scenario(tmp_path / "big.toml")  # a file's value names the file
    assert BIG not in str(refused.value)


def test_sweep_size_and_seed_are_bounded(capsys):
    assert main(["sweep", str(EX2), "--random-initial", str(10**12), "-q"]) == 2
    _one_line(capsys, "more than the 1000000 a sweep may make")
    assert main(["sweep", str(EX2), "--random-initial", "2", "--seed", "-1", "-q"]) == 2
    _one_line(capsys, "--seed -1: must be an integer from 0")


@pytest.mark.parametrize("option", ["--out", "--rrd", "--save"])
def test_an_over_long_name_is_one_line(capsys, option):
    name = "a" * 300 + (".npz" if option == "--save" else "")
    assert main(["run", str(EX2), *SHORT, option, name]) == 2
    _one_line(capsys, option, "longer than the 255")


def test_an_over_long_scenario_name_and_model_paths(tmp_path, capsys):
    assert main(["check", "a" * 300 + ".toml"]) == 2
    _one_line(capsys, "longer than the 255")
    assert main(["check", str(EX2), "--set", 'plant.mujoco.model="a\\u0000b.xml"']) == 2
    _one_line(capsys, "NUL byte")
    assert main(["check", str(EX2), "--set", f'plant.mujoco.model="{"m" * 300}.xml"']) == 2
    _one_line(capsys, "longer than the 255")


def test_an_mjcf_include_that_is_a_fifo_is_refused(tmp_path, capsys):
    os.mkfifo(tmp_path / "part.xml")
    model = (ROOT / "models" / "pendulum.xml").read_text().replace("<worldbody>", '<include file="part.xml"/>'
                                                                   "<worldbody>", 1)
    (tmp_path / "model.xml").write_text(model)
    started = time.monotonic()
    assert main(["check", str(EX2), "--set", f'plant.mujoco.model="{tmp_path / "model.xml"}"']) == 2
    _one_line(capsys, "part.xml", "a FIFO")
    assert time.monotonic() - started < 30


# --------------------------------------------------------------------------------------------
# 7. sweep edge cases


def test_a_sweep_without_a_grid_is_a_clear_error(tmp_path, capsys):
    assert main(["sweep", str(EX2), "-q", "--out", str(tmp_path / "sw")]) == 2
    _one_line(capsys, "nothing to sweep", "--random-initial")
    assert not (tmp_path / "sw").exists()
    argv = ["sweep", str(EX2), "--random-initial", "2", "--set", "simulation.duration=0.05", "--backend",
            "ode", "-q", "--out", str(tmp_path / "sw")]
    assert main(argv) == 0  # no grid, N initial states: the documented form
    assert len((tmp_path / "sw" / "sweep.csv").read_text().splitlines()) == 3


@pytest.mark.parametrize("grid, words", [("controller.gamma=1],2", "closes nothing"),
                                         ("controller.gamma=[1", "unclosed bracket"),
                                         ('plant.psi="x1', "unclosed quote"),
                                         ("plant.x0=[1, 2],[x]", "does not parse")])
def test_a_grid_value_that_does_not_parse_is_refused(tmp_path, capsys, grid, words):
    assert main(["sweep", str(EX2), "--grid", grid, "-q", "--out", str(tmp_path / "sw")]) == 2
    _one_line(capsys, words)
    assert not (tmp_path / "sw").exists()


def test_grid_values_keep_commas_inside_brackets_and_quotes():
    grid = parse_grid(['plant.psi="0.1*min(x1, x2)",\'x1, x2\'', "plant.x0=[0.1, 0.2],[0.3, 0.4]"])
    assert grid == [("plant.psi", ['"0.1*min(x1, x2)"', "'x1, x2'"]),
                    ("plant.x0", ["[0.1, 0.2]", "[0.3, 0.4]"])]


# --------------------------------------------------------------------------------------------
# 8. the bounding function's r_i >= 1, watched during the run


def test_a_bounding_function_below_one_during_the_run_is_reported():
    r = ["1 + q2**2 - max(0, 10*(abs(q1) - 10.1))", "1 + 2*q2**2", "1"]
    sc = load_scenario(EX2, {"controller.proposed.r": r, "plant.x0": [12.0, 0.0],
                             "simulation.duration": 0.05})
    s = qcontrol.run(sc, "ode").summary
    assert s["r_below_one"]["phi1"] < -10
    assert any("went below 1" in w for w in s["warnings"])
    fine = qcontrol.run(load_scenario(EX2, {"simulation.duration": 0.05}), "ode").summary
    assert "r_below_one" not in fine and not fine["warnings"]
    assert qcontrol.run(sc, "ode").trajectory.r[0, 0] == pytest.approx(-18.0)  # the signal itself


# --------------------------------------------------------------------------------------------
# 9. messages


@pytest.mark.parametrize("make, words", [(lambda p: os.mkfifo(p), "is a FIFO"),
                                         (lambda p: p.symlink_to(p), "a symbolic link loop"),
                                         (lambda p: p.mkdir(), "is a folder")])
def test_a_scenario_that_is_not_a_file_says_what_it_is(tmp_path, capsys, make, words):
    path = tmp_path / "s.toml"
    make(path)
    assert main(["check", str(path)]) == 2
    _one_line(capsys, words)


def test_a_path_with_a_newline_is_one_line(tmp_path, capsys):
    assert main(["check", str(tmp_path / "a\nb.toml")]) == 2
    _one_line(capsys, "\\n")


def test_a_command_line_value_names_the_option(capsys):
    assert main(["run", str(EX2), "--duration", "0", "-q"]) == 2
    err = _one_line(capsys, "--duration 0.0: must be a positive number of seconds", "e.g. --duration")
    assert "simulation.duration" not in err


def test_reproduce_checks_its_options_before_importing_matplotlib(tmp_path):
    code = ("import sys; from qcontrol.cli import main; status = main(['reproduce', '--duration', '0', "
            "'--out', 'r']); print(status, 'matplotlib' in sys.modules, 'rerun' in sys.modules)")
    started = time.monotonic()
    proc = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, capture_output=True, text=True,
                          timeout=60, env={**os.environ, "HOME": str(tmp_path)})
    assert proc.stdout.split() == ["2", "False", "False"], proc.stdout + proc.stderr
    assert "--duration 0.0: must be a number of seconds > 0" in proc.stderr and "e.g." in proc.stderr
    assert not (tmp_path / ".cache").exists() and not (tmp_path / "r").exists()
    assert time.monotonic() - started < 30


def test_a_missing_scenarios_folder_is_named(tmp_path, capsys):
    assert main(["reproduce", "--scenarios", str(tmp_path / "none"), "--out", str(tmp_path / "r"), "-q"]) == 2
    err = _one_line(capsys, "--scenarios", "does not exist", "example1.toml")
    assert "shipped" not in err


@pytest.mark.parametrize("option, name", [("--rrd", "r.rrd"), ("--save", "x.npz"), ("--plot", "x.png")])
def test_a_disk_with_no_space_at_all_is_exit_3(small_disk, tmp_path, capfd, option, name):
    """Not one byte free (the file's first write fails, rerun's header included): exit 3, one line,
    the previous file intact."""
    target = small_disk / name
    target.write_bytes(b"previous")
    fd = os.open(small_disk / "ballast", os.O_WRONLY | os.O_CREAT)
    try:  # fill the disk to its last byte
        while os.write(fd, b"\0" * 512):
            pass
    except OSError:
        pass
    finally:
        os.close(fd)
    argv = ("run", str(EX2), *SHORT, option, str(target))
    proc = _cli(*argv, cwd=tmp_path) if option == "--rrd" else _run_here(capfd, *argv)
    assert proc.returncode == 3, proc.stderr
    err = proc.stderr.strip()
    assert len(err.splitlines()) == 1 and "no space left" in err and "Traceback" not in err, err
    assert target.read_bytes() == b"previous"
    assert not _temporaries(small_disk)
