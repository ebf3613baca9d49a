"""pydantic-settings' environment source reading a given mapping instead of ``os.environ``.

pydantic-settings has no public way to hand ``EnvSettingsSource`` an environment of our
choosing (the tests pass one to ``load_config``). Its own ``DotEnvSettingsSource`` does it by
overriding the private hook ``_load_env_vars`` and calling
``pydantic_settings.sources.utils.parse_env_vars``; this module does the same, and
``tests/test_compat_pydantic_settings.py`` fails naming the hook when a release changes it.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from pydantic_settings import EnvSettingsSource
from pydantic_settings.sources.utils import parse_env_vars

__all__ = ["MappingEnvSource"]


class MappingEnvSource(EnvSettingsSource):
    """``EnvSettingsSource`` over ``environ`` (None: ``os.environ``, the library's own path)."""

    def __init__(self, settings_cls: Any, environ: Mapping[str, str] | None, **kwargs: Any):
        self._environ = environ
        super().__init__(settings_cls, **kwargs)

    def _load_env_vars(self) -> Mapping[str, str | None]:
        if self._environ is None:
            return super()._load_env_vars()
        return parse_env_vars(
            self._environ, self.case_sensitive, self.env_ignore_empty, self.env_parse_none_str
        )
