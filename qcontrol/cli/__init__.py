"""The ``qcontrol`` command line (:func:`main`): one module per command (``run_command``,
``compare_command``, ``reproduce_command``, ``sweep_command``, ``check_command``), the options
they share (:mod:`.arguments`) and what they print of a summary (:mod:`.printing`)."""

from .dispatch import COMMANDS, build_parser, main
from .printing import format_summary, status

__all__ = ["COMMANDS", "build_parser", "format_summary", "main", "status"]
