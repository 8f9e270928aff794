"""``qcontrol reproduce``: the paper's examples and studies (:mod:`.reproduction`), the robustness
study (:mod:`.robustness_study`, its figures :mod:`.robustness_figures`), Table 1 and REPORT.md
(:mod:`.report`, :mod:`.robustness_report`).

The package itself imports nothing (its modules bring matplotlib): ``qcontrol.reproduce`` is the
function :func:`qcontrol.commands.reproduce`, bound over this package's name when qcontrol is
imported, and ``from qcontrol.reproduce import reproduce, SCENARIO_DIR`` still reads this
package's :mod:`.reproduction` on first use."""

from typing import Any

__all__ = ["SCENARIO_DIR", "reproduce"]


def __getattr__(name: str) -> Any:
    """``SCENARIO_DIR`` and ``reproduce`` of :mod:`.reproduction`, imported on first use."""
    if name in __all__:
        from . import reproduction

        return getattr(reproduction, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
