"""The ``servowatch`` command line: the entry point (``main``, ``dispatch``), the shared arguments (``args``)
and helpers (``util``), kernel warm-up and one module per command. May import every layer.
"""

from __future__ import annotations

from collections.abc import Sequence


def main(argv: Sequence[str] | None = None) -> int:
    """``servowatch``: :func:`service.cli.dispatch.main` (imported on call, so that a command's
    helpers import without the parser)."""
    from service.cli.dispatch import main as _main

    return _main(argv)
