"""What ``run`` and ``compare`` print of a run's summary, and the exit status it gives."""

from __future__ import annotations

import sys

from ..explain import divergence_lines, gain_period_lines, paper_line
from ..metrics import LEMMA2_TOLERANCE
from ..scenario import Scenario
from .arguments import EXIT_FAILED, EXIT_OK


def print_warnings(s: dict) -> None:
    for warning in s.get("warnings", []):
        print(f"  warning: {warning}")
    physics = s.get("physics_warnings", [])
    for message in physics[:3]:
        print(f"  MuJoCo warned: {message}")
    if len(physics) > 3:
        print(f"  ... and {len(physics) - 3} more MuJoCo warnings")


def format_summary(s: dict, sc: Scenario) -> str:
    """The printed summary of a run; a diverged run says when and why it stopped and what usually
    helps (:mod:`qcontrol.explain`)."""
    rates = "  ".join(f"E({k})={v:.4f}" for k, v in s["error_rate"].items())
    if s["diverged"]:
        simulated = (f"stopped after {s['steps']} of {round(s['duration'] / s['dt'])} steps of {s['dt']:g} s "
                     f"({s['steps'] * s['dt']:g} s of {s['duration']:g} s simulated)")
    else:
        simulated = f"{s['steps']} steps of {s['dt']:g} s ({s['duration']:g} s simulated)"
    lines = [
        f"scenario {s['scenario']} on {s['backend']}: {simulated} in {s['wall_time_s']:.2f} s",
        f"  error rate: {rates}",
        f"  max |z1| over the last half: {s['max_abs_z1_last_half']:.4g}    max |u|: {s['max_abs_u']:.4g}",
        f"  actuator: max |u applied|: {s['max_abs_u_applied']:.4g}    saturated at "
        f"{100 * s['saturated_fraction']:.1f}% of the control samples",
        f"  final {s['adaptive_state']}: [{', '.join(f'{v:.4g}' for v in final_state(s))}]",
        _lemma2_line(s),
        *gain_period_lines(s),
    ]
    if s["diverged"]:
        lines += divergence_lines(s, sc)
    return "\n".join(lines)


def _lemma2_line(s: dict) -> str:
    ratio = f"  Lemma 2: max |e_zi|/L_zi = {s['lemma2_max_ratio']:.6f}"
    if not s["lemma2_applies"]:
        return (f"{ratio} (not checked: x2 is differenced from the encoder, outside the paper's "
                "assumptions)")
    return f"{ratio} (<= 1 holds: {'yes' if lemma2_holds(s) else 'NO'})"


def lemma2_holds(s: dict) -> bool:
    """Whether the run kept every Lemma 2 error within its bound (up to rounding)."""
    return s["lemma2_max_ratio"] <= 1 + LEMMA2_TOLERANCE


def print_paper_line(s: dict, sc: Scenario) -> None:
    """For a scenario of the paper, what the paper reports and where the difference is explained."""
    told = paper_line(s, sc)
    if told is not None:
        print(told)


def status(s: dict) -> int:
    """The exit status a run's summary gives: 1 when it diverged or broke a Lemma 2 bound, else 0."""
    if s["diverged"]:
        return EXIT_FAILED
    if s["lemma2_applies"] and not lemma2_holds(s):
        print("qcontrol: check failed: a Lemma 2 bound was exceeded", file=sys.stderr)
        return EXIT_FAILED
    return EXIT_OK


def final_state(s: dict) -> list[float]:
    """The law's final state as the summary names it (``final_<adaptive_state>``)."""
    return s["final_" + s["adaptive_state"]]
