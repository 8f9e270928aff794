"""The typed summary: summary.json is Summary.to_json(), read back by Summary.from_json()."""

import dataclasses
import json

import pytest

import qcontrol
from qcontrol import Summary
from qcontrol.cli import main

CONTRACT = ["scenario", "backend", "duration", "dt", "steps", "wall_time_s", "diverged", "diverged_time",
            "divergence_reason", "error_rate", "max_abs_z1_last_half", "max_abs_u", "max_abs_u_applied",
            "saturated_fraction", "final_eps_hat", "adaptive_state", "lemma2_max_ratio", "velocity_source",
            "lemma2_applies", "L_z", "L", "bound_constants", "warnings", "max_gain_period", "provenance",
            "physics_warnings"]  # max_gain_period: the paper's law's diagnostic (a law declares its own)


def test_summary_json_is_to_json_and_reads_back(tmp_path, ex2):
    assert main(["run", str(ex2), "--backend", "ode", "--duration", "0.2", "-q", "--out", str(tmp_path)]) == 0
    text = (tmp_path / "summary.json").read_text()
    data = json.loads(text)
    assert list(data) == CONTRACT
    typed = Summary.from_json(data)
    assert typed.to_json() == data
    assert json.dumps(typed.to_json(), indent=2) == json.dumps(data, indent=2)
    assert typed.steps == 200 and typed.L == typed.L_z[-1] and isinstance(typed.final_eps_hat, tuple)
    assert typed.law_diagnostics == {"max_gain_period": data["max_gain_period"]}
    with pytest.raises(dataclasses.FrozenInstanceError):
        typed.steps = 3  # type: ignore[misc]


def test_the_api_gives_the_same_summary_typed(short_example2):
    result = qcontrol.run(short_example2, "mujoco", record="metrics")
    typed = result.typed_summary
    assert typed.to_json() == result.summary and typed.backend == "mujoco"
    assert "provenance" not in dataclasses.replace(typed, provenance=None).to_json()


def test_an_unknown_field_is_refused():
    with pytest.raises(ValueError, match="not a summary field: speed"):
        Summary.from_json({"speed": 1.0})


def test_the_laws_own_final_state_key_reads_back_in_place(short_example2):
    result = qcontrol.run(short_example2.with_overrides({"controller.kind": "comparison"}), "ode",
                          record="metrics")
    data = result.summary
    keys = list(data)
    assert data["adaptive_state"] == "theta_hat" and data["final_theta_hat"] == data["final_eps_hat"]
    assert keys.index("final_theta_hat") == keys.index("warnings") + 1  # after the law's (no) diagnostics
    typed = Summary.from_json(data)
    assert typed.final_state == typed.final_eps_hat and list(typed.to_json()) == keys
    paper = qcontrol.run(short_example2, "ode", record="metrics").summary
    assert "final_state" not in paper  # final_eps_hat is the paper's law's own name
    assert Summary.from_json(paper).final_state == tuple(paper["final_eps_hat"])


def test_a_summary_written_by_an_older_version_reads_back():
    """tests/data/summary-0.2.json was written by `qcontrol run` of 0.2: a field added since must
    have a default (docs/architecture.md, 'A recorded signal'), or this older file stops reading."""
    from conftest import ROOT

    data = json.loads((ROOT / "tests" / "data" / "summary-0.2.json").read_text())
    typed = Summary.from_json(data)
    assert typed.steps == 200 and typed.law_diagnostics == {"max_gain_period": data["max_gain_period"]}
    assert {k: v for k, v in typed.to_json().items() if k in data} == data
    without = {k: v for k, v in data.items() if k != "max_abs_u"}
    with pytest.raises(ValueError, match=r"^not a summary: it lacks max_abs_u \("):
        Summary.from_json(without)
