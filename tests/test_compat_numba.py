"""Check tests of the numba internals fenced in ``service.compat.numba``: each fails with a
message naming the internal when a numba release changes it."""

from __future__ import annotations

import importlib

import numpy as np
import pytest
from numba import literal_unroll, njit

from service.compat import numba as cn


def test_private_imports_exist() -> None:
    for mod, name in [
        ("numba.np.arrayobj", "make_array"),
        ("numba.extending", "intrinsic"),
        ("numba.core.cpu", "CPUTargetOptions"),
    ]:
        m = importlib.import_module(mod)
        assert hasattr(m, name), f"numba internal {mod}.{name} is gone: see service/compat/numba.py"


def test_array_struct_has_meminfo_and_parent() -> None:
    from numba import types
    from numba.core.datamodel import default_manager
    from numba.np.arrayobj import make_array

    t = types.float64[:, :]
    assert make_array(t)._fe_type == t, "numba.np.arrayobj.make_array no longer proxies arrays"
    fields = default_manager.lookup(t)._fields
    for name in ("meminfo", "parent", "data", "shape", "strides"):
        assert name in fields, f"numba's array struct has no member {name!r} (borrowed_all)"


@njit
def _borrow_and_write(a, b, c):
    x, y, z = cn.borrowed_all((a, b, c))
    x[0, 1] = 7.5  # writes through to a
    y[1] = not y[1]
    z[2] += 40
    s = 0.0
    for i in range(x.shape[0]):
        for j in range(x.shape[1]):
            s += x[i, j]
    return s, x.shape[0], x.shape[1], x.strides[0], x.strides[1], y.shape[0], z[2]


def test_borrowed_all_gives_views_of_the_same_data() -> None:
    base = np.arange(24, dtype=float).reshape(4, 6)
    a = base[::2, 1::2]  # non-contiguous: shape and strides must survive
    b = np.array([True, False, True])
    c = np.arange(5, dtype=np.int64)
    try:
        s, n0, n1, s0, s1, nb, c2 = _borrow_and_write(a, b, c)
    except Exception as e:  # pragma: no cover - only on a numba that broke the intrinsic
        pytest.fail(f"numba internal make_array/meminfo (borrowed_all) no longer compiles: {e!r}")
    assert base[0, 3] == 7.5 and a[0, 1] == 7.5, "borrowed_all: the view does not alias the array"
    assert (n0, n1) == a.shape and (s0, s1) == a.strides, "borrowed_all: shape/strides changed"
    assert s == pytest.approx(a.sum()), "borrowed_all: the view reads other data"
    assert b.tolist() == [True, True, True] and nb == 3
    assert c2 == 42 and c[2] == 42


@njit
def _borrow_many(ws):
    v = cn.borrowed_all(ws)
    t = 0.0
    for a in literal_unroll(v):
        t += a.sum()
    return t


def test_borrowed_all_on_a_workspace_tuple() -> None:
    from service.monitor.ukf import workspace

    ws = workspace(8, 5)
    for k, a in enumerate(ws):
        a[...] = k
    want = float(sum(k * a.size for k, a in enumerate(ws)))
    assert _borrow_many(ws) == want


def test_borrowed_all_refuses_non_arrays() -> None:
    from numba.core.errors import TypingError

    @njit
    def f(a):
        return cn.borrowed_all((a, 1.0))

    with pytest.raises(TypingError):
        f(np.zeros(2))


def test_nrt_option_is_accepted() -> None:
    assert cn.HAS_NRT_OPTION, (
        "numba's private target option _nrt (numba.core.cpu.CPUTargetOptions._nrt) is gone: "
        "service.log.codec's leaf kernels now keep reference counting (slower); "
        "see service/compat/numba.py"
    )
    assert cn.NO_NRT == {"_nrt": False}

    @njit(**cn.NO_NRT)
    def leaf(a):
        s = 0.0
        for v in a:
            s += v
        return s

    assert leaf(np.arange(5.0)) == 10.0


def test_has_cached_code_sees_the_cache_index(tmp_path, monkeypatch) -> None:
    """A fresh ``cache=True`` function has no cached code until its first call compiles it;
    then it has (the index ``service.cli.warmup`` reads to announce a compile)."""
    import sys

    src = tmp_path / "_cached_kernel.py"
    src.write_text("from numba import njit\n\n@njit(cache=True)\ndef f(x):\n    return x + 1\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    mod = importlib.import_module("_cached_kernel")
    try:
        assert not cn.has_cached_code(mod.f), "numba cache index: see service/compat/numba.py"
        assert mod.f(1) == 2
        assert cn.has_cached_code(mod.f), "numba cache index: see service/compat/numba.py"
    finally:
        sys.modules.pop("_cached_kernel", None)


def test_has_cached_code_tells_closure_variants_apart(tmp_path, monkeypatch) -> None:
    """Two variants of one factory share a cache index; compiling one leaves the other
    uncached (service.monitor.kernels builds its kernels per process model this way)."""
    import sys

    src = tmp_path / "_cached_factory.py"
    src.write_text(
        "from numba import njit\n\ndef make(wh):\n    @njit(cache=True)\n"
        "    def f(x):\n        return x + 2 if wh else x + 1\n    return f\n\n"
        "F0 = make(False)\nF1 = make(True)\n"
    )
    monkeypatch.syspath_prepend(str(tmp_path))
    mod = importlib.import_module("_cached_factory")
    try:
        assert mod.F0(1) == 2
        assert cn.has_cached_code(mod.F0), "numba cache index keys: see service/compat/numba.py"
        assert not cn.has_cached_code(mod.F1), "numba cache index keys: closure variants"
        assert mod.F1(1) == 3 and cn.has_cached_code(mod.F1)
    finally:
        sys.modules.pop("_cached_factory", None)
