"""Settings of the monitoring daemon: pydantic models, a TOML file, environment overrides.

Every field has a default that makes the demo run with no file. Precedence (lowest first):
defaults, the TOML file, environment variables ``SERVOWATCH_<FIELD>`` with ``__`` between
nested names (``SERVOWATCH_STATION=ground2``, ``SERVOWATCH_ZENOH__CONNECT=tcp/127.0.0.1:7447``,
``SERVOWATCH_MONITOR__...``). An environment value is parsed as JSON when it parses
(numbers, booleans, lists, ``null``), else taken as a string; a list field also accepts a
comma-separated string. Errors raise :class:`ConfigError` naming the field and the file or
variable.
"""

from __future__ import annotations

import json
import os
import tomllib
import typing
from collections.abc import Mapping
from pathlib import Path
from typing import Any, Literal

from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    ValidationError,
    ValidationInfo,
    field_validator,
    model_validator,
)

from service.zenoh_util import EndpointError, check_endpoint, make_config

try:  # the issue-3 monitor owns its settings
    from service.monitor import MonitorConfig
except ImportError:  # pragma: no cover - until service.monitor lands

    class MonitorConfig(BaseModel):  # type: ignore[no-redef]
        """Placeholder for ``service.monitor.MonitorConfig`` (accepts any keys)."""

        model_config = ConfigDict(extra="allow")


__all__ = ["ConfigError", "ZenohSettings", "ServiceConfig", "load_config", "ENV_PREFIX"]

ENV_PREFIX = "SERVOWATCH_"


class ConfigError(ValueError):
    """A configuration that cannot be read or does not validate (names field and source)."""

    def __init__(self, message: str, field: str | None = None, source: str | None = None):
        where = ": ".join(x for x in (source, field) if x)
        super().__init__(f"{where}: {message}" if where else message)
        self.field = field
        self.source = source


class ZenohSettings(BaseModel):
    """How the daemon joins Zenoh (multicast scouting is always off)."""

    model_config = ConfigDict(extra="forbid")

    allow_remote: bool = Field(
        False, description="accept endpoints other than tcp/127.0.0.1 and unix sockets"
    )
    mode: Literal["peer", "client", "router"] = "peer"
    listen: list[str] = Field(default_factory=list, description="endpoints to listen on")
    connect: list[str] = Field(
        default_factory=lambda: ["tcp/127.0.0.1:7447"], description="endpoints to connect to"
    )

    @field_validator("listen", "connect")
    @classmethod
    def _endpoints(cls, v: list[str], info: ValidationInfo) -> list[str]:
        remote = bool(info.data.get("allow_remote", False))
        try:
            return [check_endpoint(e, allow_remote=remote, field=f"[{k}]") for k, e in enumerate(v)]
        except EndpointError as err:
            raise ValueError(str(err)) from None

    @model_validator(mode="after")
    def _client_connects(self) -> ZenohSettings:
        if self.mode == "client" and not self.connect:
            raise ValueError("a client needs at least one connect endpoint")
        return self

    def to_zenoh(self):
        """The :class:`zenoh.Config` for these settings (``service.zenoh_util.make_config``)."""
        return make_config(self.mode, self.listen, self.connect, allow_remote=self.allow_remote)

    def open_session(self):
        """``zenoh.open`` on these settings; SessionError (naming mode and endpoints) if it fails."""
        import zenoh

        try:
            return zenoh.open(self.to_zenoh())
        except zenoh.ZError as e:
            raise SessionError(
                f"cannot open a Zenoh session ({self.mode}, connect {self.connect}): {e}"
            ) from e


class SessionError(ConnectionError):
    """A Zenoh session that could not be opened."""


class ServiceConfig(BaseModel):
    """Settings of ``servowatch run`` (and defaults for demo and replay)."""

    model_config = ConfigDict(extra="forbid")

    station: str = Field("ground1", pattern=r"^[A-Za-z0-9_.\-]+$", description="station name")
    shard: str = Field("0", pattern=r"^[A-Za-z0-9_.\-]+$", description="shard of the fleet")
    zenoh: ZenohSettings = Field(default_factory=ZenohSettings)
    key_expr: str = Field("fleet/**/meas", min_length=1, description="measurements to watch")
    log_dir: Path = Field(Path("logs"), description="directory of the MCAP logs")
    log_name: str = Field("servowatch", min_length=1, description="MCAP file name prefix")
    rotate_bytes: int | None = Field(256 * 2**20, gt=0, description="rotate after this size")
    rotate_s: float | None = Field(3600.0, gt=0, description="rotate after this long [s]")
    flush_s: float = Field(1.0, gt=0, le=60, description="MCAP flush period [s]")
    publish_every: int = Field(10, ge=1, description="publish est/res/health every N samples")
    log_every: int = Field(
        1, ge=1, description="log est/residual every N outputs (events always; 1 = all)"
    )
    silence_s: float = Field(2.0, gt=0, description="an actuator is silent after this long [s]")
    queue_size: int = Field(200_000, ge=1, description="receive queue length (messages)")
    max_bytes: int = Field(65536, ge=64, description="largest accepted message [bytes]")
    baseline: Path | None = Field(None, description="calibration baseline file (None=default)")
    log_level: Literal["DEBUG", "INFO", "WARNING", "ERROR"] = "INFO"
    monitor: MonitorConfig = Field(default_factory=MonitorConfig)


def _loc(err: Mapping[str, Any]) -> str:
    return ".".join(str(x) for x in err.get("loc", ())) or "(root)"


def _raise_validation(e: ValidationError, source: str | None) -> typing.NoReturn:
    first = e.errors()[0]
    more = f" (and {e.error_count() - 1} more)" if e.error_count() > 1 else ""
    raise ConfigError(first["msg"] + more, _loc(first), source) from None


def _is_list_field(model: type[BaseModel], path: list[str]) -> bool:
    ann: Any = model
    for name in path:
        if not (isinstance(ann, type) and issubclass(ann, BaseModel)):
            return False
        f = ann.model_fields.get(name)
        if f is None:
            return False
        ann = f.annotation
        args = [a for a in typing.get_args(ann) if a is not type(None)]
        if typing.get_origin(ann) in (typing.Union, __import__("types").UnionType):
            ann = args[0] if len(args) == 1 else ann
    return typing.get_origin(ann) in (list, tuple)


def _env_overrides(environ: Mapping[str, str]) -> dict[str, tuple[list[str], Any, str]]:
    out = {}
    for var, raw in sorted(environ.items()):
        if not var.startswith(ENV_PREFIX) or var == ENV_PREFIX:
            continue
        path = [p.lower() for p in var[len(ENV_PREFIX) :].split("__")]
        if not all(path):
            raise ConfigError("empty name segment", var, "environment")
        if path[0] not in ServiceConfig.model_fields:
            continue  # other SERVOWATCH_* variables (e.g. for tests) are not settings
        try:
            value: Any = json.loads(raw)
        except ValueError:
            value = raw
        if _is_list_field(ServiceConfig, path) and isinstance(value, str):
            value = [s.strip() for s in value.split(",") if s.strip()]
        out[var] = (path, value, raw)
    return out


def _set(d: dict[str, Any], path: list[str], value: Any, var: str) -> None:
    for name in path[:-1]:
        nxt = d.setdefault(name, {})
        if not isinstance(nxt, dict):
            raise ConfigError(f"cannot set below a non-table value via {var}", name, "environment")
        d = nxt
    d[path[-1]] = value


def load_config(
    path: str | Path | None = None, *, environ: Mapping[str, str] | None = None
) -> ServiceConfig:
    """Defaults, then the TOML file ``path`` (if given), then ``SERVOWATCH_*`` variables.

    Raises :class:`ConfigError` naming the field and the file (or the environment variable).
    """
    env = os.environ if environ is None else environ
    data: dict[str, Any] = {}
    source = None
    if path is not None:
        source = str(path)
        try:
            data = tomllib.loads(Path(path).read_text())
        except OSError as e:
            raise ConfigError(f"cannot read: {e.strerror or e}", None, source) from None
        except tomllib.TOMLDecodeError as e:
            raise ConfigError(f"invalid TOML: {e}", None, source) from None
        try:
            ServiceConfig.model_validate(data)
        except ValidationError as e:
            _raise_validation(e, source)
    overrides = _env_overrides(env)
    for var, (p, value, _raw) in overrides.items():
        _set(data, p, value, var)
    try:
        return ServiceConfig.model_validate(data)
    except ValidationError as e:
        # name the variable when the failing field came from the environment
        first = e.errors()[0]
        loc = [str(x) for x in first.get("loc", ())]
        for var, (p, _v, raw) in overrides.items():
            n = min(len(p), len(loc))
            if loc[:n] == p[:n]:
                raise ConfigError(f"{first['msg']} (got {raw!r})", _loc(first), var) from None
        _raise_validation(e, source)
