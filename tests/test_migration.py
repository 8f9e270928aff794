"""The names docs/laws.md's 'Migrating from 0.2' lists are refused in one line naming their
replacement, and the table there names every one of them."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import ROOT

import qcontrol
import qcontrol.controller
from qcontrol.assembly import build_law, build_plant, build_quantizer, build_reference
from qcontrol.engine import simulate


@pytest.mark.parametrize("module, name, replacement", [
    (qcontrol, "SteppedLaw", "qcontrol.Law"),
    (qcontrol, "register_law_class", "qcontrol.register_law(kind, cls"),
    (qcontrol.controller, "ProposedController", "qcontrol.PaperLaw"),
    (qcontrol.controller, "ComparisonController", "qcontrol.ComparisonLaw"),
])
def test_a_removed_name_says_what_replaces_it(module, name: str, replacement: str) -> None:
    with pytest.raises(AttributeError) as caught:
        getattr(module, name)
    message = str(caught.value)
    assert replacement in message and "\n" not in message
    assert name in (ROOT / "docs" / "laws.md").read_text().split("## Migrating from 0.2")[1]


def test_an_unknown_name_is_still_an_ordinary_attribute_error() -> None:
    with pytest.raises(AttributeError, match="has no attribute 'nothing_here'"):
        qcontrol.nothing_here  # noqa: B018


def test_with_context_is_refused_naming_from_context() -> None:
    with pytest.raises(qcontrol.QcontrolInputError, match=r"^register_law: no argument with_context=; give "
                                                          r"the law a class method from_context\(context\)"):
        qcontrol.register_law("old-style", lambda table, context: None, with_context=True)


def test_simulate_with_its_parts_one_by_one_names_the_run_spec() -> None:
    sc = qcontrol.load_scenario("example2", {"simulation.duration": 0.01})
    parts = (build_plant(sc, "ode"), build_law([sc]), build_quantizer(sc), build_reference(sc),
             np.array(sc.x0), 0.01, 1e-3)
    with pytest.raises(TypeError, match=r"^simulate takes one RunSpec: simulate\(RunSpec\(plant=") as caught:
        simulate(*parts)
    assert "\n" not in str(caught.value)
