"""Loading and validating scenario files (TOML) with errors that name the file and field."""

from __future__ import annotations

import tomllib
from pathlib import Path

from pydantic import ValidationError

from models.scenario import Scenario

__all__ = ["ScenarioError", "load_scenario", "SCENARIO_DIR", "resolve_scenario"]

SCENARIO_DIR = Path(__file__).resolve().parent.parent / "scenarios"


class ScenarioError(ValueError):
    """A scenario file that cannot be read or does not validate."""


def resolve_scenario(name_or_path: str | Path) -> Path:
    """A path as given, or a bundled scenario by name (``paper_bench`` -> scenarios/paper_bench.toml)."""
    p = Path(name_or_path)
    if p.exists():
        return p
    for cand in (SCENARIO_DIR / p.name, SCENARIO_DIR / f"{p.name}.toml"):
        if cand.exists():
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
    try:
        return Scenario.model_validate(data)
    except ValidationError as e:
        lines = [f"{p}: invalid scenario:"]
        for err in e.errors():
            loc = ".".join(str(x) for x in err["loc"]) or "(root)"
            lines.append(f"  {loc}: {err['msg']}")
        raise ScenarioError("\n".join(lines)) from e
