"""Loading and validating scenario files (TOML) with errors that name the file and field."""

from __future__ import annotations

import os
import tomllib
from pathlib import Path

from pydantic import ValidationError

from models.scenario import Scenario
from service.strictnum import bool_in_number

__all__ = ["ScenarioError", "load_scenario", "SCENARIO_DIR", "resolve_scenario"]

SCENARIO_DIR = Path(__file__).resolve().parents[2] / "scenarios"


class ScenarioError(ValueError):
    """A scenario file that cannot be read or does not validate."""


def resolve_scenario(name_or_path: str | Path) -> Path:
    """The scenario file of an argument: a bare name of a bundled scenario (``paper_bench``:
    no folder, no ``.toml``) is always the bundled one (scenarios/paper_bench.toml), whatever
    the working directory holds; anything else is a path (``./demo`` for a local file named
    like a bundled scenario), or, when no such file exists, the bundled file of that name."""
    text = str(name_or_path)
    p = Path(text)
    bare = (
        text
        and "/" not in text
        and os.sep not in text
        and not text.endswith(".toml")
        and text not in (".", "..")
    )
    if bare and (SCENARIO_DIR / f"{text}.toml").is_file():
        return SCENARIO_DIR / f"{text}.toml"
    if p.is_file():
        return p
    if p.exists():
        raise ScenarioError(f"{name_or_path}: not a scenario file (a directory?)")
    for cand in (SCENARIO_DIR / p.name, SCENARIO_DIR / f"{p.name}.toml"):
        if cand.is_file():
            return cand
    raise ScenarioError(f"{name_or_path}: no such scenario file")


def load_scenario(path: str | Path) -> Scenario:
    """Read and validate a scenario TOML file."""
    p = resolve_scenario(path)
    try:
        data = tomllib.loads(p.read_text())
    except (OSError, tomllib.TOMLDecodeError) as e:
        raise ScenarioError(f"{p}: cannot read scenario: {e}") from e
    data.setdefault("name", p.stem)
    hit = bool_in_number(Scenario, data)
    if hit is not None:  # pydantic would read true as 1.0
        raise ScenarioError(
            f"{p}: invalid scenario:\n  {'.'.join(hit)}: expected a number, got a boolean"
        )
    try:
        return Scenario.model_validate(data)
    except ValidationError as e:
        lines = [f"{p}: invalid scenario:"]
        for err in e.errors():
            loc = ".".join(str(x) for x in err["loc"]) or "(root)"
            lines.append(f"  {loc}: {err['msg']}")
        raise ScenarioError("\n".join(lines)) from e
