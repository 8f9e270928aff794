"""Bad input of the sensor keys ([quantizer], [quantizer.input], plant.input_gain, t in the
plant's terms): through the real command line, each one line naming the file and the key with
the fix, exit status 2, nothing created (the catalogue's own checks, test_bad_input.py)."""

from __future__ import annotations

from pathlib import Path

import pytest
from conftest import EX2
from test_bad_input import _assert_nothing_written, _assert_one_line, _edit, _prepare, case

from qcontrol.cli import main

STEP = "delta = 0.01               # quantization step, eq. (3)\n"


def quantizer(table: str) -> str:
    """Example 2 with its controller.delta replaced by a [quantizer] table."""
    return _edit(EX2, STEP, "") + "\n" + table


def plant(old: str, new: str) -> str:
    return _edit(EX2, old, new)


CATALOGUE = {
    "list of the wrong length": case(quantizer("[quantizer]\ndelta = [0.01, 0.02, 0.03]\n"),
                                     "quantizer.delta", "has 3 entries, expected 2"),
    "input list of the wrong length": case(quantizer("[quantizer]\ndelta = 0.01\n[quantizer.input]\n"
                                                     "delta = [0.1, 0.2]\n"), "quantizer.input.delta",
                                           "expected 1"),
    "delta zero": case(quantizer("[quantizer]\ndelta = 0.0\n"), "quantizer.delta", "must be > 0"),
    "delta negative in a list": case(quantizer("[quantizer]\ndelta = [0.01, -0.5]\n"), "quantizer.delta[1]",
                                     "must be > 0"),
    "hysteresis delta negative": case(quantizer("[quantizer]\nkind = \"hysteresis\"\ndelta = -1.0\n"),
                                      "quantizer.delta", "must be > 0"),
    "rho one": case(quantizer("[quantizer]\nkind = \"logarithmic\"\nrho = 1.0\nu_min = 0.01\n"),
                    "quantizer.rho", "(0, 1)"),
    "rho zero": case(quantizer("[quantizer]\nkind = \"logarithmic\"\nrho = 0.0\nu_min = 0.01\n"),
                     "quantizer.rho", "> 0"),
    "u_min zero": case(quantizer("[quantizer]\nkind = \"logarithmic\"\nrho = 0.9\nu_min = 0.0\n"),
                       "quantizer.u_min", "> 0"),
    "range zero": case(quantizer("[quantizer]\ndelta = 0.01\nrange = 0.0\n"), "quantizer.range", "> 0"),
    "range negative in a list": case(quantizer("[quantizer]\ndelta = 0.01\nrange = [3.0, -1.0]\n"),
                                     "quantizer.range[1]", "> 0"),
    "input_gain zero": case(plant("order = 2\n", "order = 2\ninput_gain = 0.0\n"), "plant.input_gain",
                            "must be > 0"),
    "input_gain negative": case(plant("order = 2\n", "order = 2\ninput_gain = -2.0\n"), "plant.input_gain",
                                "must be > 0"),
    "t in a bounding function": case(_edit(EX2, '"1 + q2**2"', '"1 + q2**2 + cos(t)"'),
                                     "controller.proposed.r[0]", "t (time) is not allowed",
                                     "function of the readings"),
    "hysteresis with a range": case(quantizer("[quantizer]\nkind = \"hysteresis\"\ndelta = 0.01\n"
                                              "range = 3.0\n"), "quantizer.range",
                                    "does not apply to kind 'hysteresis'"),
    "logarithmic with a step": case(quantizer("[quantizer]\nkind = \"logarithmic\"\nrho = 0.9\nu_min = 0.01\n"
                                              "delta = 0.01\n"), "quantizer.delta",
                                    "does not apply to kind 'logarithmic'"),
    "hysteresis on the input": case(quantizer("[quantizer]\ndelta = 0.01\n[quantizer.input]\n"
                                              "kind = \"hysteresis\"\ndelta = 1.0\n"), "quantizer.input.kind",
                                    "not available for the input"),
    "a step in two places": case(_edit(EX2, "", "") + "\n[quantizer]\ndelta = 0.01\n", "controller.delta",
                                 "together with a [quantizer] table"),
    "no step anywhere": case(_edit(EX2, STEP, ""), "controller.delta", "missing"),
    "comparison law with a term in t": case(plant('"sin(x1)"', '"sin(x1)*cos(t)"').replace(
        'kind = "proposed"          # the paper', 'kind = "comparison"          # the paper'), "plant",
        "terms in t"),
}


@pytest.mark.parametrize("name", list(CATALOGUE))
def test_sensor_keys_refused_in_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                         monkeypatch: pytest.MonkeyPatch, name: str) -> None:
    c = CATALOGUE[name]
    monkeypatch.chdir(tmp_path)
    argv, out = _prepare(tmp_path, c)
    assert main(argv) == 2
    _assert_one_line(capsys.readouterr().err, c, argv[1])
    _assert_nothing_written(tmp_path, out)
