"""A run's summary as a typed, frozen record: :class:`Summary`, whose :meth:`~Summary.to_json` is
``summary.json`` (its keys: docs/commands.md, `qcontrol run`) and :meth:`~Summary.from_json` reads it back."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import MISSING, dataclass, field, fields
from typing import Any


@dataclass(frozen=True, kw_only=True)
class Summary:
    """What a closed-loop run reports (the fields of ``summary.json``, in its order).

    ``scenario`` and ``backend`` name the run; ``duration`` (s), ``dt`` (s) and ``steps`` its grid
    and how far it got; ``wall_time_s`` what it cost. ``diverged`` with ``diverged_time`` (s, or
    None) and ``divergence_reason`` say whether and why it stopped. The metrics: ``error_rate``,
    Table 1's E(omega) keyed ``"0.100"`` .. ``"0.200"``; ``max_abs_z1_last_half`` (the ultimate
    bound of Theorem 1's tracking error); ``max_abs_u`` and ``max_abs_u_applied`` (the command
    and what the actuator applied); ``saturated_fraction`` (of the control samples);
    ``final_eps_hat``, the adaptive estimates at the end (named ``adaptive_state``: eps_hat of
    (45), theta_hat of (46), ...). Lemma 2: ``lemma2_max_ratio`` = max over time and i of
    ``|e_zi| / L_zi`` (<= 1 holds), ``lemma2_applies`` (false when x2 is differenced,
    ``velocity_source``, and on a plant outside the chain of eq. (1)), the bounds ``L_z`` and
    ``L = L_zn``. The separation (37)-(43):
    ``bound_constants`` (term -> largest ``|term| / r(x_q)``, None where unbounded; None, and absent
    from ``summary.json``, when not checked: a law without bounding functions, terms in t) and
    ``warnings``; ``r_below_one`` (term -> smallest ``r_i(x_q)``), present only when a bounding
    function went below 1 during the run. ``law_diagnostics``: the law's own diagnostics as it
    declared them (``max_gain_period`` for the paper's law: the largest K T over the control
    samples), written as top-level keys ``<reduce>_<name>`` of ``summary.json``. ``final_state``:
    the law's state at the end under the law's own name, the key ``final_<adaptive_state>``
    (``final_theta_hat`` for the comparison law; for the paper's law that key is ``final_eps_hat``
    itself, kept for every law as an alias). ``provenance`` and
    ``physics_warnings`` are present (not None) in the summary of a single run written by
    ``qcontrol run`` or :func:`qcontrol.run`. The sensors of a ``[quantizer]`` table, each present
    only where it applies: ``reading_saturated_fraction`` (the share of readings beyond a channel's
    range; Lemma 2's bounds do not hold there), ``quantizer_sector`` (a logarithmic quantizer's
    relative bound xi, reported instead of Lemma 2, ``lemma2_applies`` false),
    ``max_abs_input_quantization_error`` and ``input_quantized_fraction`` (``[quantizer.input]``:
    the largest ``|q_u(u) - u|`` and the share of control samples at which the applied input
    differed from the command).
    ``law_failure`` is present only when a law written in Python failed during the run (raised,
    or returned what its method must not): the one line that says so, also the
    ``divergence_reason`` of the run it stopped.
    """

    scenario: str
    backend: str
    duration: float
    dt: float
    steps: int
    wall_time_s: float
    diverged: bool
    diverged_time: float | None
    divergence_reason: str
    error_rate: Mapping[str, float]
    max_abs_z1_last_half: float
    max_abs_u: float
    max_abs_u_applied: float
    saturated_fraction: float
    final_eps_hat: tuple[float, ...]
    adaptive_state: str
    lemma2_max_ratio: float
    velocity_source: str
    lemma2_applies: bool
    L_z: tuple[float, ...]
    L: float
    bound_constants: Mapping[str, float | None] | None = None
    warnings: tuple[str, ...] = ()
    law_diagnostics: Mapping[str, Any] = field(default_factory=dict)
    final_state: tuple[float, ...] | None = None  # written as final_<adaptive_state>
    r_below_one: Mapping[str, float] | None = None
    provenance: Mapping[str, Any] | None = field(default=None, compare=False)
    physics_warnings: tuple[str, ...] | None = None
    reading_saturated_fraction: float | None = None
    quantizer_sector: float | None = None
    max_abs_input_quantization_error: float | None = None
    input_quantized_fraction: float | None = None
    law_failure: str | None = None

    def to_json(self) -> dict[str, Any]:
        """``summary.json``'s object: every field in order, lists for tuples, the optional ones
        only when present."""
        out: dict[str, Any] = {}
        for f in fields(self):
            value = getattr(self, f.name)
            if value is None and f.name in _OPTIONAL:
                continue
            if f.name == "law_diagnostics":  # flat: "max_gain_period": 0.011
                out.update({key: _plain(v) for key, v in value.items()})
                continue
            if f.name == "final_state":  # "final_theta_hat": [...]; "final_eps_hat" is the field itself
                if value is not None and self.adaptive_state != "eps_hat":
                    out[f"final_{self.adaptive_state}"] = _plain(value)
                continue
            out[f.name] = _plain(value)
        return out

    @classmethod
    def from_json(cls, data: Mapping[str, Any]) -> Summary:
        """The summary of a ``summary.json`` object (as :meth:`to_json` writes it). A field added
        since the file was written takes its default (every field added after the first release
        has one); a field without a default that the file lacks is refused in one line."""
        known = {f.name for f in fields(cls)} - {"law_diagnostics", "final_state"}
        state_key = f"final_{data.get('adaptive_state')}"
        diagnostics = {k: v for k, v in data.items() if k not in known and k.startswith(_DIAGNOSTIC_PREFIXES)}
        unknown = sorted(set(data) - known - set(diagnostics) - {state_key})
        if unknown:
            raise ValueError(f"not a summary field: {', '.join(unknown)}")
        required = [f.name for f in fields(cls) if f.default is MISSING and f.default_factory is MISSING]
        missing = [name for name in required if name not in data]
        if missing:
            raise ValueError(f"not a summary: it lacks {', '.join(missing)} (a summary.json written by "
                             "qcontrol has every field without a default)")
        values = {k: v for k, v in data.items() if k in known} | {"law_diagnostics": diagnostics,
                                                                   "final_state": data.get(state_key)}
        for name in ("final_eps_hat", "final_state", "L_z", "warnings", "physics_warnings"):
            if values.get(name) is not None:
                values[name] = tuple(values[name])
        return cls(**values)


_OPTIONAL = ("bound_constants", "r_below_one", "provenance", "physics_warnings", "reading_saturated_fraction",
             "quantizer_sector", "max_abs_input_quantization_error", "input_quantized_fraction",
             "law_failure")
_DIAGNOSTIC_PREFIXES = ("max_", "last_")  # a law diagnostic's key: <reduce>_<name>


def _plain(value: Any) -> Any:
    if isinstance(value, tuple):
        return [_plain(v) for v in value]
    if isinstance(value, Mapping):
        return {k: _plain(v) for k, v in value.items()}
    return value
