"""Sweep grids: ``--grid key=v1,v2,...`` options and their product, with random initial states."""

from __future__ import annotations

import itertools
from collections.abc import Sequence

import numpy as np

from ..errors import QcontrolInputError


def parse_grid(items: Sequence[str]) -> list[tuple[str, list[str]]]:
    """``["key=v1,v2", ...]`` -> ``[(key, [v1, v2]), ...]`` (values kept as text, read as TOML
    by the scenario loader). A value that is a list (``plant.x0=[0.1,0.2],[0.3,0.4]``) is split
    at the top level only."""
    grid = []
    for item in items:
        key, sep, raw = item.partition("=")
        key = key.strip()
        if not sep or not key or not raw.strip():
            raise QcontrolInputError(f"--grid {item!r}: expected KEY=V1,V2,... such as "
                                     "controller.kappa_margin=0.1,0.5,1.1")
        values, depth, start = [], 0, 0
        for i, ch in enumerate(raw + ","):
            depth += ch in "[{" and 1 or (-1 if ch in "]}" else 0)
            if ch == "," and depth == 0:
                value = raw[start:i].strip()
                if not value:
                    raise QcontrolInputError(f"--grid {item!r}: empty value; list values as v1,v2,...")
                values.append(value)
                start = i + 1
        if any(k == key for k, _ in grid):
            raise QcontrolInputError(f"--grid {key}: given twice; list all its values in one --grid")
        grid.append((key, values))
    return grid


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
