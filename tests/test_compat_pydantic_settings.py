"""Check tests of service.compat.pydantic_settings: the private hook it overrides."""

from __future__ import annotations

import inspect

from pydantic_settings import EnvSettingsSource
from pydantic_settings.sources import utils

from service.compat.pydantic_settings import MappingEnvSource
from service.config import ServiceConfig, load_config


def test_private_hook_and_helper_exist():
    assert callable(getattr(EnvSettingsSource, "_load_env_vars", None)), (
        "pydantic-settings renamed EnvSettingsSource._load_env_vars: "
        "service/compat/pydantic_settings.py must follow"
    )
    params = list(inspect.signature(utils.parse_env_vars).parameters)
    assert params[:4] == ["env_vars", "case_sensitive", "ignore_empty", "parse_none_str"], (
        f"pydantic_settings.sources.utils.parse_env_vars changed its signature: {params}"
    )


def test_mapping_source_reads_the_given_mapping_only(monkeypatch):
    monkeypatch.setenv("SERVOWATCH_STATION", "from-os")
    src = MappingEnvSource(ServiceConfig, {"SERVOWATCH_STATION": "given"}, env_prefix="SERVOWATCH_")
    assert src()["station"] == "given"
    assert MappingEnvSource(ServiceConfig, None, env_prefix="SERVOWATCH_")()["station"] == "from-os"
    assert load_config(None, environ={"SERVOWATCH_STATION": "hooked"}).station == "hooked"
