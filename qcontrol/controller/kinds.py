"""The one way a control law becomes a controller kind: :func:`register_law`, for the built-in
laws (at import, :mod:`qcontrol.controller`) and users' alike.

A law comes in one of two forms:

* a per-copy law of the :class:`~.user.Law` protocol (numpy arrays of one copy; its state by RK4
  of ``state_rate`` or by its own ``advance``), made by ``factory(table, n)``, or by
  ``factory.from_context(context)`` when the factory has that class method; the adapter
  :class:`~.user.UserLaw` drives one law per copy;
* a column-form class (a subclass of :class:`~.backstepping.BacksteppingLaw`, as the paper's law
  :class:`~.proposed.PaperLaw` and the comparison law :class:`~.comparison.ComparisonLaw` are),
  made by ``cls.from_context(context)`` for a whole batch, and run on the engine's fast paths.

Its keys are declared: a list of names (others are refused), a :class:`~.law.LawKeys` (typed
keys and how they are parsed, batched and bounded: the built-in laws), or None (the factory
checks its table itself, :func:`~.user.check_keys`). ``extends`` names a kind whose
``[controller.<extends>]`` settings are parsed, checked and handed on as ``context.base``.
"""

from __future__ import annotations

from collections.abc import Callable, Hashable, Sequence
from dataclasses import dataclass, replace
from types import MappingProxyType
from typing import Any

from ..errors import QcontrolInputError
from ..schema import Table
from .backstepping import BacksteppingLaw
from .law import CHAIN, LAW_KINDS, LawContext, LawKeys, LawKind, add_kind, check_kind_name
from .user import UserKind, _freeze, _thaw
from .user_diagnostics import checked_class_diagnostics

# Arguments register_law took before, and what replaces them (a one-line refusal names the fix)
REMOVED_ARGUMENTS = {
    "with_context": "give the law a class method from_context(context) instead: it receives the "
                    "qcontrol.LawContext (n, dt, control_period, delta, c; its keys in context.settings)",
}


@dataclass(frozen=True)
class ClassSettings:
    """A class kind's settings: the parsed settings of its declared :class:`~.law.LawKeys` or of
    the kind it extends (``base``), and its own keys."""

    base: Any
    own: tuple[tuple[str, Any], ...]

    @property
    def table(self) -> MappingProxyType:
        return MappingProxyType(_thaw(self.own))


def register_law(kind: str, factory: Callable[..., Any], *, keys: Sequence[str] | LawKeys | None = None,
                 extends: str | None = None, state_name: str | None = None, replace: bool = False,
                 **removed: Any) -> None:
    """Make ``controller.kind = "<kind>"`` select the law ``factory`` makes (module docstring).

    ``factory``: a callable ``factory(table, n)`` returning a :class:`~.user.Law` (``table``: the
    scenario's ``[controller]`` table as a dict, ``kind``, ``delta``, ``c`` and the law's keys from
    ``[controller.<kind>]`` and ``[controller]``; ``n``: the plant order); a class with a class
    method ``from_context(context)`` (a :class:`~.law.LawContext`: n, dt, the control period,
    delta, c, the law's keys in ``context.settings``); or a subclass of
    :class:`~.backstepping.BacksteppingLaw` (column form). ``keys``: the law's keys (module
    docstring). ``extends``: ``"proposed"`` or ``"comparison"`` (a column-form class only).
    ``state_name`` names a per-copy law's state in outputs (``final_<state_name>``; a class sets
    its attribute ``state_name``). ``kind``: letters, digits, ``_`` and ``-``, starting with a
    letter or ``_``. ``replace=True`` replaces a law registered before under the same name; the
    built-in kinds are never replaced.
    """
    check_kind_name(kind, "register_law")
    for name in removed:
        fix = REMOVED_ARGUMENTS.get(name, "")
        raise QcontrolInputError(f"register_law: no argument {name}=" + (f"; {fix}" if fix else ""))
    if not callable(factory):
        raise QcontrolInputError(f"register_law: factory for {kind!r} must be callable as factory(table, n), "
                                 f"got {type(factory).__name__}")
    if not isinstance(replace, bool):
        raise QcontrolInputError(f"register_law: replace must be True or False, got {replace!r}")
    if keys is not None and not isinstance(keys, LawKeys) and (
            isinstance(keys, str) or not all(isinstance(k, str) for k in keys)):
        raise QcontrolInputError(f"register_law: keys for {kind!r} must be a list of key names, got {keys!r}")
    extendable = [k for k, v in LAW_KINDS.items() if v.declared is not None]
    if extends is not None and extends not in extendable:
        raise QcontrolInputError(f"register_law: extends={extends!r} for {kind!r}: use one of "
                                 f"{', '.join(extendable)}, or None")
    if isinstance(factory, type) and issubclass(factory, BacksteppingLaw):
        if state_name is not None:
            raise QcontrolInputError(f"register_law: state_name for {kind!r}: a law class names its state "
                                     "with its class attribute state_name")
        made = ClassKind(kind, factory, extends, keys)
        add_kind(made.entry(), replace=replace)
        return
    if extends is not None or isinstance(keys, LawKeys):
        raise QcontrolInputError(f"register_law: extends= and LawKeys for {kind!r} take a column-form law "
                                 "(a subclass of qcontrol.BacksteppingLaw, qcontrol.PaperLaw or "
                                 "qcontrol.ComparisonLaw)")
    state_name = "state" if state_name is None else state_name
    if not isinstance(state_name, str) or not state_name.isidentifier():
        raise QcontrolInputError(f"register_law: state_name {state_name!r} must be letters, digits and _, "
                                 "starting with a letter or _")
    user = UserKind(kind, factory, state_name, None if keys is None else tuple(keys))
    add_kind(LawKind(kind, None, user.parse, user.build, user.structure), replace=replace)


class ClassKind:
    """A controller kind of a column-form class: its settings parsed by its :class:`~.law.LawKeys`
    (or those of the kind it extends, plus its own keys), the law built by ``cls.from_context``."""

    def __init__(self, kind: str, cls: type, extends: str | None,
                 keys: Sequence[str] | LawKeys | None) -> None:
        self.kind, self.cls, self.extends = kind, cls, extends
        self.declared = keys if isinstance(keys, LawKeys) else None
        self.keys = () if keys is None or self.declared is not None else tuple(keys)
        self.base_keys = self.declared or (LAW_KINDS[extends].declared if extends is not None else None)

    def entry(self) -> LawKind:
        base, own = self.base_keys, self.declared
        return LawKind(self.kind, own.keys if own is not None else None, self.parse, self.build,
                       self.structure,
                       bounds=self.bounds if base is not None and base.bounds is not None else None,
                       divergence_hint=own.divergence_hint if own is not None else "", extends=self.extends,
                       declared=own, also_measure=own.also_measure if own is not None else None,
                       plants=base.plants if base is not None else CHAIN)

    def parse(self, table: Table, ctx: LawContext) -> Any:
        """The settings of a variant: the :class:`~.law.LawKeys`' own parse when the keys are
        declared so (a built-in law's settings object), else a :class:`ClassSettings`, checked by
        building the law once."""
        if self.declared is not None:
            return self.declared.parse(table, ctx)
        base_names = () if self.base_keys is None else self.base_keys.keys.names
        own = {k: v for k, v in table.data.items() if k not in base_names}
        for key in own:
            if key not in self.keys:
                allowed = ", ".join((*self.keys, *base_names)) or "none"
                raise table.error(key, f"unknown key for kind {self.kind!r}",
                                  f"keys of this kind are {allowed} (remove it or check its spelling)")
        base = None if self.extends is None else self._base_settings(table, ctx, base_names)
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

    def build(self, settings: Sequence[Any], ctx: LawContext) -> BacksteppingLaw:
        if self.declared is not None:  # variants of one batch: per-copy values (LawKeys.combine)
            return self.cls.from_context(replace(ctx, base=self.declared.combine(settings)))
        first = settings[0]
        law = self.cls.from_context(replace(ctx, settings=first.table, base=first.base, controller=None))
        if not isinstance(law, BacksteppingLaw):
            raise QcontrolInputError(f"{self.cls.__name__}.from_context must return the law, got "
                                     f"{type(law).__name__}")
        if law.diagnostics != ():  # none declared: nothing to check (and no attribute of its own added)
            law.diagnostics = checked_class_diagnostics(law.diagnostics, self.kind)
        return law

    def structure(self, settings: Any, ctx: LawContext) -> Hashable:
        if self.declared is not None:
            return self.declared.structure(settings, ctx)
        return settings  # variants share a batch only when their settings are equal

    def bounds(self, settings: Any) -> tuple:
        """The bounding functions r of the law's (or the extended law's) settings, checked along
        single runs."""
        return self.base_keys.bounds(settings if self.declared is not None else settings.base)


def removed_name(name: str) -> str | None:
    """The one-line migration note for a public name that no longer exists, else None."""
    return REMOVED_NAMES.get(name)


REMOVED_NAMES = {
    "register_law_class": "qcontrol.register_law_class was merged into qcontrol.register_law: call "
                          "qcontrol.register_law(kind, cls, extends=..., keys=[...]) with the same arguments",
    "SteppedLaw": "qcontrol.SteppedLaw was merged into qcontrol.Law: a law gives advance(t, x_q, yd, state, "
                  "h) in place of state_rate; use qcontrol.Law where you named qcontrol.SteppedLaw",
    "ProposedController": "ProposedController was renamed: use qcontrol.PaperLaw",
    "ComparisonController": "ComparisonController was renamed: use qcontrol.ComparisonLaw",
}
