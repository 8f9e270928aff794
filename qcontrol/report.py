"""Table 1 and REPORT.md of the reproduction: our numbers beside the paper's, with differences."""

from __future__ import annotations

from collections.abc import Mapping, Sequence

from .metrics import TABLE1_OMEGAS, omega_key

OMEGA_KEYS = [omega_key(w) for w in TABLE1_OMEGAS]

# Sun et al. (2022), Table 1: error rate E(omega) on Example 2 (M = 1302 samples over T = 10 s).
PAPER_TABLE1: dict[str, dict[str, float]] = {
    "proposed": dict(zip(OMEGA_KEYS, (0.0253, 0.0223, 0.0200, 0.0177, 0.0161), strict=True)),
    "comparison": dict(zip(OMEGA_KEYS, (0.9570, 0.9339, 0.9132, 0.8925, 0.8679), strict=True)),
}
METHOD_LABELS = {"proposed": "proposed (44)-(45)", "comparison": "comparison [20], eq. (46)"}


def table1(ours: Mapping[str, Mapping[str, Mapping[str, float]]]) -> dict:
    """Table 1 as JSON: ``ours[backend][method][omega]`` beside the paper's, and our - paper."""
    return {
        "omegas": OMEGA_KEYS,
        "paper": PAPER_TABLE1,
        "ours": {b: {m: dict(r) for m, r in methods.items()} for b, methods in ours.items()},
        "difference": {
            backend: {
                method: {w: rates[w] - PAPER_TABLE1[method][w] for w in OMEGA_KEYS}
                for method, rates in methods.items()
            }
            for backend, methods in ours.items()
        },
        "notes": (
            "Example 2, canonical plant theta = [-1, -3.5, -34.3], paper parameters (delta 0.01, "
            "c = [4, 3], gamma = sigma = 1, kappa = 1.1 + L), bounding functions r = [1 + q2^2, "
            "1 + 2 q2^2, 1] (the paper gives none). Comparison: reference [20]'s law (46) with our "
            "reconstructed adaptive law. No parameter was fitted to the table."
        ),
    }


def table1_markdown(table: Mapping) -> str:
    """Table 1 in Markdown: one row per method and source, then the differences."""
    header = "| method | source | " + " | ".join(f"E({w})" for w in OMEGA_KEYS) + " |"
    lines = [header, "|---|---|" + "---|" * len(OMEGA_KEYS)]
    for method in ("proposed", "comparison"):
        label = METHOD_LABELS[method]
        lines.append(_row(label, "paper", table["paper"][method]))
        for backend, methods in table["ours"].items():
            if method in methods:
                lines.append(_row(label, f"ours, {backend}", methods[method]))
        for backend, methods in table["difference"].items():
            if method in methods:
                lines.append(_row(label, f"ours - paper ({backend})", methods[method], signed=True))
    return "\n".join(lines) + "\n"


def _row(method: str, source: str, rates: Mapping[str, float], signed: bool = False) -> str:
    fmt = "{:+.4f}" if signed else "{:.4f}"
    return f"| {method} | {source} | " + " | ".join(fmt.format(rates[w]) for w in OMEGA_KEYS) + " |"


def study_markdown(x_label: str, x_values: Sequence, summaries: Sequence[Mapping]) -> str:
    """A sensitivity study as a Markdown table: one row per parameter value."""
    lines = [
        f"| {x_label} | " + " | ".join(f"E({w})" for w in OMEGA_KEYS)
        + " | max \\|z1\\| last half | max \\|u\\| | Lemma 2 ratio | diverged |",
        "|---|" + "---|" * (len(OMEGA_KEYS) + 4),
    ]
    for x, s in zip(x_values, summaries, strict=True):
        rates = " | ".join(f"{s['error_rate'][w]:.4f}" for w in OMEGA_KEYS)
        lines.append(
            f"| {x} | {rates} | {s['max_abs_z1_last_half']:.3g} | {s['max_abs_u']:.3g} | "
            f"{s['lemma2_max_ratio']:.6f} | {'yes' if s['diverged'] else 'no'} |"
        )
    return "\n".join(lines) + "\n"
