"""The edits made to a scenario file's data before it is validated: ``--unset key`` removals and
``--set key=value`` overrides (or a dict of them, from the API), and the messages that name the
override which gave a bad value (docs/scenarios.md)."""

from __future__ import annotations

import re
import tomllib
from collections.abc import Mapping, Sequence
from typing import Any

from ..errors import KeyNotForKind, OverrideError, QcontrolInputError, brief, shown
from ..schema import show_key
from .limits import check_limits

Overrides = Sequence[str] | Mapping[str, Any]  # "key=value" strings (the value read as TOML), or a dict


def check_overrides(overrides: object, function: str) -> None:
    """Overrides as :func:`load_scenario` takes them, else one line naming ``function``."""
    strings = isinstance(overrides, list | tuple) and all(isinstance(o, str) for o in overrides)
    if not strings and not (isinstance(overrides, Mapping) and all(isinstance(k, str) for k in overrides)):
        raise QcontrolInputError(f"{function}: overrides must be a dict {{\"key\": value}} or a list of "
                                 f"\"key=value\" strings, got {overrides!r}")


def command_line_fix(exc: KeyNotForKind, given: Sequence[str | tuple[str, Any]]) -> QcontrolInputError:
    """A key the chosen kind does not take, with the fix on the command line when the overrides
    chose the kind (the key is then the file's: ``--unset`` it) or set the key (named as the
    override: leave it out)."""
    keys = [(item.partition("=")[0] if isinstance(item, str) else item[0]).strip() for item in given]
    table = exc.key.rsplit(".", 1)[0]
    if exc.key in keys:
        item = given[len(keys) - 1 - keys[::-1].index(exc.key)]
        detail = str(exc).split(f": {exc.key}: ", 1)[-1]
        return OverrideError(override_label(item), f"{detail}; or leave out --set {exc.key}=...", item)
    if f"{table}.kind" in keys:
        return QcontrolInputError(f"{exc}; or, as the kind came from --set, remove the file's key: "
                                  f"--unset {exc.key}")
    return QcontrolInputError(str(exc))


def from_override(exc: QcontrolInputError, source: str, given: Sequence[str | tuple[str, Any]],
                   file_data: dict) -> QcontrolInputError:
    """A problem the validator found at a key (``SOURCE: key: problem; fix``), named as the override
    that gave the key its value when one did (the last one, as it wins): the key itself or a table
    above it was set, or the key is a table the override made (it is not in the file)."""
    prefix = f"{source}: "
    message = str(exc)
    if not given or not message.startswith(prefix):
        return exc
    rest = message[len(prefix):]
    at = rest.split(": ", 1)[0]
    for item in reversed(given):
        key = (item.partition("=")[0] if isinstance(item, str) else item[0]).strip()
        if at == key:
            return OverrideError(override_label(item), rest[len(at) + 2:], item)
        inside = at.startswith((f"{key}.", f"{key}["))
        made = key.startswith(f"{at}.") and not _has_key(file_data, at)
        if inside or made:
            return OverrideError(override_label(item), rest, item)
    return exc


def _has_key(data: dict, dotted: str) -> bool:
    node: Any = data
    for part in dotted.split("."):
        if not isinstance(node, dict) or part not in node:
            return False
        node = node[part]
    return True


def override_label(item: str | tuple[str, Any]) -> str:
    """How a message names one override: ``--set key=value`` for a string (as on the command
    line), ``override key=value`` for an entry of a dict (the API); a long value is cut short."""
    if isinstance(item, str):
        key, sep, raw = item.partition("=")
        return f"--set {shown(key.strip())}{sep}{brief(raw.strip())}"
    return f"override {shown(item[0])}={brief(repr(item[1]))}"


def as_given(overrides: Overrides) -> tuple[str | tuple[str, Any], ...]:
    """The overrides as entries: ``"key=value"`` strings, or ``(key, value)`` pairs from a dict
    (entries already in that form pass through)."""
    if isinstance(overrides, Mapping):
        return tuple((str(key), value) for key, value in overrides.items())
    if isinstance(overrides, str):
        raise QcontrolInputError(f"overrides {overrides!r}: give a list of \"key=value\" strings or a dict; "
                                 f"e.g. [{overrides!r}]")
    return tuple(item if isinstance(item, str) else (str(item[0]), item[1]) for item in overrides)


def remove_key(data: dict, key: str, source: str) -> None:
    """Remove one ``--unset`` key (a dotted path) from the file's data; a key that is not there is
    one line naming where it would be and what is there instead."""
    parts = key.strip().split(".")
    if not key.strip() or any(not p for p in parts):
        raise QcontrolInputError(f"--unset {key!r}: not a key path; write e.g. --unset reference.amplitude")
    node, where = data, "the top level"
    for depth, part in enumerate(parts[:-1]):
        child = node.get(part)
        if not isinstance(child, dict):
            path = ".".join(parts[: depth + 1])
            problem = (f"{path} is a value, not a table" if part in node
                       else f"{source} has no table [{path}]")
            raise QcontrolInputError(f"--unset {key}: {problem}; " + _present(node, where))
        node, where = child, f"[{'.'.join(parts[: depth + 1])}]"
    last = parts[-1]
    if last not in node:
        raise QcontrolInputError(f"--unset {key}: {source} has no key {last} in {where}; "
                                 + _moved(node, parts) + _present(node, where))
    del node[last]


def _moved(node: dict, parts: Sequence[str]) -> str:
    """A hint when the key sits in a sub-table of the table named (e.g. a kind's settings)."""
    holders = [name for name, value in node.items() if isinstance(value, dict) and parts[-1] in value]
    if not holders:
        return ""
    inner = ".".join([*parts[:-1], holders[0], parts[-1]])
    return f"it is in a sub-table: --unset {inner}; "


def _present(node: dict, where: str) -> str:
    names = ", ".join(show_key(k) for k in node) or "none"
    return f"the keys in {where} are {names}"


def apply_override(data: dict, item: str) -> None:
    """Apply one ``key.path=value`` override; the value is read as TOML, else as a string."""
    key, sep, raw = item.partition("=")
    key = key.strip()
    if not sep or not key:
        raise OverrideError(override_label(item), "expected KEY=VALUE; write e.g. "
                            "--set controller.kappa_margin=0.1", item)
    set_key(data, key, override_value(raw.strip()), item)


# a decimal number as TOML writes it (no underscores), the usual value of an override
_DECIMAL = re.compile(r"[+-]?(?:0|[1-9][0-9]*)(\.[0-9]+)?([eE][+-]?[0-9]+)?")


def override_value(raw: str) -> Any:
    """The value of ``key=raw`` read as TOML, else the text itself as a string. A decimal number,
    or an array of them on one line (``[0.1, -2]``, as ``plant.x0``), is read directly, as TOML
    reads it: ``float`` of its text, or ``int``."""
    numbers = raw[1:-1].split(",") if raw.startswith("[") and raw.endswith("]") else [raw]
    if len(numbers) > 1 and not numbers[-1].strip(" \t"):  # an array's trailing comma
        numbers.pop()
    matched = [_DECIMAL.fullmatch(text.strip(" \t")) for text in numbers]
    if all(matched):
        try:
            values = [float(m[0]) if m[1] or m[2] else int(m[0]) for m in matched]
            return values if raw.startswith("[") else values[0]
        except ValueError:  # an integer of more digits than Python converts: as TOML fails on it
            pass
    try:
        return tomllib.loads(f"v = {raw}")["v"]
    except (tomllib.TOMLDecodeError, RecursionError, ValueError):
        return raw


def owned(data: dict, key: str) -> None:
    """Make each table along the dotted ``key`` a copy of its own in ``data`` (before an override
    writes there: the tables of a file read once may be shared by its variants)."""
    node = data
    for part in key.split(".")[:-1]:
        child = node.get(part)
        if not isinstance(child, dict):
            return
        node[part] = node = dict(child)


def set_key(data: dict, key: str, value: Any, item: str | tuple[str, Any]) -> None:
    """Set the dotted ``key`` of the scenario's data to ``value`` (tables made as needed); ``item``
    is the override as given, which a problem names."""
    parts = key.split(".")
    if not key or any(not p for p in parts):
        raise OverrideError(override_label(item), f"key {shown(key)} has an empty part; write e.g. "
                            "--set controller.kappa_margin=0.1", item)
    node = data
    for part in parts[:-1]:
        child = node.setdefault(part, {})
        if not isinstance(child, dict):
            raise OverrideError(override_label(item), f"{part!r} is a value, not a table; set "
                                f"{'.'.join(parts[:-1])} directly", item)
        node = child
    try:
        check_limits(value, "", key)
    except QcontrolInputError as exc:
        raise OverrideError(override_label(item), str(exc).removeprefix(f"{key}: "), item) from None
    node[parts[-1]] = value
