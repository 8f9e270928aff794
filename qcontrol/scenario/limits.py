"""Bounds on what a scenario's data may hold, checked as soon as it is read (the file, each
``--set`` value, each value of an API dict), so ``check`` and ``run`` refuse the same input with
one line instead of running out of memory, time or stack later.

Every key has its own range besides (e.g. ``metrics.samples``, a disturbance's ``start``); these
limits are the ones no key should ever need: how deep arrays and tables nest, how long a list or
a string is, how large an integer literal is.
"""

from __future__ import annotations

from typing import Any

from ..errors import QcontrolInputError

MAX_DEPTH = 8  # nested arrays or tables inside a key's value (x0 is 1, a list of tables 2)
MAX_LIST = 100_000  # entries of one list
MAX_TEXT = 100_000  # characters of one string (an expression)
MAX_INTEGER = 2**63 - 1  # an integer literal's magnitude (a seed is at most this)


def check_limits(value: Any, where: str, path: str = "") -> None:
    """Refuse, as one line naming ``where`` and the key path, data beyond the module's limits
    (walked without recursion, so depth alone cannot exhaust the stack)."""
    stack = [(value, path, 0)]
    while stack:
        item, at, depth = stack.pop()
        named = ": ".join(part for part in (where, at) if part)
        if depth > MAX_DEPTH:
            raise QcontrolInputError(f"{named}: nested more than {MAX_DEPTH} levels deep; no key takes such "
                                     "a value: flatten it")
        if isinstance(item, bool):
            continue
        if isinstance(item, int) and abs(item) > MAX_INTEGER:
            digits = len(str(abs(item)))
            raise QcontrolInputError(f"{named}: an integer of {digits} digits is beyond the limit 2**63 - 1 "
                                     "of an integer literal; write a smaller number (or a float, e.g. 1e20)")
        elif isinstance(item, str) and len(item) > MAX_TEXT:
            raise QcontrolInputError(f"{named}: the string is {len(item)} characters long, more than "
                                     f"{MAX_TEXT}; shorten it")
        elif isinstance(item, list):
            if len(item) > MAX_LIST:
                raise QcontrolInputError(f"{named}: the list has {len(item)} entries, more than {MAX_LIST}; "
                                         "shorten it")
            stack.extend((v, f"{at}[{i}]", depth + 1) for i, v in enumerate(item))
        elif isinstance(item, dict):
            inner = depth + (1 if at else 0)  # the top-level tables are not nesting
            stack.extend((v, f"{at}.{k}" if at else str(k), inner) for k, v in item.items())
