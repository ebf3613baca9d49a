"""The numba internals the kernels rely on, fenced in one module (checked by
``tests/test_compat_numba.py`` on every numba release the project allows).

* ``borrowed_all``: an intrinsic built on ``numba.np.arrayobj.make_array`` (the array's
  LLVM struct proxy) that nulls the ``meminfo`` and ``parent`` members of array structs, so
  numba's reference counting skips them. Numba increfs/decrefs every array a function holds
  with atomic operations and its pruning pass leaves most of them in a function the size of
  the UKF step: about a third of ``service.monitor.ukf.ukf_one`` and a fifth of the monitor's block
  loop (``service.monitor.kernels``).
* ``has_cached_code``: whether a dispatcher's on-disk cache index (``numba.core.caching``:
  ``Dispatcher._cache._cache_file._load_index``) holds a fresh entry, i.e. whether its first
  call loads compiled code instead of compiling (``service.cli.warmup`` announces a compile).
* ``NO_NRT``: the private ``_nrt`` target option (``numba.core.cpu.CPUTargetOptions``), which
  compiles a kernel without the runtime's reference counting at all; for kernels that
  allocate nothing (``service.log.codec``). Empty when the option is gone (the kernels still
  work, slower), which the check tests report.

Every other module imports these from here, never from numba's private packages.
"""

from __future__ import annotations

from llvmlite.ir import Constant
from numba import types
from numba.core import cpu
from numba.extending import intrinsic
from numba.np.arrayobj import make_array

__all__ = ["borrowed_all", "NO_NRT", "HAS_NRT_OPTION", "has_cached_code"]

HAS_NRT_OPTION: bool = hasattr(cpu.CPUTargetOptions, "_nrt")
NO_NRT: dict[str, bool] = {"_nrt": False} if HAS_NRT_OPTION else {}


@intrinsic
def borrowed_all(typingctx, arrays):
    """The arrays of a tuple without their memory-info pointers: views that numba does not
    reference-count (``a, b = borrowed_all((a, b))``, or a ``workspace`` tuple at once); on
    such a view numba's atomic increfs/decrefs are no-ops. Only for arrays that outlive the
    views (a kernel's arguments, for the duration of the call); never return or store one."""
    if not isinstance(arrays, types.BaseTuple) or not all(
        isinstance(a, types.Array) for a in arrays.types
    ):
        return None

    def codegen(context, builder, sig, args):
        out = []
        for i, a in enumerate(arrays.types):
            ary = make_array(a)(context, builder, value=builder.extract_value(args[0], i))
            ary.meminfo = Constant(ary.meminfo.type, None)
            ary.parent = Constant(ary.parent.type, None)
            out.append(ary._getvalue())
        return context.make_tuple(builder, sig.return_type, out)

    return arrays(arrays), codegen


def has_cached_code(dispatcher) -> bool:
    """True when ``dispatcher`` (an ``@njit(cache=True)`` function) has compiled code in its
    cache index for its current source, this target and, for a closure, its closure values
    (the variants of one factory share an index): its first call loads instead of compiling.
    A cache that cannot be read counts as absent."""
    try:
        cache = dispatcher._cache
        overloads = cache._cache_file._load_index()
        # the index keys: (signature, target magic tuple, (bytecode hash, closure hash))
        _, magic, code = cache._index_key(None, dispatcher.targetctx.codegen())
    except (AttributeError, OSError, EOFError, ValueError, TypeError):
        return False
    return any(k[1] == magic and k[2] == code for k in overloads)
