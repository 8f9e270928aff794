"""Several control laws on the same scenario and backend, side by side: a table (a row per law),
an overlay figure (y, z1, u per law) and a rerun recording with every law (the first as the main
run, the others as its twins). ``qcontrol laws`` is this module on the command line."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from .api import Result, _call, check_scenario, observer_for, recording_for
from .assembly import assemble, runnable_backend
from .controller.law import LAW_KINDS
from .errors import QcontrolInputError
from .metrics import summary
from .scenario import Scenario
from .scenario.resolve import scenario_provenance
from .sweep.table import metric_row

TABLE_METRICS = ("max_abs_z1_last_half", "max_abs_u", "lemma2_max_ratio", "diverged")


@dataclass(frozen=True)
class LawComparison:
    """``runs`` maps each kind to its :class:`~qcontrol.Result`; ``table`` has a row per law
    (``kind``, the error rate per omega, ``max_abs_z1_last_half``, ``max_abs_u``,
    ``lemma2_max_ratio``, ``diverged``, ``diverged_time``)."""

    runs: dict[str, Result]
    table: list[dict[str, Any]]
    provenance: dict[str, Any]

    def plot(self, path: str | Path) -> Path:
        """The overlay figure: y and y_d, z1 and u of every law."""
        from .outputs import check_output_file
        from .plots.laws import fig_law_overlay

        check_output_file(path, "plot")
        first = next(iter(self.runs.values()))
        return fig_law_overlay({k: r.trajectory for k, r in self.runs.items()}, path,
                               f"{first.scenario.name} on {first.backend}: {', '.join(self.runs)}")


def compare_laws(scenario: Scenario, kinds: Sequence[str], *, backend: str | None = None,
                 rrd: str | Path | None = None, command: str | None = None) -> LawComparison:
    """Run the scenario once per controller kind in ``kinds`` (``["proposed", "comparison",
    "mine"]``; each with ``controller.kind`` set, its settings from ``[controller.<kind>]``) on
    one backend; ``rrd`` records every law, the first as the main run and the others as twins."""
    check_scenario(scenario, "compare_laws")
    if isinstance(kinds, str) or not isinstance(kinds, Sequence) or len(kinds) < 2:
        raise QcontrolInputError(f"compare_laws: kinds must be a list of two or more controller kinds, "
                                 f"got {kinds!r}")
    unknown = [k for k in kinds if k not in LAW_KINDS]
    if unknown or len(set(kinds)) != len(kinds):
        raise QcontrolInputError(f"compare_laws: kinds {list(kinds)} must be distinct registered kinds "
                                 f"({', '.join(LAW_KINDS)}); register yours first (--law-module FILE)")
    variants = {k: scenario.with_overrides({"controller.kind": k}) for k in kinds}
    backend = runnable_backend(scenario, backend)
    command = command or _call("compare_laws", scenario, backend=backend)
    provenance = scenario_provenance(scenario, command)
    assemblies = {kind: assemble(sc, backend) for kind, sc in variants.items()}
    first = next(iter(assemblies.values()))  # the main run: the recording's constants and scene
    runs: dict[str, Result] = {}
    with recording_for(rrd, False, first, provenance) as rec:
        for kind, asm in assemblies.items():
            main = next(iter(runs.values())).record if runs else None
            observer = None if rec is None else observer_for(rec, first.scene, kind, main)
            traj = asm.run(observer=observer)[0]
            runs[kind] = Result(summary(traj, asm.scenario.name, backend), asm.scenario, backend, traj, asm)
    table = [{"kind": k} | metric_row(r.typed_summary) for k, r in runs.items()]
    return LawComparison(runs, table, provenance)
