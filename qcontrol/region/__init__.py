"""The region of attraction of control laws, measured on a grid of initial states
(:mod:`.study`) and written as region.csv, region.json and region.png (:func:`write_region`); the
command ``qcontrol region`` is :mod:`qcontrol.cli.region_command`."""

from .study import (
    BOX,
    OUTCOMES,
    LawSpec,
    Region,
    RegionGrid,
    RegionPoint,
    check_region_size,
    default_laws,
    measure_region,
    parse_grid,
    parse_law,
    write_region,
)

__all__ = [
    "BOX",
    "OUTCOMES",
    "LawSpec",
    "Region",
    "RegionGrid",
    "RegionPoint",
    "check_region_size",
    "default_laws",
    "measure_region",
    "parse_grid",
    "parse_law",
    "write_region",
]
