"""Sweep grids: ``--grid key=v1,v2,...`` options and their product, with random initial states."""

from __future__ import annotations

import itertools
import math
import tomllib
from collections.abc import Sequence

import numpy as np

from ..errors import QcontrolInputError, shown

MAX_RUNS = 1_000_000  # runs in one sweep (grid points times initial states): a bound on memory and time
MAX_SEED = 2**63 - 1
_OPEN, _CLOSE, _QUOTES = "[{", "]}", "\"'"


def split_values(item: str, raw: str) -> list[str]:
    """The values of ``--grid KEY=raw``, split at the commas outside brackets and quotes
    (``plant.x0=[0.1,0.2],[0.3,0.4]``, ``plant.psi="min(x1, x2)","x1"``); unbalanced brackets or an
    open quote are refused."""
    values, depth, quote, start = [], 0, "", 0
    for i, ch in enumerate(raw + ","):
        if quote:
            quote = "" if ch == quote and i < len(raw) else quote
            continue
        if ch in _QUOTES and i < len(raw):
            quote = ch
        elif ch in _OPEN:
            depth += 1
        elif ch in _CLOSE:
            depth -= 1
            if depth < 0:
                raise QcontrolInputError(f"--grid {shown(item)}: a {ch!r} closes nothing; balance the "
                                         "brackets of each value, e.g. plant.x0=[0.1, 0.2],[0.3, 0.4]")
        elif ch == "," and depth == 0:
            values.append(raw[start:i].strip())
            start = i + 1
    if quote or depth:
        what = "quote" if quote else "bracket"
        raise QcontrolInputError(f"--grid {shown(item)}: an unclosed {what}; close it, "
                                 "e.g. plant.x0=[0.1, 0.2],[0.3, 0.4]")
    if any(not v for v in values):
        raise QcontrolInputError(f"--grid {shown(item)}: empty value; list values as v1,v2,...")
    for value in values:
        _check_value(item, value)
    return values


def _check_value(item: str, value: str) -> None:
    """A value that looks like a TOML array, table or string must parse as one (a bare word is
    read as a string, as ``--set`` reads it)."""
    if value[0] not in _OPEN + _QUOTES and not any(ch in value for ch in _OPEN + _CLOSE + _QUOTES):
        return
    try:
        tomllib.loads(f"v = {value}")
    except tomllib.TOMLDecodeError as exc:
        raise QcontrolInputError(f"--grid {shown(item)}: the value {shown(value)} does not parse as TOML "
                                 f"({exc}); write e.g. [0.1, 0.2] or \"text\"") from None


def parse_grid(items: Sequence[str]) -> list[tuple[str, list[str]]]:
    """``["key=v1,v2", ...]`` -> ``[(key, [v1, v2]), ...]`` (values kept as text, read as TOML
    by the scenario loader); see :func:`split_values`."""
    grid = []
    for item in items:
        key, sep, raw = item.partition("=")
        key = key.strip()
        if not sep or not key or not raw.strip():
            raise QcontrolInputError(f"--grid {shown(item)}: expected KEY=V1,V2,... such as "
                                     "controller.kappa_margin=0.1,0.5,1.1")
        values = split_values(item, raw)
        if any(k == key for k, _ in grid):
            raise QcontrolInputError(f"--grid {key}: given twice; list all its values in one --grid")
        grid.append((key, values))
    return grid


def check_size(grid: Sequence[tuple[str, list[str]]], random_initial: int, seed: int) -> int:
    """The number of runs, refused as one line when there is none to make or more than
    :data:`MAX_RUNS`; ``random_initial`` and ``seed`` are checked too."""
    if not 0 <= seed <= MAX_SEED:
        raise QcontrolInputError(f"--seed {seed}: must be an integer from 0 to 2**63 - 1; e.g. --seed 0")
    if random_initial < 0:
        raise QcontrolInputError(f"--random-initial {random_initial}: must be >= 0; e.g. --random-initial 10")
    if not grid and not random_initial:
        raise QcontrolInputError("sweep: nothing to sweep; give --grid KEY=V1,V2,... or --random-initial N "
                                 "(for a single run use qcontrol run)")
    runs = math.prod(len(values) for _, values in grid) * max(1, random_initial)
    if runs > MAX_RUNS:
        raise QcontrolInputError(f"sweep: {runs} runs is more than the {MAX_RUNS} a sweep may make; "
                                 "split it into several sweeps")
    return runs


def grid_points(grid: Sequence[tuple[str, list[str]]], random_initial: int = 0, seed: int | None = None,
                x0_scale: float = 1.0, order: int = 2) -> list[dict[str, str]]:
    """The product of the grids, times ``random_initial`` initial states per point (uniform in
    ``[-x0_scale, x0_scale]^n`` from ``seed``); each point maps key -> value text."""
    keys = [k for k, _ in grid]
    points = [dict(zip(keys, combo, strict=True)) for combo in itertools.product(*(v for _, v in grid))]
    if random_initial <= 0:
        return points
    rng = np.random.default_rng(seed)
    starts = rng.uniform(-x0_scale, x0_scale, size=(random_initial, order))
    texts = ["[" + ", ".join(repr(float(v)) for v in x) + "]" for x in starts]
    return [p | {"plant.x0": text} for p in points for text in texts]
