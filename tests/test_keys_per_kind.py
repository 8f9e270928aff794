"""Keys per kind, in every table: a key that does not apply to the chosen kind (controller kinds,
reference kinds, plant backends) is refused with one line naming the kind and the keys that do
apply, from a file and from --set alike; --unset removes keys so that switching kind works.

The cases are made from the registries, so a kind or backend added later is covered too.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest
from conftest import EX2, ROOT

from qcontrol.cli import main
from qcontrol.controller import LAW_KINDS, comparison
from qcontrol.controller.law import LawKind
from qcontrol.errors import QcontrolInputError
from qcontrol.plants import BACKENDS
from qcontrol.reference import REFERENCE_KINDS, Constant, Sine, SumOfSines
from qcontrol.scenario import load_scenario, parse_scenario
from qcontrol.scenario.document import scenarios_markdown, toml_value
from qcontrol.schema import OPTIONAL, REQUIRED, Key

CHAIN3 = ROOT / "scenarios" / "chain3.toml"
SINE_KEYS = ("reference.amplitude", "reference.frequency")  # what example2's [reference] holds


def _value(key: Key) -> str:
    """A TOML value for ``key``: its example, else its default, else a number (a key refused for
    its kind is refused before its value is read)."""
    if key.example:
        return key.example
    return "1.0" if key.default in (REQUIRED, OPTIONAL, None) else toml_value(key.default)


def _names_override(message: str, key: str, problem: str) -> bool:
    """Whether ``message`` names the override that set ``key`` (not the file) and says ``problem``."""
    return message.startswith(f"--set {key}=") and f": {problem}" in message


def _refused(argv_tail: list[str], scenario: Path = EX2, unset: tuple[str, ...] = ()) -> str:
    """The one-line message a scenario with these --set overrides is refused with (load only)."""
    with pytest.raises(QcontrolInputError) as exc:
        load_scenario(scenario, argv_tail, list(unset))
    message = str(exc.value)
    assert "\n" not in message and "; " in message, message
    return message


# --------------------------------------------------------------------------------------------
# [controller]: every kind refuses every key of every other kind


def _law_cases() -> list[tuple[str, str, Key]]:
    cases = []
    for chosen, kind in LAW_KINDS.items():
        for other, other_kind in LAW_KINDS.items():
            if other == chosen or kind.keys is None or other_kind.keys is None:
                continue
            cases += [(chosen, other, key) for key in other_kind.keys.keys if key.name not in kind.keys.names]
    return cases


@pytest.mark.parametrize(("chosen", "other", "key"), _law_cases(),
                         ids=lambda v: v if isinstance(v, str) else v.name)
def test_a_controller_key_of_another_kind_is_refused(chosen: str, other: str, key: Key) -> None:
    message = _refused([f"controller.kind={chosen}", f"controller.{key.name}={_value(key)}"])
    owner = next(k for k, kind in LAW_KINDS.items()  # a key two kinds take is named by the first
                 if k != chosen and kind.keys is not None and key.name in kind.keys.names)
    assert _names_override(message, f"controller.{key.name}",
                           f"does not apply to kind '{chosen}' (it is a setting of kind '{owner}')")
    assert other == owner or key.name in LAW_KINDS[owner].keys.names
    applies = ", ".join(["kind", "delta", "c", *LAW_KINDS[chosen].keys.names])
    assert f"keys of [controller] with kind = '{chosen}' are {applies}" in message


@pytest.mark.parametrize("chosen", [k for k, kind in LAW_KINDS.items() if kind.keys is not None])
def test_an_unknown_key_in_a_kind_sub_table_is_refused(chosen: str) -> None:
    message = _refused([f"controller.{chosen}.no_such_key=1"])
    assert _names_override(message, f"controller.{chosen}.no_such_key", "unknown key")
    assert ", ".join(LAW_KINDS[chosen].keys.names) in message


def test_switching_the_law_from_the_command_line_keeps_working() -> None:
    """example2 holds both laws' settings in sub-tables: --set controller.kind picks one."""
    sc = load_scenario(EX2, ["controller.kind=comparison"])
    assert sc.controller.kind == "comparison" and sc.controller.settings.gain == 1.0
    # the kind's former name still loads, as the same kind, and so does its former sub-table
    old = load_scenario(EX2, ["controller.kind=baseline"])
    assert old.controller == sc.controller
    text = EX2.read_text().replace("[controller.comparison]", "[controller.baseline]")
    older = parse_scenario(text, base_dir=EX2.parent,
                           overrides=["controller.kind=baseline", "controller.baseline.gain=2"])
    assert older.controller.kind == "comparison" and older.controller.settings.gain == 2
    sc = load_scenario(EX2, ["controller.kappa=1.2"])  # kappa directly replaces the file's margin
    assert sc.controller.settings.kappa == 1.2 and sc.controller.settings.kappa_margin is None


def test_a_law_registered_from_python_gets_its_keys_unchecked(monkeypatch: pytest.MonkeyPatch,
                                                               capsys: pytest.CaptureFixture[str]) -> None:
    """A kind whose keys are None (registered from Python) receives the merged [controller] table
    and checks it itself; check and the documentation say so."""
    seen = {}

    def parse(table, ctx):  # the law's own factory: records what it was given
        seen.update(table.data)
        return comparison.ComparisonSettings(1.0, "adaptive")

    def build(settings, ctx):
        return comparison.ComparisonLaw.from_context(dataclasses.replace(ctx, base=settings[0]))

    kind = LawKind("mine", None, parse, build, comparison.structure)
    monkeypatch.setitem(LAW_KINDS, "mine", kind)
    assert main(["check", str(EX2), "--set", "controller.kind=mine", "--set", "controller.anything=3"]) == 0
    assert seen == {"anything": 3}
    assert "ok: " in capsys.readouterr().out
    assert "checked by the law's own factory" in scenarios_markdown()


# --------------------------------------------------------------------------------------------
# [reference]: every kind refuses every key of every other kind


def _required_settings(kind: str) -> list[str]:
    """--set overrides giving a kind its required keys."""
    keys = REFERENCE_KINDS[kind].keys.keys
    return [f"reference.{k.name}={_value(k)}" for k in keys if k.default is REQUIRED]


def _reference_cases() -> list[tuple[str, str, Key]]:
    cases = []
    for chosen, kind in REFERENCE_KINDS.items():
        for other, other_kind in REFERENCE_KINDS.items():
            if other != chosen:
                cases += [(chosen, other, key) for key in other_kind.keys.keys
                          if key.name not in kind.keys.names]
    return cases


@pytest.mark.parametrize(("chosen", "other", "key"), _reference_cases(),
                         ids=lambda v: v if isinstance(v, str) else v.name)
def test_a_reference_key_of_another_kind_is_refused(chosen: str, other: str, key: Key) -> None:
    overrides = [f"reference.kind={chosen}", *_required_settings(chosen),
                 f"reference.{key.name}={_value(key)}"]
    message = _refused(overrides, unset=SINE_KEYS)
    assert _names_override(message, f"reference.{key.name}", f"does not apply to kind '{chosen}'")
    applies = ", ".join(["kind", *REFERENCE_KINDS[chosen].keys.names])
    assert f"keys of [reference] with kind = '{chosen}' are {applies}" in message


def test_the_findings_on_the_reference_are_refused() -> None:
    """A constant reference ignored `offset` and `amplitude`; chain3's amplitude was silently
    dropped on --set reference.kind=constant."""
    message = _refused(["reference.kind=constant", "reference.offset=0.5"], unset=SINE_KEYS)
    assert _names_override(message, "reference.offset", "does not apply to kind 'constant'")
    assert "kind, value" in message
    message = _refused(["reference.kind=constant", "reference.amplitude=3"], unset=SINE_KEYS)
    assert _names_override(message, "reference.amplitude", "does not apply to kind 'constant'")
    message = _refused(["reference.kind=constant"], scenario=CHAIN3)
    assert "reference.amplitude: does not apply to kind 'constant'" in message


@pytest.mark.parametrize("kind", list(REFERENCE_KINDS))
def test_each_reference_kind_takes_its_settings_from_its_sub_table(kind: str) -> None:
    keys = REFERENCE_KINDS[kind].keys.keys
    overrides = [f"reference.kind={kind}"]
    overrides += [f"reference.{kind}.{k.name}={_value(k)}" for k in keys if k.example]
    sc = load_scenario(EX2, overrides, list(SINE_KEYS))
    expected = {"sine": Sine(1.0, 1.5), "constant": Constant(0.2),
                "sum_of_sines": SumOfSines((Sine(1.0, 1.5), Sine(0.2, 4.0, 0.5)))}
    assert sc.reference.signal == expected[kind]


# --------------------------------------------------------------------------------------------
# [plant]: each backend's keys belong in its own [plant.<backend>]


def _backend_cases() -> list[tuple[str, Key]]:
    return [(name, key) for name, backend in BACKENDS.items() if backend.section is not None
            for key in backend.section.keys]


@pytest.mark.parametrize(("backend", "key"), _backend_cases(),
                         ids=lambda v: v if isinstance(v, str) else v.name)
def test_a_backend_key_written_directly_in_plant_is_refused(backend: str, key: Key) -> None:
    message = _refused([f"plant.{key.name}={_value(key)}"])
    assert _names_override(message, f"plant.{key.name}",
                           f"does not apply to [plant] (it is a setting of backend '{backend}')")
    assert f"write it in [plant.{backend}]" in message


@pytest.mark.parametrize("backend", [name for name, b in BACKENDS.items() if b.section is None])
def test_a_backend_without_settings_refuses_a_section(backend: str) -> None:
    message = _refused([f"plant.{backend}.anything=1"])
    assert f"plant.{backend}: backend '{backend}' takes no settings" in message


@pytest.mark.parametrize("backend", [name for name, b in BACKENDS.items() if b.section is not None])
def test_an_unknown_key_in_a_backend_section_is_refused(backend: str) -> None:
    message = _refused([f"plant.{backend}.no_such_key=1"])
    assert _names_override(message, f"plant.{backend}.no_such_key", "unknown key")


def test_the_mujoco_section_needs_a_plant_of_order_two_or_a_filter_actuator(tmp_path: Path) -> None:
    """The MuJoCo backend models one joint, or (order 3) one driven through a filter actuator read
    by an activation sensor: a [plant.mujoco] on an order-3 plant without one is refused at load,
    whatever backend runs."""
    text = CHAIN3.read_text() + (
        f'\n[plant.mujoco]\nmodel = "{ROOT}/models/slider.xml"\njoint = "slide"\n'
        'position_sensor = "position"\nvelocity_sensor = "velocity"\nactuator = "force"\n'
    )
    (tmp_path / "c3.toml").write_text(text)
    message = _refused([], scenario=tmp_path / "c3.toml")
    assert "plant.mujoco: plant order 3 on MuJoCo reads x3 from the filter actuator, but activation_sensor " \
        "is missing" in message


# --------------------------------------------------------------------------------------------
# --unset


def test_unset_turns_example2_into_a_set_point_run(capsys: pytest.CaptureFixture[str]) -> None:
    argv = ["--unset", "reference.amplitude", "--unset", "reference.frequency",
            "--set", "reference.kind=constant", "--set", "reference.value=0.2"]
    sc = load_scenario(EX2, ["reference.kind=constant", "reference.value=0.2"], list(SINE_KEYS))
    assert sc.reference.signal == Constant(0.2) and sc.unset == SINE_KEYS
    assert main(["run", str(EX2), *argv, "--backend", "ode", "--duration", "3", "-q"]) == 0
    out = capsys.readouterr().out
    assert "scenario example2 on ode: 3000 steps" in out


def test_unset_then_set_the_same_key_sets_it() -> None:
    sc = load_scenario(EX2, ["reference.amplitude=0.5"], ["reference.amplitude"])
    assert sc.reference.signal.amplitude == 0.5


def test_unset_a_whole_sub_table() -> None:
    sc = load_scenario(EX2, ["simulation.backend=ode"], ["plant.mujoco"])
    assert "mujoco" not in sc.backends


@pytest.mark.parametrize(("key", "expected"), [
    ("reference.amplitud", "--unset reference.amplitud: {f} has no key amplitud in [reference]; the keys in "
     "[reference] are kind, amplitude, frequency"),
    ("controller.kappa_margin", "--unset controller.kappa_margin: {f} has no key kappa_margin in "
     "[controller]; it is in a sub-table: --unset controller.proposed.kappa_margin; the keys in "
     "[controller] are kind, delta, c, proposed, comparison"),
    ("simulation.dt.x", "--unset simulation.dt.x: simulation.dt is a value, not a table; the keys in "
     "[simulation] are duration, dt, backend"),
    ("nosuch.foo", "--unset nosuch.foo: {f} has no table [nosuch]; the keys in the top level are "
     "scenario, plant, controller, reference, simulation"),
    ("a..b", "--unset 'a..b': not a key path; write e.g. --unset reference.amplitude"),
])
def test_unset_of_a_key_that_is_not_there_is_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                                     key: str, expected: str) -> None:
    assert main(["run", str(EX2), "--unset", key, "--out", str(tmp_path / "out"), "-q"]) == 2
    err = capsys.readouterr().err
    assert err == f"qcontrol: error: {expected.format(f=EX2)}\n"
    assert list(tmp_path.iterdir()) == []
