"""What ``run`` and ``compare`` print of a run's summary (read as a typed
:class:`~qcontrol.summary.Summary`), and the exit status it gives."""

from __future__ import annotations

import sys
from collections.abc import Iterable, Mapping, Sequence

from ..explain import MONITORED_DIAGNOSTICS, divergence_lines, gain_period_lines, paper_line
from ..metrics import LEMMA2_TOLERANCE
from ..scenario import Scenario
from ..summary import Summary
from .arguments import EXIT_FAILED, EXIT_LAW_FAILED, EXIT_OK


def print_warnings(warnings: Sequence[str], physics: Sequence[str]) -> None:
    """The separation's ``warnings`` of a run, then the first three of MuJoCo's ``physics`` ones."""
    for warning in warnings:
        print(f"  warning: {warning}")
    for message in physics[:3]:
        print(f"  MuJoCo warned: {message}")
    if len(physics) > 3:
        print(f"  ... and {len(physics) - 3} more MuJoCo warnings")


def format_summary(s: Summary | Mapping, sc: Scenario) -> str:
    """The printed summary of a run (a :class:`Summary`, or its ``summary.json`` object); a diverged
    run says when and why it stopped and what usually helps (:mod:`qcontrol.explain`)."""
    f = typed(s)
    rates = "  ".join(f"E({k})={v:.4f}" for k, v in f.error_rate.items())
    if f.diverged:
        simulated = (f"stopped after {f.steps} of {round(f.duration / f.dt)} steps of {f.dt:g} s "
                     f"({f.steps * f.dt:g} s of {f.duration:g} s simulated)")
    else:
        simulated = f"{f.steps} steps of {f.dt:g} s ({f.duration:g} s simulated)"
    lines = [
        f"scenario {f.scenario} on {f.backend}: {simulated} in {f.wall_time_s:.2f} s",
        f"  error rate: {rates}",
        f"  max |z1| over the last half: {f.max_abs_z1_last_half:.4g}    max |u|: {f.max_abs_u:.4g}",
        f"  actuator: max |u applied|: {f.max_abs_u_applied:.4g}    {_saturation(f.saturated_fraction)}",
        *([f"  final {f.adaptive_state}: [{', '.join(f'{v:.4g}' for v in final_state(f))}]"]
          if final_state(f) else []),  # a stateless law has none to print
        _lemma2_line(f),
        *sensor_lines(f),
        *gain_period_lines(f),
        *law_diagnostic_lines(f),
    ]
    if f.diverged:
        lines += divergence_lines(f, sc)
    return "\n".join(lines)


def law_diagnostic_lines(f: Summary) -> list[str]:
    """The law's own diagnostics as the summary reports them (``max_<name>``, ``last_<name>``),
    on one line; those with a monitor of their own (K T) are printed there instead."""
    shown = {key: value for key, value in f.law_diagnostics.items() if key not in MONITORED_DIAGNOSTICS}
    if not shown:
        return []
    return ["  law diagnostics: " + "    ".join(f"{key} = {_number(value)}" for key, value in shown.items())]


def _number(value: object) -> str:
    """A diagnostic's reduced value: ``n/a`` where the run had none, a list for one of width > 1."""
    if isinstance(value, list):
        return f"[{', '.join(_number(v) for v in value)}]"
    return "n/a" if value is None else f"{value:.4g}"


def _saturation(fraction: float) -> str:
    """How often the actuator's limit cut the command; a run it never cut says so (not "at 0.0%")."""
    if fraction == 0.0:
        return "never saturated"
    return f"saturated at {100 * fraction:.2g}% of the control samples"


def _lemma2_line(f: Summary) -> str:
    ratio = f"  Lemma 2: max |e_zi|/L_zi = {f.lemma2_max_ratio:.6f}"
    if f.quantizer_sector is not None:
        return (f"{ratio} (not checked: a logarithmic quantizer's error has no constant bound; its sector "
                f"bound is |q(x) - x| <= {f.quantizer_sector:.4g} |x|)")
    if f.reading_saturated_fraction:
        return f"{ratio} (not checked: readings saturated at their range, where Lemma 2's bounds do not hold)"
    if not f.lemma2_applies:
        return (f"{ratio} (not checked: x2 is differenced from the encoder, outside the paper's "
                "assumptions)")
    return f"{ratio} (<= 1 holds: {'yes' if lemma2_holds(f) else 'NO'})"


def sensor_lines(f: Summary) -> list[str]:
    """What a ``[quantizer]`` table's sensors add: saturated readings, the input's quantization."""
    lines = []
    if f.reading_saturated_fraction is not None:
        share = 100 * f.reading_saturated_fraction
        lines.append(f"  readings beyond their range: {share:.3g}% of the samples")
    if f.max_abs_input_quantization_error is not None:
        lines.append(f"  input quantizer: max |q_u(u) - u| = {f.max_abs_input_quantization_error:.4g}    "
                     f"q_u(u) != u at {100 * f.input_quantized_fraction:.3g}% of the control samples")
    return lines


def lemma2_holds(f: Summary) -> bool:
    """Whether the run kept every Lemma 2 error within its bound (up to rounding)."""
    return f.lemma2_max_ratio <= 1 + LEMMA2_TOLERANCE


def print_paper_line(sc: Scenario) -> None:
    """For a scenario of the paper, what the paper reports and where the difference is explained."""
    told = paper_line(sc)
    if told is not None:
        print(told)


def law_failed(summaries: Iterable[Summary | Mapping | None]) -> int | None:
    """When a law written in Python failed in any of the runs: the first failure's line on stderr
    (and how many runs it stopped) and the exit status 4; else None."""
    return report_law_failures([f.law_failure for f in (typed(s) for s in summaries if s is not None)
                                if f.law_failure])


def report_law_failures(failures: Sequence[str]) -> int | None:
    """:func:`law_failed` for the failures' lines themselves."""
    if not failures:
        return None
    runs = f" (it stopped {len(failures)} runs)" if len(failures) > 1 else ""
    print(f"qcontrol: error: the law failed: {failures[0]}{runs}", file=sys.stderr)
    return EXIT_LAW_FAILED


def status(s: Summary | Mapping) -> int:
    """The exit status a run's summary gives: 4 when its law failed, 1 when it diverged or broke a
    Lemma 2 bound, else 0."""
    f = typed(s)
    if f.law_failure is not None:
        return law_failed([f]) or EXIT_LAW_FAILED
    if f.diverged:
        return EXIT_FAILED
    if f.lemma2_applies and not lemma2_holds(f):
        print("qcontrol: check failed: a Lemma 2 bound was exceeded", file=sys.stderr)
        return EXIT_FAILED
    return EXIT_OK


def final_state(f: Summary) -> tuple[float, ...]:
    """The law's final state (the summary's ``final_<adaptive_state>``)."""
    return f.final_eps_hat if f.final_state is None else f.final_state


def typed(s: Summary | Mapping) -> Summary:
    """``s`` as a :class:`Summary` (read from its ``summary.json`` object if it is one)."""
    return s if isinstance(s, Summary) else Summary.from_json(s)
