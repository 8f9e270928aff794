"""Console entry point: Ctrl-C while the command's modules are still importing exits 130 quietly."""

import sys


def main() -> int:
    try:
        from .cli import main as cli_main
    except KeyboardInterrupt:
        print("\nqcontrol: interrupted", file=sys.stderr)
        return 130
    return cli_main()
