"""The passive force of eq. (1)'s terms without a rigid-body counterpart, as a native callback.

A numba ``cfunc`` with MuJoCo's callback signature ``void(const mjModel*, mjData*)``, generated
from the same expression trees as the Python callback (:func:`qcontrol.expr.source.float_source`)
and computing the same numbers: ``qfrc_passive[dof] += sum_i (I c_i) term_i(qpos[qadr],
qvel[dof])``, summed in order from 0.0. Where Python's ``math`` refuses a term, the Python force
takes numpy's answer; the compiled code, with numpy's error model, computes that very IEEE value
(NaN, Inf) without raising.
MuJoCo calls it without the Python interpreter (RK4: four times per step; ``mujoco.batch``:
from its C threads).

The numbers that differ between plants sharing the terms live in ``mjData.userdata`` (every
model is built with room for them, :data:`USERDATA_SLOTS`):

    userdata[0]      the callback's tag: a model whose data does not carry it is left alone
    userdata[1], [2] the joint's qpos and dof addresses
    userdata[3 + i]  I c_i, the generalized-force coefficient of term i (theta_i times the inertia)

so one compiled callback serves every copy and every value of theta. Its pointer members of
``mjData`` and ``nuserdata`` of ``mjModel`` are read at offsets found at import by matching the
addresses and values the bindings report for a probe model (:func:`struct_offsets`), never
written into the code by hand: they change between MuJoCo builds. The offsets are part of the
generated text, so the disk cache keys on them too.
"""

from __future__ import annotations

import ctypes
import hashlib
from collections.abc import Sequence
from dataclasses import dataclass
from functools import cache
from typing import Any

import mujoco
import numpy as np

from ... import compiled as compiled_paths
from ...expr import Expression
from ...expr.source import FLAG, Statements, float_source
from ..base import timed

FIRST_COEFFICIENT = 3  # userdata slots before the coefficients: tag, qadr, dof
USERDATA_SLOTS = 32  # every model is built with at least this nuserdata (more terms: the Python callback)
_DATA_POINTERS = ("qpos", "qvel", "qfrc_passive", "userdata")
_PROBE = """<mujoco><size nuserdata="{n}"/><worldbody><body><joint type="hinge"/>
<geom size="0.1" mass="1"/></body></worldbody></mujoco>"""
_SCAN_BYTES = 1 << 22  # where the pointers are searched for: an mjData is about 170 kB in MuJoCo 4
_CHUNK_BYTES = 1 << 14


def userdata_size(terms: int) -> int:
    """``nuserdata`` a model needs for a native callback of ``terms`` terms."""
    return FIRST_COEFFICIENT + terms


@cache
def struct_offsets() -> dict[str, int]:
    """Byte offsets of ``mjData``'s pointer members and ``mjModel.nuserdata`` in this MuJoCo.

    Found by matching: each member's address (``data.qpos.ctypes.data``) in the words of the
    struct, and two distinct ``nuserdata`` values in two probe models. Raises ``LookupError``
    when a member is not found exactly once."""
    models = [mujoco.MjModel.from_xml_string(_PROBE.format(n=n)) for n in (7919, 6007)]
    data = mujoco.MjData(models[0])
    wanted = {name: int(getattr(data, name).ctypes.data) for name in _DATA_POINTERS}
    offsets = {}
    for start in range(0, _SCAN_BYTES, _CHUNK_BYTES):  # chunk by chunk: never read past the members
        words = np.frombuffer((ctypes.c_uint64 * (_CHUNK_BYTES // 8)).from_address(data._address + start),
                              dtype=np.uint64)
        for name, address in wanted.items():
            hits = np.flatnonzero(words == address)
            if name not in offsets and hits.size:
                offsets[name] = start + 8 * int(hits[0])
        if len(offsets) == len(wanted):
            break
    firsts = [np.frombuffer((ctypes.c_int64 * 1024).from_address(m._address), dtype=np.int64) for m in models]
    matches = (8 * np.flatnonzero((firsts[0] == 7919) & (firsts[1] == 6007))).tolist()
    if len(matches) != 1 or len(offsets) != len(wanted):
        raise LookupError(f"mjData/mjModel members not found in this MuJoCo build (found {offsets}, "
                          f"nuserdata at {matches})")
    offsets["nuserdata"] = matches[0]
    return offsets


def callback_source(terms: Sequence[Expression], offsets: dict[str, int]) -> tuple[str, float]:
    """The module text of the callback for ``terms`` and its tag (an exact integer as a float)."""
    body = Statements("t")
    names = ["q", "v"]
    for i, term in enumerate(terms):
        value = float_source(term._tree, names, body)
        body.lines.append(f"total += userdata[{FIRST_COEFFICIENT + i}] * {value}")
    lines = ["total = 0.0", f"{FLAG} = False", *body.lines]
    key = "\n".join([*(f"{t.variables} {t.source}" for t in terms), repr(sorted(offsets.items()))])
    tag = float(int(hashlib.sha256(key.encode()).hexdigest()[:12], 16))
    slots = userdata_size(len(terms))
    indented = "\n".join("    " + line for line in lines)
    shown = "; ".join(t.source for t in terms)  # user text, so only as a repr literal
    source = f'''"""qcontrol's passive force (generated): see TERMS."""
import math

import numba
import numpy as np
from numba import types

from qcontrol.compiled.pointers import as_address, as_pointer, carray, opaque

TAG = {tag!r}
TERMS = {shown!r}


@numba.cfunc(types.void(types.voidptr, types.voidptr), cache=True, error_model="numpy")
def passive(model, data):
    m, d = as_address(model), as_address(data)
    if carray(as_pointer(m + {offsets["nuserdata"]}), 1, dtype=np.int64)[0] < {slots}:
        return
    userdata = carray(as_pointer(carray(as_pointer(d + {offsets["userdata"]}), 1, dtype=np.intp)[0]),
                      {slots}, dtype=np.float64)
    if userdata[0] != TAG:
        return
    qadr, dof = int(userdata[1]), int(userdata[2])
    qpos = carray(as_pointer(carray(as_pointer(d + {offsets["qpos"]}), 1, dtype=np.intp)[0]), qadr + 1,
                  dtype=np.float64)
    qvel = carray(as_pointer(carray(as_pointer(d + {offsets["qvel"]}), 1, dtype=np.intp)[0]), dof + 1,
                  dtype=np.float64)
    qfrc = carray(as_pointer(carray(as_pointer(d + {offsets["qfrc_passive"]}), 1, dtype=np.intp)[0]),
                  dof + 1, dtype=np.float64)
    q, v = qpos[qadr], qvel[dof]
{indented}
    qfrc[dof] += total
'''
    return source, tag


@dataclass(frozen=True)
class NativeForce:
    """A compiled passive callback and what a plant writes into each copy's userdata."""

    key: str  # the generated module's name: plants with equal keys share the callback
    tag: float
    pointer: Any  # the ctypes function pointer MuJoCo's bindings accept
    address: int  # the callback's address (for :func:`ctypes` calls from a Python dispatcher)

    def fill(self, data: mujoco.MjData, qadr: int, dof: int, coefficients: Sequence[float]) -> None:
        """Write the tag, the addresses and the coefficients into ``data.userdata``."""
        data.userdata[:FIRST_COEFFICIENT] = (self.tag, qadr, dof)
        data.userdata[FIRST_COEFFICIENT:FIRST_COEFFICIENT + len(coefficients)] = coefficients

    def fill_rows(self, userdata: np.ndarray, qadr: int, dof: int, coefficients: np.ndarray) -> None:
        """:meth:`fill` for every row of a batch's ``(copies, nuserdata)`` userdata; row ``b`` of
        ``coefficients`` (``(copies, terms)``) is copy b's (theta per copy)."""
        userdata[:, :FIRST_COEFFICIENT] = (self.tag, qadr, dof)
        userdata[:, FIRST_COEFFICIENT:FIRST_COEFFICIENT + coefficients.shape[1]] = coefficients


def native_force(terms: Sequence[Expression]) -> NativeForce | None:
    """The native callback for ``terms`` (compiled, or loaded from the disk cache), or None
    where compiled paths are off or unavailable (then the Python callback serves)."""
    if not compiled_paths.enabled() or any(timed(t) for t in terms):  # (terms in t: the Python callback)
        return None
    if userdata_size(len(terms)) > USERDATA_SLOTS:
        compiled_paths.fallback("MuJoCo's passive terms", f"more than {USERDATA_SLOTS - FIRST_COEFFICIENT} "
                                "terms do not fit the models' userdata")
        return None
    try:
        return _native_force(tuple(terms))
    except Exception as exc:  # numba refusing a construct, an unexpected MuJoCo layout
        compiled_paths.fallback("MuJoCo's passive terms", f"{type(exc).__name__}: {exc}")
        return None


@cache
def _native_force(terms: tuple[Expression, ...]) -> NativeForce:
    from ...compiled.cache import generated_module

    source, tag = callback_source(terms, struct_offsets())
    module = generated_module("passive", source)
    function = module.passive
    return NativeForce(module.__name__, tag, function.ctypes, int(function.address))

