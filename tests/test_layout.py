"""The repository's layout holds: tests and package code use the importable packages
(``models``, ``service``, ``evaluation``), never a script of ``bench/`` (timing benchmarks)
or ``research/`` (one-off investigations, outside CI).

A source uses a script folder when it imports from it (``import bench.x``, ``from research
import y``, or a bare module name that is one of the folder's scripts, reachable after a
``sys.path`` insert) or names the folder as a path in a call (``sys.path.insert(0, ROOT /
"bench")``, ``spec_from_file_location(.., "bench/x.py")``, ``subprocess.run([.., "bench/x.py"])``).
"""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SCRIPT_DIRS = ("bench", "research")


def _scripts(root: Path) -> dict[str, str]:
    """Module name -> its folder, for every script of the script folders."""
    return {p.stem: d for d in SCRIPT_DIRS for p in sorted((root / d).glob("*.py"))}


def _names_a_folder(s: str) -> str | None:
    for d in SCRIPT_DIRS:
        if s.startswith((f"{d}/", f"./{d}/")) or f"/{d}/" in s:
            return d
    return None


def uses_of_scripts(source: str, scripts: dict[str, str]) -> list[str]:
    """Each use of a script folder in ``source``, as "line N: what", in line order."""
    out: set[tuple[int, str]] = set()
    for node in ast.walk(ast.parse(source)):
        mods: list[str] = []
        if isinstance(node, ast.Import):
            mods = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            mods = [node.module]
        for m in mods:
            top = m.split(".")[0]
            if top in SCRIPT_DIRS or top in scripts:
                out.add((node.lineno, f"imports {m}"))
        if isinstance(node, ast.Call):
            for arg in ast.walk(node):
                if isinstance(arg, ast.Constant) and isinstance(arg.value, str):
                    d = _names_a_folder(arg.value) if "/" in arg.value else None
                    if d is not None:
                        out.add((arg.lineno, f"names {d}/ ({arg.value!r})"))
                right = arg.right if isinstance(arg, ast.BinOp) else None  # ROOT / "bench"
                if isinstance(right, ast.Constant) and right.value in SCRIPT_DIRS:
                    out.add((right.lineno, f"names {right.value}/ (a path part)"))
    return [f"line {n}: {what}" for n, what in sorted(out)]


def test_no_test_or_package_module_uses_bench_or_research():
    scripts = _scripts(ROOT)
    assert "service" in {p.stem for p in (ROOT / "bench").glob("*.py")}  # bench/service.py
    # a script may share a package's name (bench/models.py): that import is the package's
    packages = {"models", "service", "evaluation"}
    scripts = {k: v for k, v in scripts.items() if k not in packages}
    problems = []
    for top in ("tests", "models", "service", "evaluation"):
        for f in sorted((ROOT / top).rglob("*.py")):
            if f == Path(__file__).resolve():
                continue
            for p in uses_of_scripts(f.read_text(encoding="utf-8"), scripts):
                problems.append(f"{f.relative_to(ROOT)}: {p}")
    assert not problems, "\n".join(problems)


def test_the_check_finds_each_kind_of_use():
    """Guards the checker: each way a test reached a script before is reported."""
    scripts = {"estimation_suite": "bench", "gate_bias": "research"}
    src = (
        "import sys, subprocess, importlib.util\n"
        "from bench.estimation_suite import run_one\n"  # 2
        "import estimation_suite\n"  # 3: after a sys.path insert
        'sys.path.insert(0, str(ROOT / "bench"))\n'  # 4
        'any(p in ("tests", "bench") for p in found)\n'  # 5: a name, not a path
        'importlib.util.spec_from_file_location("s", ROOT / "bench/estimation_suite.py")\n'  # 6
        'subprocess.run([sys.executable, str(ROOT / "research/gate_bias.py")])\n'  # 7
        "from research import gate_bias\n"  # 8
        'load_scenario("paper_bench")\n'  # not a folder
        "from evaluation.suite import run_one\n"  # the package: fine
    )
    found = uses_of_scripts(src, scripts)
    assert [p.split(":")[0] for p in found] == [f"line {n}" for n in (2, 3, 4, 6, 7, 8)]
    assert uses_of_scripts("from evaluation import suite\n", scripts) == []
