"""The package layout: no import cycle among the modules of ``service/`` and ``models/``, no
import that runs up the layers (``LAYERS``), at most 8 loose modules in ``service/``, and no
module there over 800 lines.

The import graph is built from the source with ``ast``: every ``import`` and ``from ... import``
counts, including those inside functions and ``if TYPE_CHECKING:`` blocks. An edge goes to the
module named (``from a.b import c`` to ``a.b.c`` when that is a module, else to ``a.b``); the
implicit import of a parent package is not an edge.
"""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
PACKAGES = ("service", "models")
MAX_LINES = 800
MAX_LOOSE = 8

#: The layers, lowest first (docs/design.md, "Layout"). A module may import its own unit (the
#: longest prefix listed here that names it) and any unit of a LOWER layer; not a unit of its
#: own layer (siblings stay independent) and never one above.
LAYERS: tuple[tuple[str, ...], ...] = (
    ("models",),
    ("service.compat", "service.jsonutil", "service.strictnum", "service.progress",
     "service.plots", "service.zenoh_util", "service.names", "service.paths"),
    ("service.log", "service.store"),
    ("service.monitor",),
    ("service.wire",),
    ("service.prognostics", "service.sim"),
    ("service.edge",),
    ("service.config",),
    ("service.daemon",),
    ("service.replay",),
    ("service.importer",),
    ("service.cli",),
)  # fmt: skip


def _modules() -> dict[str, Path]:
    """Dotted module name -> file, for every .py file of the packages."""
    out = {}
    for pkg in PACKAGES:
        for p in sorted((ROOT / pkg).rglob("*.py")):
            parts = list(p.relative_to(ROOT).with_suffix("").parts)
            if parts[-1] == "__init__":
                parts = parts[:-1]
            out[".".join(parts)] = p
    return out


def _imports(name: str, path: Path, mods: dict[str, Path]) -> set[str]:
    """The modules of ``mods`` that module ``name`` imports anywhere in its source."""
    is_pkg = path.name == "__init__.py"
    out = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            targets = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                pkg = name.split(".") if is_pkg else name.split(".")[:-1]
                pkg = pkg[: len(pkg) - (node.level - 1)]
                base = ".".join([*pkg, base] if base else pkg)
            targets = [
                f"{base}.{a.name}" if f"{base}.{a.name}" in mods else base for a in node.names
            ]
        else:
            continue
        out.update(t for t in targets if t in mods and t != name)
    return out


def import_graph() -> dict[str, set[str]]:
    """Module -> the modules it imports (within ``service`` and ``models``)."""
    mods = _modules()
    return {n: _imports(n, p, mods) for n, p in mods.items()}


def find_cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Cycles (a, b, ..., a): for each strongly connected component of more than one module
    (Tarjan's algorithm, iterative), a shortest cycle through each of its modules."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    on, stack, sccs = set(), [], []
    for root in sorted(graph):
        if root in index:
            continue
        work = [(root, iter(sorted(graph[root])))]
        index[root] = low[root] = len(index)
        stack.append(root)
        on.add(root)
        while work:
            v, it = work[-1]
            w = next(it, None)
            if w is not None:
                if w not in index:
                    index[w] = low[w] = len(index)
                    stack.append(w)
                    on.add(w)
                    work.append((w, iter(sorted(graph[w]))))
                elif w in on:
                    low[v] = min(low[v], index[w])
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[v])
            if low[v] == index[v]:
                comp = []
                while True:
                    w = stack.pop()
                    on.discard(w)
                    comp.append(w)
                    if w == v:
                        break
                if len(comp) > 1:
                    sccs.append(set(comp))
    out = []
    for comp in sccs:
        for start in sorted(comp):
            c = _cycle_in(graph, comp, start)
            if not any(set(c) == set(o) for o in out):
                out.append(c)
    return out


def _cycle_in(graph: dict[str, set[str]], comp: set[str], start: str) -> list[str]:
    """A shortest cycle through module ``start`` of a strongly connected component."""
    prev: dict[str, str] = {}
    frontier = [start]
    while frontier:
        nxt = []
        for v in frontier:
            for w in sorted(graph[v] & comp):
                if w == start:
                    path = [v]
                    while path[-1] != start:
                        path.append(prev[path[-1]])
                    return [start, *reversed(path[:-1]), start]
                if w not in prev:
                    prev[w] = v
                    nxt.append(w)
        frontier = nxt
    return [start]


def test_the_cycle_finder_finds_cycles():
    g = {"a": {"b"}, "b": {"c"}, "c": {"a", "d"}, "d": set(), "e": {"d"}}
    assert find_cycles(g) == [["a", "b", "c", "a"]]
    assert find_cycles({"a": {"b"}, "b": set()}) == []


def test_the_graph_sees_type_checking_and_function_imports():
    g = import_graph()
    assert "service.daemon.intake" in g["service.daemon.core"]
    assert "service.config" in g["service.cli.args"]  # under TYPE_CHECKING, and in a function
    assert "service.store.writer" in g["service.daemon.outputs"]  # in __init__ only
    assert len(g) > 50 and sum(map(len, g.values())) > 100


def test_no_import_cycle_in_service_and_models():
    cycles = find_cycles(import_graph())
    assert not cycles, "import cycles:\n" + "\n".join(" -> ".join(c) for c in cycles)


def unit_of(module: str) -> tuple[int, str]:
    """(layer index, unit) of a module: the longest prefix of ``LAYERS`` that names it."""
    best = None
    for k, units in enumerate(LAYERS):
        for u in units:
            if (module == u or module.startswith(u + ".")) and (
                best is None or len(u) > len(best[1])
            ):
                best = (k, u)
    if best is None:
        raise AssertionError(f"{module} is in no layer of LAYERS: add it")
    return best


def upward(graph: dict[str, set[str]]) -> list[str]:
    """Every import of a unit that is not below the importer's, as ``a -> b``."""
    out = []
    for a, deps in sorted(graph.items()):
        if a in ("service", "models"):
            continue
        la, ua = unit_of(a)
        for b in sorted(deps):
            lb, ub = unit_of(b)
            if ub != ua and lb >= la:
                out.append(f"{a} -> {b} (layer {la} -> {lb})")
    return out


def test_the_layer_check_finds_upward_imports():
    g = {"service.log.reader": {"service.store"}, "service.cli.dispatch": {"service.log"},
         "service.edge.web.view": {"service.cli.commands.fleet"}}  # fmt: skip
    assert upward(g) == [
        "service.edge.web.view -> service.cli.commands.fleet (layer 6 -> 11)",
        "service.log.reader -> service.store (layer 2 -> 2)",
    ]
    assert unit_of("service.wire.kernels") == (4, "service.wire")
    assert unit_of("service.edge.web.live") == (6, "service.edge")


def test_no_import_runs_up_the_layers():
    bad = upward(import_graph())
    assert not bad, "imports up the layers (or across one):\n" + "\n".join(bad)


def test_at_most_8_loose_modules_in_service():
    loose = sorted(p.stem for p in (ROOT / "service").glob("*.py") if p.stem != "__init__")
    assert len(loose) <= MAX_LOOSE, loose


def test_no_module_over_800_lines():
    long = {
        str(p.relative_to(ROOT)): n
        for p in _modules().values()
        if (n := len(p.read_text().splitlines())) > MAX_LINES
    }
    assert not long, f"modules over {MAX_LINES} lines: {long}"
