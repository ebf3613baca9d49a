"""Control characters of untrusted text, escaped before it reaches a terminal or a log line
(docs/security.md, "Against an insider": log lines escape what they quote): C0 and C1 controls, DEL, the Unicode
line and paragraph separators and the bidirectional overrides become ``\\xNN``/``\\uNNNN``,
so a quoted value can neither forge a line nor move the cursor, clear the screen or reorder
what follows it."""

from __future__ import annotations

__all__ = ["CONTROLS", "escape_controls"]

#: code point -> its escape, for every character a terminal or a log reader acts upon
CONTROLS: dict[int, str] = {
    **{c: f"\\x{c:02x}" for c in (*range(0x20), 0x7F, *range(0x80, 0xA0))},
    **{c: f"\\u{c:04x}" for c in (0x2028, 0x2029, *range(0x202A, 0x202F), *range(0x2066, 0x206A))},
    0x0A: "\\n", 0x0D: "\\r", 0x09: "\\t",
}  # fmt: skip


def escape_controls(text: object, limit: int | None = None) -> str:
    """``str(text)`` with :data:`CONTROLS` escaped, cut to ``limit`` characters first."""
    s = text if isinstance(text, str) else str(text)
    if limit is not None and len(s) > limit:
        s = s[:limit] + "..."
    return s.translate(CONTROLS)
