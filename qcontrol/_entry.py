"""Console entry point: Ctrl-C while the command's modules are still importing exits 130 quietly,
a reader that closes the pipe early (``qcontrol run ... | head``) ends the command quietly, and
once the command has returned its exit status, a Ctrl-C that arrives while the interpreter exits
(or one still pending from the Ctrl-C the command answered) no longer turns that status into
death by SIGINT.

CPython remembers a ``KeyboardInterrupt`` that left code evaluated from a string (``exec`` or
``eval`` of text: ``collections.namedtuple``, ``dataclasses`` and numba's generated code do it,
while modules import or functions compile) even when a caller caught it, and ``python -m`` then
ends the process by SIGINT whatever status the command returned. Evaluating a string clears that
memory: done once the status is decided, so the command's 130 is the process's.

Then the process's objects are frozen (:func:`gc.freeze`): the interpreter's teardown leaves them
to the system instead of collecting the whole heap object by object, which after ``qcontrol
reproduce`` (numba, MuJoCo, matplotlib and rerun loaded) took about 1 s of one core, the rest of
the machine idle, at the end of the command. Every output is closed and in place by then."""

import gc
import os
import signal
import sys


def main() -> int:
    try:
        return _command()
    finally:
        signal.signal(signal.SIGINT, signal.SIG_IGN)  # the status is decided
        eval("None")  # clears CPython's memory of a caught KeyboardInterrupt (module docstring)
        gc.freeze()  # the heap left to the system at exit, not collected (module docstring)


def _command() -> int:
    try:
        from .cli import main as cli_main
    except KeyboardInterrupt:
        print("\nqcontrol: interrupted", file=sys.stderr)
        return 130
    try:
        return cli_main()
    except BrokenPipeError:
        # the reader is gone: send what is left of stdout nowhere, so closing it does not fail again
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 0
