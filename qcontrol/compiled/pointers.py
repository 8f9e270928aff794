"""Raw memory access for compiled callbacks: an address as a pointer, and the word stored there.

MuJoCo passes its callbacks ``mjModel*`` and ``mjData*``; the arrays a callback needs are pointer
members of those structs, at offsets found at import time (:mod:`qcontrol.plants.mujoco.native`).
"""

from __future__ import annotations

import numpy as np
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


# what generated code imports: ``from qcontrol.compiled.pointers import ...``
__all__ = ["as_address", "as_pointer", "carray", "np"]
