"""Law classes registered from Python: :func:`register_law_class` makes a subclass of the paper's
law (:class:`~.proposed.PaperLaw`), of the comparison law (:class:`~.comparison.ComparisonLaw`)
or of the shared coordinates (:class:`~.backstepping.BacksteppingLaw`) a controller kind.

Such a class is written in the column form the built-in laws are written in (columns of any
form, :mod:`qcontrol.columns`: ``(batch,)`` arrays for a batch), so it runs a single run in the
engine's fast form as a built-in law does; it is built by ``cls.from_context(context)`` with a
:class:`~.law.LawContext` carrying n, dt, the control period, delta, c, its own keys
(``context.settings``) and, with ``extends``, the parsed settings of the built-in kind it extends
(``context.base``, read from ``[controller.<extends>]``).
"""

from __future__ import annotations

from collections.abc import Hashable, Sequence
from dataclasses import dataclass, replace
from types import MappingProxyType
from typing import Any

from ..errors import QcontrolInputError
from ..schema import Table
from .backstepping import BacksteppingLaw
from .law import LAW_KINDS, LawContext, LawKind, check_kind_name, register_kind
from .user import _freeze, _thaw
from .user_diagnostics import checked_class_diagnostics

EXTENDABLE = ("proposed", "comparison")


@dataclass(frozen=True)
class ClassSettings:
    """A class kind's settings: the parsed settings of the kind it extends, and its own keys."""

    base: Any
    own: tuple[tuple[str, Any], ...]

    @property
    def table(self) -> MappingProxyType:
        return MappingProxyType(_thaw(self.own))


def register_law_class(kind: str, cls: type, *, extends: str | None = None, keys: Sequence[str] = (),
                       replace: bool = False) -> None:
    """Make ``controller.kind = "<kind>"`` select the law ``cls.from_context(context)``.

    ``cls`` subclasses :class:`~.proposed.PaperLaw`, :class:`~.comparison.ComparisonLaw` or
    :class:`~.backstepping.BacksteppingLaw`. ``extends`` (``"proposed"`` or ``"comparison"``): the
    kind whose ``[controller.<extends>]`` settings are parsed, checked and handed on as
    ``context.base`` (keys of that kind given in ``[controller.<kind>]`` take precedence).
    ``keys``: the law's own keys, read from ``[controller.<kind>]`` into ``context.settings``
    (others are refused). ``replace=True`` replaces a law registered before under this name.
    """
    check_kind_name(kind, "register_law_class")
    if not (isinstance(cls, type) and issubclass(cls, BacksteppingLaw)):
        raise QcontrolInputError(f"register_law_class: {cls!r} for {kind!r} must be a class deriving from "
                                 "qcontrol.PaperLaw, qcontrol.ComparisonLaw or qcontrol.BacksteppingLaw")
    if extends is not None and extends not in EXTENDABLE:
        raise QcontrolInputError(f"register_law_class: extends={extends!r} for {kind!r}: use one of "
                                 f"{', '.join(EXTENDABLE)}, or None")
    if isinstance(keys, str) or not all(isinstance(k, str) for k in keys):
        raise QcontrolInputError(f"register_law_class: keys for {kind!r} must be a list of key names, "
                                 f"got {keys!r}")
    if not isinstance(replace, bool):
        raise QcontrolInputError(f"register_law_class: replace must be True or False, got {replace!r}")
    made = ClassKind(kind, cls, extends, tuple(keys))
    bounds = made.bounds if extends is not None and LAW_KINDS[extends].bounds is not None else None
    register_kind(LawKind(kind, None, made.parse, made.build, made.structure, extends=extends,
                          bounds=bounds), replace=replace)


class ClassKind:
    """A controller kind made by :func:`register_law_class`."""

    def __init__(self, kind: str, cls: type, extends: str | None, keys: tuple[str, ...]) -> None:
        self.kind, self.cls, self.extends, self.keys = kind, cls, extends, keys

    def parse(self, table: Table, ctx: LawContext) -> ClassSettings:
        base_names = () if self.extends is None else LAW_KINDS[self.extends].keys.names
        own = {k: v for k, v in table.data.items() if k not in base_names}
        for key in own:
            if key not in self.keys:
                allowed = ", ".join((*self.keys, *base_names)) or "none"
                raise table.error(key, f"unknown key for kind {self.kind!r}",
                                  f"keys of this kind are {allowed} (remove it or check its spelling)")
        base = None
        if self.extends is not None:
            base = self._base_settings(table, ctx, base_names)
        settings = ClassSettings(base, _freeze(own))
        try:
            self.build([settings], ctx)
        except QcontrolInputError as exc:
            raise QcontrolInputError(f"{ctx.source}: controller kind {self.kind!r}: {exc}") from None
        return settings

    def _base_settings(self, table: Table, ctx: LawContext, base_names: Sequence[str]) -> Any:
        """The extended kind's settings: its sub-table, with its keys given for this kind on top."""
        root = ctx.controller
        sub = root.data.get(self.extends, {}) if root is not None else {}
        if not isinstance(sub, dict):
            raise root.error(self.extends, "must be a table", f"write [{root.path(self.extends)}]")
        data = dict(sub) | {k: v for k, v in table.data.items() if k in base_names}
        where = root.path(self.extends) if root is not None else f"controller.{self.extends}"
        return LAW_KINDS[self.extends].parse(Table(data, table.source, where, base_names), ctx)

    def build(self, settings: Sequence[ClassSettings], ctx: LawContext) -> BacksteppingLaw:
        first = settings[0]
        law = self.cls.from_context(replace(ctx, settings=first.table, base=first.base, controller=None))
        if not isinstance(law, BacksteppingLaw):
            raise QcontrolInputError(f"{self.cls.__name__}.from_context must return the law, got "
                                     f"{type(law).__name__}")
        if law.diagnostics != ():  # none declared: nothing to check (and no attribute of its own added)
            law.diagnostics = checked_class_diagnostics(law.diagnostics, self.kind)
        return law

    @staticmethod
    def structure(settings: ClassSettings, ctx: LawContext) -> Hashable:
        return settings  # variants share a batch only when their settings are equal

    def bounds(self, settings: ClassSettings) -> tuple:
        """The bounding functions r of the extended paper's law, checked along single runs."""
        return LAW_KINDS[self.extends].bounds(settings.base)
