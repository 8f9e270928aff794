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
from .controller.law import KIND_ALIASES, LAW_KINDS
from .errors import QcontrolInputError
from .metrics import summary
from .region import LawSpec, parse_law
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
        from .plots import scenario_units
        from .plots.laws import fig_law_overlay

        check_output_file(path, "plot")
        first = next(iter(self.runs.values()))
        return fig_law_overlay({k: r.trajectory for k, r in self.runs.items()}, path,
                               f"{first.scenario.name} on {first.backend}: {', '.join(self.runs)}",
                               scenario_units(first.scenario))


def compare_laws(scenario: Scenario, kinds: Sequence[str], *, backend: str | None = None,
                 rrd: str | Path | None = None, command: str | None = None) -> LawComparison:
    """Run the scenario once per law in ``kinds`` on one backend: a controller kind (``"proposed"``,
    ``"comparison"``, one registered from Python), optionally with settings of its ``[controller]``
    table as ``KIND:KEY=VALUE,...`` (``"proposed:hold=exact"``), as ``qcontrol region --law``
    takes them. Each run sets ``controller.kind`` and takes the kind's settings from
    ``[controller.<kind>]``; ``runs`` and ``table`` are keyed by the law as given. ``rrd`` records
    every law, the first as the main run and the others as twins."""
    check_scenario(scenario, "compare_laws")
    if isinstance(kinds, str) or not isinstance(kinds, Sequence) or len(kinds) < 2 or not all(
            isinstance(k, str) for k in kinds):
        raise QcontrolInputError(f"compare_laws: kinds must be a list of two or more controller kinds, "
                                 f"got {kinds!r}")
    unknown = [k for k in kinds if KIND_ALIASES.get(k.partition(":")[0].strip(), k.partition(":")[0].strip())
               not in LAW_KINDS]
    specs = [] if unknown else [parse_law(text) for text in kinds]
    labels = [spec.label for spec in specs]
    if unknown or len(set(labels)) != len(labels):
        raise QcontrolInputError(f"compare_laws: kinds {list(kinds)} must be distinct registered kinds "
                                 f"({', '.join(LAW_KINDS)}), each optionally with settings "
                                 "(proposed:hold=exact); register yours first (--law-module FILE)")
    variants = {spec.label: scenario.with_overrides(_overrides(spec)) for spec in specs}
    backend = runnable_backend(scenario, backend)
    command = command or _call("compare_laws", scenario, backend=backend)
    provenance = scenario_provenance(scenario, command)
    assemblies = {kind: assemble(sc, backend) for kind, sc in variants.items()}
    first = next(iter(assemblies.values()))  # the main run: the recording's constants and scene
    runs: dict[str, Result] = {}
    with recording_for(rrd, False, first, provenance) as rec:
        for kind, asm in assemblies.items():
            main = next(iter(runs.values())).record if runs else None
            observer = None if rec is None else observer_for(rec, first.scene, _entity_label(kind), main)
            traj = asm.run(observer=observer)[0]
            runs[kind] = Result(summary(traj, asm.scenario.name, backend), asm.scenario, backend, traj, asm)
    table = [{"kind": k} | metric_row(r.typed_summary) for k, r in runs.items()]
    return LawComparison(runs, table, provenance)


def _overrides(spec: LawSpec) -> dict[str, str] | list[str]:
    """A law's overrides: the kind alone as a dict (as before settings were accepted), with its
    settings as the ``key=value`` texts a region run takes."""
    return {"controller.kind": spec.kind} if not spec.settings else spec.overrides()


def _entity_label(label: str) -> str:
    """A law's label as a recording's entity names take it (``proposed:hold=exact`` ->
    ``proposed_hold-exact``)."""
    return label.replace(":", "_").replace("=", "-").replace(",", "_")
