"""Raw memory access for compiled callbacks: an address as a pointer, and the word stored there;
and a float the compiler cannot see the value of (:func:`opaque`).

MuJoCo passes its callbacks ``mjModel*`` and ``mjData*``; the arrays a callback needs are pointer
members of those structs, at offsets found at import time (:mod:`qcontrol.plants.mujoco.native`).
"""

from __future__ import annotations

import numpy as np
from llvmlite import ir
from numba import carray, types
from numba.extending import intrinsic


@intrinsic
def as_pointer(typingctx, address):  # noqa: ANN001, ARG001 (numba's intrinsic signature)
    """The integer ``address`` as a ``void*``."""
    signature = types.voidptr(types.intp)

    def codegen(context, builder, sig, args):  # noqa: ANN001, ARG001
        return builder.inttoptr(args[0], context.get_value_type(types.voidptr))

    return signature, codegen


@intrinsic
def as_address(typingctx, pointer):  # noqa: ANN001, ARG001
    """The ``void*`` ``pointer`` as an integer."""
    signature = types.intp(types.voidptr)

    def codegen(context, builder, sig, args):  # noqa: ANN001, ARG001
        return builder.ptrtoint(args[0], context.get_value_type(types.intp))

    return signature, codegen


@intrinsic
def opaque(typingctx, x):  # noqa: ANN001, ARG001
    """The float ``x`` itself, through an empty assembly statement (two register moves): LLVM
    cannot see its value, so it cannot specialise a call on it. ``math.pow(b, 0.5)`` with the
    constant 0.5 becomes ``sqrt(b)`` (``pow(b, -1.0)`` ``1 / b``), which libm's pow, Python's
    ``math.pow``, does not always equal to the last bit; ``math.pow(b, opaque(0.5))`` stays pow."""
    signature = types.float64(types.float64)

    def codegen(context, builder, sig, args):  # noqa: ANN001, ARG001
        word = ir.IntType(64)
        asm = builder.asm(ir.FunctionType(word, [word]), "", "=r,0", [builder.bitcast(args[0], word)],
                          side_effect=False)
        return builder.bitcast(asm, ir.DoubleType())

    return signature, codegen


# what generated code imports: ``from qcontrol.compiled.pointers import ...``
__all__ = ["as_address", "as_pointer", "carray", "np", "opaque"]
