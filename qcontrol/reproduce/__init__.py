"""``qcontrol reproduce``: the paper's examples and studies (:mod:`.reproduction`), the robustness
study (:mod:`.robustness_study`, its figures :mod:`.robustness_figures`), Table 1 and REPORT.md
(:mod:`.report`, :mod:`.robustness_report`)."""

from .reproduction import SCENARIO_DIR, reproduce

__all__ = ["SCENARIO_DIR", "reproduce"]
