"""A shared work counter for the compiled tracer's threads: dynamic scheduling of a fixed set of parts.

numba's ``prange`` gives each thread one contiguous run of the iterations, decided before any runs. When one
core is slowed (another process, a virtual machine's stolen time), its thread finishes last and the other
threads wait. Instead each of ``get_num_threads()`` workers takes the next untaken part from a counter until
none is left: ``take_next(counter)`` is an atomic fetch-and-add (LLVM ``atomicrmw add``, monotonic ordering:
the counter orders nothing else; joining the threads makes the parts' results visible). Which thread
traces a part then varies from run to run, but what a part computes and where it writes do not, so results
stay bit-identical.
"""

from __future__ import annotations

from numba import types
from numba.core import cgutils
from numba.extending import intrinsic

from . import numba_kernels as _numba_kernels

_numba_kernels.activate()  # before any cached njit: the kernel cache locator, then numba_callable's overloads


@intrinsic
def take_next(typingctx, counter):
    """The value of ``counter[0]`` (a one-element int64 array) before adding 1 to it, atomically."""
    if not (isinstance(counter, types.Array) and counter.dtype == types.int64 and counter.ndim == 1):
        return None
    sig = types.int64(counter)

    def codegen(context, builder, signature, args):
        aty = signature.args[0]
        ary = context.make_array(aty)(context, builder, args[0])
        ptr = cgutils.get_item_pointer(context, builder, aty, ary, [context.get_constant(types.intp, 0)])
        return builder.atomic_rmw("add", ptr, context.get_constant(types.int64, 1), "monotonic")

    return sig, codegen
