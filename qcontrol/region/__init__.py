"""The region of attraction of control laws, measured on a grid of initial states
(:mod:`.study`), and the command ``qcontrol region`` (:mod:`.command`)."""

from .command import add_region_parser, cmd_region, write_region
from .study import (
    BOX,
    OUTCOMES,
    LawSpec,
    Region,
    RegionGrid,
    RegionPoint,
    default_laws,
    measure_region,
    parse_grid,
    parse_law,
)

__all__ = [
    "BOX",
    "OUTCOMES",
    "LawSpec",
    "Region",
    "RegionGrid",
    "RegionPoint",
    "add_region_parser",
    "cmd_region",
    "default_laws",
    "measure_region",
    "parse_grid",
    "parse_law",
    "write_region",
]
