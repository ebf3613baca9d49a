"""Every reference to a Markdown file in the repository resolves.

The code and the docs cite the docs by file and section: "physics.md section 3",
"physics.md sections 2, 3 and 6", "physics.md 5", "physics.md section 3, "Consistency with
the simplified models"", "design.md, "Data flow" and "Backpressure"", Markdown links, and
"§N". A fresh clone has only what is in the repository, so each cited file must exist in it,
each cited section number must be a numbered heading of that file, each quoted name must be a
heading of it, and each link anchor must be a heading's anchor.

Resolution: a Markdown link ``[..](target)`` in a .md file is relative to that file (as a
renderer reads it); any other mention is looked up relative to the citing file, the
repository root and ``docs/``, so the bare "physics.md" of a docstring means
``docs/physics.md``. A bare "§N" in a .md file refers to that file's own sections; in a .py
file it names no file and is an error.
"""

from __future__ import annotations

import os
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
MD = ".md"  # these two are kept apart so that this file's examples are not references
SEC = "\u00a7"  # the section sign
SKIP_DIRS = {"__pycache__", "node_modules", "build", "dist", "logs"}

_NUM = r"\d+(?:\.\d+)?"
_NUMS = rf"{_NUM}(?:\s*(?:-|–|,|,?\s*and)\s*{_NUM})*"
MD_REF = re.compile(r"(?<![\w/.\-])((?:\.{1,2}/)*(?:[\w\-]+/)*[\w\-.]*\w\.md)(?![\w/])")
SECTIONS = re.compile(
    rf"[ \t]*,?\s*sections\s*(?P<list>{_NUMS})|[ \t]*,?\s*(?:section|{SEC})\s*(?P<one>{_NUM})"
    rf"|[ \t]+(?P<bare>{_NUM})\b"
)
QUOTED = re.compile(r'\s*(?:,|and|\()?\s*"([A-Za-z][^"]{0,79})"')
ANCHOR = re.compile(r"#([\w\-]+)")
BARE_SECTION = re.compile(rf"{SEC}\s*({_NUMS})")
FENCED = re.compile(r"^```.*?^```", re.M | re.S)
HEADING = re.compile(r"^#{1,6}[ \t]+(.+?)[ \t]*#*$", re.M)
HEADING_NUMBER = re.compile(r"(\d+(?:\.\d+)*)\.?(?:\s|$)")


def source_files(root: Path) -> list[Path]:
    """The repository's *.py and *.md files (hidden, cache and build folders skipped)."""
    out = []
    for d, dirs, files in os.walk(root):
        dirs[:] = sorted(
            x
            for x in dirs
            if not x.startswith(".") and x not in SKIP_DIRS and not x.endswith(".egg-info")
        )
        out += [Path(d) / f for f in sorted(files) if f.endswith((".py", MD))]
    return out


def _numbers(spec: str) -> list[str]:
    """The section numbers of "2, 3 and 6" (2, 3, 6) or "1-3" (1, 2, 3)."""
    out: list[str] = []
    for part in re.split(r"\s*(?:,?\s*and|,)\s*", spec.strip()):
        ends = [x.strip() for x in re.split(r"[-–]", part, maxsplit=1)]
        if len(ends) == 2 and ends[0].isdigit() and ends[1].isdigit():
            out += [str(k) for k in range(int(ends[0]), int(ends[1]) + 1)]
        else:
            out += ends
    return out


def _slug(text: str) -> str:
    """A heading's anchor as Markdown renderers make it."""
    return re.sub(r"[^\w\- ]", "", text.strip().lower()).replace(" ", "-")


class _Target:
    def __init__(self, path: Path):
        text = FENCED.sub("", path.read_text(encoding="utf-8"))  # no "# comments" of code
        headings = HEADING.findall(text)
        self.numbers: set[str] = set()
        self.names: list[str] = []
        for h in headings:
            m = HEADING_NUMBER.match(h)
            if m:
                num = m.group(1)
                self.numbers.add(num)
                self.numbers.add(num.split(".")[0])
                h = h[m.end() :]
            self.names.append(h.strip().lower())
        self.slugs = {_slug(h) for h in headings}

    def has_name(self, name: str) -> bool:
        n = " ".join(name.split()).lower()
        return any(h == n or h.startswith(n) for h in self.names)


def _resolve(ref: str, src: Path, root: Path, link: bool) -> Path | None:
    bases = [src.parent] if link else [src.parent, root, root / "docs"]
    for b in bases:
        p = (b / ref).resolve()
        if p.is_file():
            return p
    return None


def check_text(text: str, src: Path, root: Path) -> list[str]:
    """Problems of the references in ``text`` (the content of ``src``), as "file:line: ..."."""
    rel = src.relative_to(root) if src.is_relative_to(root) else src
    problems: list[str] = []
    targets: dict[Path, _Target] = {}
    consumed: list[tuple[int, int]] = []

    def target(p: Path) -> _Target:
        if p not in targets:
            targets[p] = _Target(p)
        return targets[p]

    def report(pos: int, msg: str) -> None:
        problems.append(f"{rel}:{text.count(chr(10), 0, pos) + 1}: {msg}")

    def check_sections(t: _Target, name: str, spec: str, pos: int) -> None:
        for n in _numbers(spec):
            if n not in t.numbers:
                report(pos, f"{name} has no section {n}")

    for m in MD_REF.finditer(text):
        ref, pos, end = m.group(1), m.start(1), m.end(1)
        link = src.suffix == MD and text[max(0, pos - 2) : pos] == "]("
        p = _resolve(ref, src, root, link)
        if p is None:
            where = "relative to the citing file" if link else "in the repository or docs/"
            report(pos, f"{ref} does not exist ({where})")
            continue
        t = target(p)
        a = ANCHOR.match(text, end) if link else None
        if a is not None:
            if a.group(1).lower() not in t.slugs:
                report(pos, f"{ref} has no heading with the anchor #{a.group(1)}")
            end = a.end()
        s = SECTIONS.match(text, end)
        if s is not None:
            check_sections(t, ref, s.group(s.lastgroup), pos)
            consumed.append((s.start(), s.end()))
            end = s.end()
        while (q := QUOTED.match(text, end)) is not None:
            if not t.has_name(q.group(1)):
                report(pos, f'{ref} has no heading "{q.group(1)}"')
            end = q.end()

    for m in BARE_SECTION.finditer(text):
        if any(a <= m.start() < b for a, b in consumed):
            continue
        if src.suffix != MD:
            report(m.start(), f"{SEC}{m.group(1)} names no file (write e.g. physics{MD} section N)")
        else:
            check_sections(target(src), src.name, m.group(1), m.start())
    return problems


def scan(root: Path) -> list[str]:
    """Problems of every *.py and *.md file under ``root``."""
    out: list[str] = []
    for f in source_files(root):
        out += check_text(f.read_text(encoding="utf-8"), f, root)
    return out


# -- the repository ------------------------------------------------------------------------
def test_every_doc_reference_in_the_repository_resolves():
    problems = scan(ROOT)
    assert not problems, "dangling doc references:\n" + "\n".join(problems)


def test_the_scan_sees_the_citations_it_is_meant_to_check():
    """Guards the checker itself: the repository's section citations are found (a regex that
    matched nothing would pass the test above vacuously)."""
    files = {
        f.relative_to(ROOT).as_posix(): f.read_text(encoding="utf-8") for f in source_files(ROOT)
    }
    assert "docs/physics.md" in files and "docs/design.md" in files
    cites = [
        (name, s.group(s.lastgroup))
        for name, text in files.items()
        for m in MD_REF.finditer(text)
        if m.group(1).endswith("physics" + MD) and (s := SECTIONS.match(text, m.end(1)))
    ]
    assert len(cites) >= 30
    assert ("models/params.py", "4") in cites and ("models/metrics.py", "5") in cites
    assert {"1", "2", "3", "4", "5", "6"} <= {n for _, spec in cites for n in _numbers(spec)}


ARCHIVE = re.compile(r"(?<![\w\-])((?:\.{1,2}/|docs/)*archive/[\w\-./]*)")


def archive_citations(text: str) -> list[str]:
    """The paths into docs/archive/ that ``text`` cites (a file in it, or the folder)."""
    return [m.group(1) for m in ARCHIVE.finditer(text)]


def test_nothing_cites_the_archive():
    """docs/archive/ holds history: no code, test or current doc cites it (the reference and
    the decision records do), so it can be deleted without breaking a reference."""
    archive = ROOT / "docs" / "archive"
    problems = [
        f"{f.relative_to(ROOT)}: cites {c}"
        for f in source_files(ROOT)
        if not f.is_relative_to(archive)
        for c in archive_citations(f.read_text(encoding="utf-8"))
        if f != Path(__file__).resolve()
    ]
    assert not problems, "\n".join(problems)


def test_archive_citations_found_by_hand():
    text = (
        f"see docs/archive/estimation-notebook{MD} and [old](archive/notes{MD}), "
        f"or ../archive/x{MD}; not an_archive/y{MD} nor archived things"
    )
    assert archive_citations(text) == [
        f"docs/archive/estimation-notebook{MD}",
        f"archive/notes{MD}",
        f"../archive/x{MD}",
    ]


# -- the checker on made-up files (it must be able to fail) -------------------------------
def _tree(tmp_path: Path) -> Path:
    (tmp_path / "docs").mkdir()
    (tmp_path / "docs" / ("physics" + MD)).write_text(
        "# Title\n## 1. One\n## 2. Two\n### 2.1 Sub part\n## 3. Three\n"
    )
    (tmp_path / "docs" / ("design" + MD)).write_text("# D\n## Data flow\n## Backpressure\n")
    (tmp_path / "pkg").mkdir()
    return tmp_path


def _check(root: Path, name: str, text: str) -> list[str]:
    f = root / name
    f.write_text(text)
    return check_text(text, f, root)


def test_checker_accepts_good_references(tmp_path):
    root = _tree(tmp_path)
    phys, des = "physics" + MD, "design" + MD
    good = (
        f'"""Law (docs/{phys} section 2), ({phys} sections 1-3), ({phys} sections 1, 2 and 3),\n'
        f'({phys} 3), ({phys} {SEC}2.1), ({phys} section 2, "Sub part"),\n'
        f'({des}, "Data flow" and "Backpressure"). As the seed paper reports (section 6)."""\n'
    )
    assert _check(root, "pkg/mod.py", good) == []
    md = f"See [{phys}]({phys}) section 3 and [it](../docs/{phys}#2-two); below, {SEC}1.\n# 1 X\n"
    assert _check(root, "docs/notes" + MD, md) == []


def test_checker_names_file_and_line_of_each_broken_reference(tmp_path):
    root = _tree(tmp_path)
    phys, des = "physics" + MD, "design" + MD
    bad = (
        "x = 1\n"
        f'"""({phys} section 7)\n'  # line 2: no section 7
        f"({phys} sections 2-4)\n"  # line 3: no section 4
        f'({des}, "Threads")\n'  # line 4: no such heading
        f"(nosuch{MD})\n"  # line 5: no such file
        f'see {SEC}2"""\n'  # line 6: a bare section sign in code
    )
    problems = _check(root, "pkg/mod.py", bad)
    assert problems == [
        f"pkg/mod.py:2: {phys} has no section 7",
        f"pkg/mod.py:3: {phys} has no section 4",
        f'pkg/mod.py:4: {des} has no heading "Threads"',
        f"pkg/mod.py:5: nosuch{MD} does not exist (in the repository or docs/)",
        f"pkg/mod.py:6: {SEC}2 names no file (write e.g. physics{MD} section N)",
    ]
    # a Markdown link resolves relative to its file only, and its anchor must exist
    md = f"[a]({phys})\n[b](../docs/{phys}#nine)\n{SEC}5\n"
    assert _check(root, "pkg/readme" + MD, md) == [
        f"pkg/readme{MD}:1: {phys} does not exist (relative to the citing file)",
        f"pkg/readme{MD}:2: ../docs/{phys} has no heading with the anchor #nine",
        f"pkg/readme{MD}:3: readme{MD} has no section 5",
    ]
    assert scan(root) != []
