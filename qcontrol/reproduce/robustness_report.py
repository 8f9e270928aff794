"""REPORT.md's robustness section: the tables of ``robustness.json`` and a reading of them.

Every number and every comparison in the text is computed from the study; the prose around them
says what the paper's assumptions are and why an imperfection leaves them.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

E = "0.100"
EXAMPLE_NAMES = {"example2": "Example 2 (the arm, `example2-arm.toml`)",
                 "example1": "Example 1 (the cart, `example1-cart.toml`)"}
PHYSICAL = ("torque limit", "force limit", "friction", "rotor inertia (armature)", "link mass (rod)",
            "sensor noise", "sensor delay", "sensor period", "control period")


def _number(value: float | None, digits: int = 3) -> str:
    if value is None or not math.isfinite(value):
        return "n/a"
    return f"{value:.{digits}g}"


def _rate(value: float | None) -> str:
    return "n/a" if value is None or not math.isfinite(value) else f"{value:.4f}"


def _cell(spread: Mapping, show=_number) -> str:
    """A median, with the range when the runs differ."""
    median, low, high = (spread[k] for k in ("median", "min", "max"))
    text = show(median)
    if low is not None and high is not None and math.isfinite(low) and high > low:
        text += f" [{show(low)}, {show(high)}]"
    return text


def _median(cell: Mapping, metric: str) -> float:
    spread = cell["error_rate"][E] if metric == "E" else cell[metric]
    value = spread["median"]
    return math.nan if value is None else float(value)


def _diverged(cell: Mapping) -> str:
    return "no" if not cell["diverged"] else f"{cell['diverged']}/{cell['runs']}"


def rows_table(rows: Sequence[Mapping]) -> list[str]:
    lines = ["| imperfection | law | E(0.1) MuJoCo | E(0.1) ODE twin | max \\|z1\\| last half MuJoCo | "
             "ODE twin | max \\|u applied\\| | saturated | diverged |",
             "|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        m, o = r["mujoco"], r["ode"]
        lines.append(f"| {r['imperfection']} | {r['law']} | {_cell(m['error_rate'][E], _rate)} | "
                     f"{_cell(o['error_rate'][E], _rate)} | {_cell(m['max_abs_z1_last_half'])} | "
                     f"{_cell(o['max_abs_z1_last_half'])} | {_cell(m['max_abs_u_applied'])} | "
                     f"{_cell(m['saturated_fraction'])} | {_diverged(m)} |")
    return lines


def margins_table(margins: Sequence[Mapping]) -> list[str]:
    lines = ["| example | imperfection | value | law | E(0.1) | max \\|z1\\| last half | "
             "max \\|u applied\\| | saturated | diverged |", "|---|---|---|---|---|---|---|---|---|"]
    for r in margins:
        m = r["mujoco"]
        lines.append(f"| {r['example']} | {r['imperfection']} | {show_amount(r)} | {r['law']} | "
                     f"{_cell(m['error_rate'][E], _rate)} | {_cell(m['max_abs_z1_last_half'])} | "
                     f"{_cell(m['max_abs_u_applied'])} | {_cell(m['saturated_fraction'])} | {_diverged(m)} |")
    return lines


def _seconds(value: float | None) -> str:
    return "never" if value is None else f"{value:.3f} s"


def disturbances_table(cases: Sequence[Mapping]) -> list[str]:
    lines = ["| arm | disturbance | law | plant | peak \\|z1\\| (undisturbed) | peak deviation | "
             "back within delta of the undisturbed run | \\|z1\\| < 0.1 for good | "
             "deviation over the last second |",
             "|---|---|---|---|---|---|---|---|---|"]
    for c in cases:
        r = c["result"]
        plant = "MuJoCo" if c["backend"] == "mujoco" else "ODE twin"
        lines.append(f"| {c['plant']} | {c['disturbance']} | {c['law']} | {plant} | "
                     f"{_number(r['peak_abs_z1'])} ({_number(r['peak_abs_z1_undisturbed'])}) | "
                     f"{_number(r['peak_deviation'])} | {_seconds(r['recovery_to_undisturbed_s'])} | "
                     f"{_seconds(r['recovery_time_s'])} | {_number(r['final_deviation'])} |")
    return lines


# --------------------------------------------------------------------------------------------
# the reading


def _row(rows: Sequence[Mapping], example: str, law: str, label: str) -> Mapping | None:
    return next((r for r in rows
                 if r["example"] == example and r["law"] == law and r["imperfection"] == label), None)


def _worst(rows: Sequence[Mapping], example: str, law: str) -> tuple[str, float, float] | None:
    """The physical imperfection that raises max |z1| over the last half the most, alone: its label,
    that value and the ideal's."""
    ideal = _row(rows, example, law, "ideal")
    candidates = [r for r in rows if r["example"] == example and r["law"] == law
                  and r["imperfection"] in PHYSICAL and not r["mujoco"]["diverged"]]
    if ideal is None or not candidates:
        return None
    worst = max(candidates, key=lambda r: _median(r["mujoco"], "max_abs_z1_last_half"))
    return (worst["imperfection"], _median(worst["mujoco"], "max_abs_z1_last_half"),
            _median(ideal["mujoco"], "max_abs_z1_last_half"))


def _change(value: float, base: float) -> str:
    """``+12 %`` against ``base``; a change that rounds to 0 % says so instead of "+0 %"."""
    if not base:
        return "n/a"
    percent = 100 * (value - base) / base
    return "unchanged to within 0.5 %" if abs(percent) < 0.5 else f"{percent:+.0f} %"


def _per_law(study: Mapping, example: str) -> list[str]:
    rows, lines = study["rows"], []
    for law in dict.fromkeys(r["law"] for r in rows if r["example"] == example):
        ideal, together = _row(rows, example, law, "ideal"), _row(rows, example, law, "all together")
        worst = _worst(rows, example, law)
        if ideal is None or together is None or worst is None:
            continue
        label, value, base = worst
        z_all = _median(together["mujoco"], "max_abs_z1_last_half")
        e_all, e_ideal = _median(together["mujoco"], "E"), _median(ideal["mujoco"], "E")
        if abs(value - base) <= 0.05 * base:
            effect = (f"no imperfection alone moves max |z1| over the last half by more than 5 % (the "
                      f"largest, {label}: {_number(value)} against {_number(base)} ideal, "
                      f"{_change(value, base)}): the loop's own tracking error dominates.")
        else:
            effect = (f"the largest effect alone is **{label}**: max |z1| over the last half "
                      f"{_number(value)} against {_number(base)} ideal ({_change(value, base)}).")
        lines.append(
            f"* {EXAMPLE_NAMES[example]}, {law} law: {effect}"
            f" All together: max |z1| last half {_number(z_all)} ({_change(z_all, base)}), "
            f"E(0.1) = {_rate(e_all)} against {_rate(e_ideal)} ideal; the ODE twin with the same "
            f"settings gives E(0.1) = {_rate(_median(together['ode'], 'E'))}: the difference is what "
            "the physics costs.")
    return lines


def _ladder(margins: Sequence[Mapping], example: str, law: str, label: str) -> list[Mapping]:
    return [r for r in margins if r["example"] == example and r["law"] == law and r["imperfection"] == label]


def show_amount(row: Mapping) -> str:
    """A margin row's amount of its imperfection: a time in ms, anything else in its own unit."""
    return f"{1000 * row['value']:g} ms" if row["unit"] == "s" else f"{row['value']:g} {row['unit']}"


def _first_divergence(margins: Sequence[Mapping], example: str, law: str, label: str) -> str:
    ladder = _ladder(margins, example, law, label)
    if not ladder:
        return "not studied"
    gone = [r for r in ladder if r["mujoco"]["diverged"]]
    if not gone:
        return f"bounded up to {show_amount(ladder[-1])}"
    return "diverged at " + ", ".join(show_amount(r) for r in gone)


def _saturation(rows: Sequence[Mapping], margins: Sequence[Mapping], example: str, law: str) -> str:
    """Where clipping starts to cost: the first limit at which max |z1| last half grows by 20 %."""
    ideal = _row(rows, example, law, "ideal")
    ladder = [r for label in ("torque limit", "force limit") for r in _ladder(margins, example, law, label)]
    if ideal is None or not ladder:
        return f"{example} {law}: not studied"
    base = _median(ideal["mujoco"], "max_abs_z1_last_half")
    hurt = next((r for r in ladder if not _median(r["mujoco"], "max_abs_z1_last_half") <= 1.2 * base), None)
    if hurt is None:
        return f"{example} {law}: no cost down to {show_amount(ladder[-1])}"
    m = hurt["mujoco"]
    clipped = _number(100 * _median(m, "saturated_fraction"))
    return (f"{example} {law}: at {show_amount(hurt)} the actuator clips {clipped} % of the samples and "
            f"max |z1| last half is {_number(_median(m, 'max_abs_z1_last_half'))} (ideal {_number(base)})")


def _largest(rows: Sequence[Mapping], key: str, labels: Sequence[str]) -> float:
    values = [r["mujoco"][key]["max"] for r in rows if r["imperfection"] in labels]
    finite = [v for v in values if v is not None and math.isfinite(v)]
    return max(finite) if finite else math.nan


def reading(study: Mapping) -> list[str]:
    """The honest reading: which imperfection hurts which controller, where the theorem's
    assumptions break and what the measurements show there."""
    rows, margins = study["rows"], study["margins"]
    examples = list(dict.fromkeys(r["example"] for r in rows))
    pairs = [(example, law) for example in examples for law in dict.fromkeys(r["law"] for r in rows)]
    lines = ["### Reading", ""]
    for example in examples:
        lines += _per_law(study, example)
    clipped = _largest(rows, "saturated_fraction", ("torque limit", "force limit", "all together"))
    friction = [(e, law, _row(rows, e, law, "friction")) for e, law in pairs]
    lines += [
        "* **Saturation.** Theorem 1 assumes the input is applied as computed. With the realistic motors "
        + ("the actuator never clipped" if clipped == 0 else
           f"the actuator clipped at most {_number(100 * clipped, 2)} % of the control samples")
        + ": the motors are sized for the task and the paper's laws, at its settings, ask for less. "
        "Beyond the hardware "
        "(margins): "
        + "; ".join(_saturation(rows, margins, e, law) for e, law in pairs) + ".",
        "* **Delay and sampling.** The analysis is in continuous time, with q(x(t)) read at t; a delayed or "
        "held reading is not. Lemma 2 still holds for the reading the quantizer saw (it is a property of "
        "the quantizer), but the loop acts on old information. Margins: "
        + "; ".join(f"{e} {law}: sensor delay {_first_divergence(margins, e, law, 'sensor delay')}, "
                    f"control period {_first_divergence(margins, e, law, 'control period')}"
                    for e, law in pairs) + ".",
        "* **Velocity from the encoder.** Lemma 2 assumes every state is measured and quantized; a "
        "differenced x2 is neither (its resolution is delta / T, and it lags). "
        + "; ".join(_differencing(rows, margins, e, law) for e, law in pairs) + ". " + _twin_agrees(rows),
        "* **Friction.** Dry friction is a discontinuous force, Ff sign(x2); eq. (1)'s terms are continuous "
        "and the bounding functions r the laws are given do not cover it. Near the reference the commanded "
        "force is of the order of the friction force, so the body sticks until the error has grown "
        "(stick-slip). Alone, at the realistic value: " + "; ".join(
            f"{e} {law}: max |z1| last half {_number(_median(r['mujoco'], 'max_abs_z1_last_half'))}"
            for e, law, r in friction if r is not None) + ".",
        *_noise(rows, pairs),
        *_disturbances(study["disturbances"]),
        _lemma2_line(rows),
        "",
    ]
    return lines


def _noise(rows: Sequence[Mapping], pairs: Sequence[tuple[str, str]]) -> list[str]:
    """Where sensor noise alone lowers the tracking error (it dithers a coarse quantizer)."""
    lower = []
    for example, law in pairs:
        noisy, ideal = _row(rows, example, law, "sensor noise"), _row(rows, example, law, "ideal")
        if noisy is None or ideal is None:
            continue
        z, base = (_median(r["mujoco"], "max_abs_z1_last_half") for r in (noisy, ideal))
        if z < 0.95 * base:
            lower.append(f"{example} {law}: {_number(z)} against {_number(base)}")
    if not lower:
        return []
    return ["* **Sensor noise** alone lowers max |z1| over the last half by more than 5 % in "
            + "; ".join(lower) + ": added before the quantizer, it dithers q(x), so the controller sees a "
            "finer average than delta."]


def _disturbances(cases: Sequence[Mapping]) -> list[str]:
    """The disturbances on the realistic arm, on MuJoCo: peak deviation, recovery, what stays."""
    chosen = [c for c in cases if c["plant"] == "realistic arm" and c["backend"] == "mujoco"]
    if not chosen:
        return []
    parts = []
    for c in chosen:
        r = c["result"]
        back = r["recovery_to_undisturbed_s"]
        offset = f"never back within delta (offset {_number(r['final_deviation'])} over the last second)"
        parts.append(f"{c['disturbance']}, {c['law']}: peak deviation {_number(r['peak_deviation'])}, "
                     + (f"back within delta after {back:.2f} s" if back is not None else offset))
    held = [c for c in cases if c["result"]["recovery_time_s"] is not None]
    band = ("|z1| < 0.1 is never held to the end, disturbed or not: the undisturbed loop already exceeds "
            "0.1 most of the time." if not held else
            f"|z1| < 0.1 is held to the end in {len(held)} of {len(cases)} cases.")
    return ["* **Disturbances** on the realistic arm (MuJoCo): " + "; ".join(parts) + ". A load that "
            "stays leaves an offset where it is not among the terms a law adapts to (phi, psi) and no law "
            "here has integral action. " + band]


def _differencing(rows: Sequence[Mapping], margins: Sequence[Mapping], example: str, law: str) -> str:
    row = _row(rows, example, law, "x2 differenced")
    if row is None:
        return f"{example} {law}: not studied"
    m = row["mujoco"]
    state = ("diverged" if m["diverged"] else
             f"stayed bounded (max |z1| last half {_number(_median(m, 'max_abs_z1_last_half'))}, max |u| "
             f"{_number(_median(m, 'max_abs_u_applied'))})")
    return (f"{example} {law} with T = dt: {state}; over longer T: "
            f"{_first_divergence(margins, example, law, 'x2 differenced over T')}")


def _twin_agrees(rows: Sequence[Mapping]) -> str:
    """Whether the ODE twin, which differences x2 the same way, diverged where MuJoCo did."""
    differenced = [r for r in rows if r["imperfection"] == "x2 differenced"]
    same = all(bool(r["mujoco"]["diverged"]) == bool(r["ode"]["diverged"]) for r in differenced)
    if same:
        return ("The ODE twin, which differences x2 the same way, diverges or stays bounded exactly where "
                "MuJoCo does: the cause is the controller's input, not the physics.")
    return "The ODE twin, which differences x2 the same way, does not always agree with MuJoCo here."


def _lemma2_line(rows: Sequence[Mapping]) -> str:
    checked = [r["mujoco"]["lemma2_max_ratio"]["max"] for r in rows if r["mujoco"]["lemma2_applies"]]
    checked = [v for v in checked if v is not None and math.isfinite(v)]
    unchecked = [r["mujoco"]["lemma2_max_ratio"]["max"] for r in rows if not r["mujoco"]["lemma2_applies"]]
    unchecked = [v for v in unchecked if v is not None and math.isfinite(v)]
    largest = max(checked, default=math.nan)
    holds = "<= 1 everywhere" if largest <= 1 + 1e-9 else "VIOLATED"
    text = ("* **Lemma 2** over every run where its premise holds (all but the differenced ones): largest "
            f"|e_zi| / L_zi = {largest:.7f} ({holds}: noise, delay and friction change what is read, not "
            "the quantizer)")
    if unchecked:
        text += (f"; with x2 differenced the ratio reaches {_number(max(unchecked))} (reported, not checked: "
                 "such runs exit 0 unless they diverge)")
    return text + "."


def robustness_section(study: Mapping) -> list[str]:
    """The section, tables first, then the figures and the reading."""
    seeds = len(study["seeds"])
    lines = [
        "## Robustness on realistic hardware (MuJoCo, with the ODE twin beside)",
        "",
        "The controllers keep the paper's settings; the plants get the imperfections of real hardware "
        "(`scenarios/example2-arm.toml`, `scenarios/example1-cart.toml`: each number's source is commented "
        "there). Each imperfection is put alone on the paper's ideal scenario with the realistic value, "
        "then all together (the realistic scenario without its demonstration disturbance), plus x2 "
        "differenced from the encoder (`velocity_source = \"difference\"`). The ODE twin runs the same "
        "settings on eq. (1): it shares the control period, the velocity source and the disturbances, none "
        f"of the physics. Rows with sensor noise run {seeds} seeds: median [min, max]. Saturated: the "
        "fraction of control samples at which the actuator clipped the command.",
        "",
    ]
    for example in dict.fromkeys(r["example"] for r in study["rows"]):
        lines += [f"### {EXAMPLE_NAMES.get(example, example)}", "",
                  *rows_table([r for r in study["rows"] if r["example"] == example]), ""]
    lines += ["![robustness study](study_robustness.png)", "",
              "### Margins: each imperfection alone, beyond the hardware (MuJoCo)", "",
              *margins_table(study["margins"]), "", "![margins](study_margins.png)", "",
              "### Disturbances on the arm (at half the run)", "",
              "An impulse (20 N m for 50 ms) and a load step (10 N m that stays). The deviation is "
              "|z1 - z1 of the same run without the disturbance|; 'back within delta' is the time from the "
              "disturbance's start until that deviation stays below the quantizer step delta; "
              "'|z1| < 0.1 for good' the time until |z1| stays below 0.1 (Table 1's smallest omega).", "",
              *disturbances_table(study["disturbances"]), "", *reading(study)]
    return lines
