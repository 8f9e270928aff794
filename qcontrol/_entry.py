"""Console entry point: Ctrl-C while the command's modules are still importing exits 130 quietly,
and a reader that closes the pipe early (``qcontrol run ... | head``) ends the command quietly."""

import os
import sys


def main() -> int:
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
