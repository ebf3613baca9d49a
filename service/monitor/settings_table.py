"""The table of every monitor setting (``MonitorConfig``: name, default, meaning), generated
from the code for docs/estimation.md ("Settings"); ``tests/test_settings_table.py`` keeps the
document in sync.

    python -m service.monitor.settings_table           # print the table
    python -m service.monitor.settings_table --write   # rewrite it in docs/estimation.md
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from pydantic import BaseModel

from service.monitor.config import MonitorConfig

__all__ = ["BEGIN", "END", "settings_rows", "settings_table", "replace_table"]

BEGIN = "<!-- settings:begin -->"
END = "<!-- settings:end -->"
DOC = Path(__file__).resolve().parents[2] / "docs" / "estimation.md"


def settings_rows(
    cls: type[BaseModel] = MonitorConfig, prefix: str = ""
) -> list[tuple[str, str, str]]:
    """(dotted name, default, description) of every leaf setting, in declaration order."""
    rows: list[tuple[str, str, str]] = []
    for name, f in cls.model_fields.items():
        ann = f.annotation
        if isinstance(ann, type) and issubclass(ann, BaseModel):
            rows.extend(settings_rows(ann, f"{prefix}{name}."))
            continue
        default = f.get_default(call_default_factory=True)
        text = f"`{default!r}`" if isinstance(default, str) else f"`{default:g}`"
        desc = " ".join((f.description or "").split()).replace("|", "\\|")
        rows.append((f"`{prefix}{name}`", text, desc))
    return rows


def settings_table() -> str:
    """The markdown table of ``settings_rows``."""
    lines = ["| setting | default | meaning |", "|---|---|---|"]
    lines += [f"| {n} | {d} | {t} |" for n, d, t in settings_rows()]
    return "\n".join(lines) + "\n"


def replace_table(text: str, table: str) -> str:
    """``text`` with the block between ``BEGIN`` and ``END`` replaced by ``table``."""
    a, b = text.index(BEGIN) + len(BEGIN), text.index(END)
    return text[:a] + "\n" + table + text[b:]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--write", action="store_true", help=f"rewrite the table in {DOC.name}")
    args = ap.parse_args(argv)
    table = settings_table()
    if args.write:
        DOC.write_text(replace_table(DOC.read_text(), table))
    else:
        sys.stdout.write(table)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
