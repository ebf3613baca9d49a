"""service.progress: a tqdm line on a terminal, nothing otherwise."""

from __future__ import annotations

import io

from service.progress import Progress


def test_silent_when_not_a_terminal():
    buf = io.StringIO()
    p = Progress("job", stream=buf)
    for f in (0.1, 0.5, 1.0):
        p(f)
    p.done()
    assert buf.getvalue() == ""


def test_draws_label_and_percentage_when_forced():
    buf = io.StringIO()
    p = Progress("calibrate", stream=buf, force=True, max_hz=1e6)
    p(0.25)
    p(0.2)  # never backwards
    p.done()
    out = buf.getvalue()
    assert "calibrate" in out and " 25.0%" in out and "100.0%" in out
    assert out.endswith("\n")
