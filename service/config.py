"""Settings of the monitoring daemon: pydantic models, a TOML file, environment overrides.

Every field has a default that makes the demo run with no file. Precedence (lowest first):
defaults, the TOML file, environment variables ``SERVOWATCH_<FIELD>`` with ``__`` between
nested names (``SERVOWATCH_STATION=ground2``, ``SERVOWATCH_ZENOH__CONNECT=tcp/127.0.0.1:7447``,
``SERVOWATCH_ZENOH__TLS__ROOT_CA=/etc/servowatch/pki/ca.pem``, ``SERVOWATCH_MONITOR__...``).
The environment is read by pydantic-settings (``EnvSettingsSource``): a list, table or
model value is JSON, ``null`` is None, and the endpoint lists also accept a comma-separated
string. Errors raise :class:`ConfigError` naming the field and the file or variable.

TLS (docs/security.md): ``[zenoh.tls]`` holds paths only (``root_ca``, ``cert``, ``key``);
no secret is ever a setting value, so none can reach a command line or a log.
"""

from __future__ import annotations

import os
import tomllib
import typing
from collections.abc import Mapping
from pathlib import Path
from typing import Annotated, Any, Literal

from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    ValidationError,
    ValidationInfo,
    field_validator,
    model_validator,
)
from pydantic_settings import NoDecode
from pydantic_settings.exceptions import SettingsError

from service.compat.pydantic_settings import MappingEnvSource
from service.log.settings import LogSettings
from service.monitor import MonitorConfig
from service.names import NAME_PATTERN
from service.paths import DEFAULT_LOG_DIR
from service.strictnum import bool_in_number
from service.zenoh_util import EndpointError, check_endpoint, diagnose_link, make_config

#: a station, shard or group name: the station's one grammar (service.names)
_NAME = rf"^{NAME_PATTERN}$"

__all__ = [
    "ConfigError",
    "TlsSettings",
    "ZenohSettings",
    "ServiceConfig",
    "PrognosticsSettings",
    "ClockSettings",
    "FoxgloveSettings",
    "SessionError",
    "AuthError",
    "load_config",
    "ENV_PREFIX",
    "EXIT_UNREACHABLE",
    "EXIT_REFUSED",
]

ENV_PREFIX = "SERVOWATCH_"
#: exit code of a command whose Zenoh session could not be opened (nobody listening, ...)
EXIT_UNREACHABLE = 3
#: exit code of a command whose connection was refused by the router's TLS (certificate
#: missing, not signed by the station CA, expired) or whose router certificate is not trusted
EXIT_REFUSED = 4


class ConfigError(ValueError):
    """A configuration that cannot be read or does not validate (names field and source)."""

    def __init__(self, message: str, field: str | None = None, source: str | None = None):
        where = ": ".join(x for x in (source, field) if x)
        super().__init__(f"{where}: {message}" if where else message)
        self.field = field
        self.source = source


class TlsSettings(BaseModel):
    """TLS files of a Zenoh client (paths only; PEM). Used by every ``tls/`` endpoint.

    ``root_ca`` is the CA certificate that signed the router's certificate (the station CA);
    ``cert`` and ``key`` are this identity's certificate and private key for mutual TLS: the
    router's access-control rules know the identity by the certificate's common name.
    """

    model_config = ConfigDict(extra="forbid")

    root_ca: Path | None = Field(None, description="CA certificate (PEM) trusted for the router")
    cert: Path | None = Field(None, description="this identity's certificate (PEM), mutual TLS")
    key: Path | None = Field(None, description="private key (PEM) of cert; mode 0600")

    @field_validator("root_ca", "cert", "key")
    @classmethod
    def _readable(cls, v: Path | None) -> Path | None:
        if v is not None:
            v = v.expanduser()
            if not v.is_file():
                raise ValueError(f"no such file: {v}")
            if not os.access(v, os.R_OK):
                raise ValueError(f"not readable by this user: {v}")
        return v

    @model_validator(mode="after")
    def _pair(self) -> TlsSettings:
        if (self.cert is None) != (self.key is None):
            raise ValueError("cert and key go together (both or neither)")
        return self

    def to_zenoh(self, listen: bool = False) -> dict[str, Any]:
        """Zenoh config paths (``transport/link/tls/...``) for these files."""
        out: dict[str, Any] = {}
        base = "transport/link/tls/"
        if self.root_ca is not None:
            out[base + "root_ca_certificate"] = str(self.root_ca)
        if self.cert is not None and self.key is not None:
            out[base + "connect_certificate"] = str(self.cert)
            out[base + "connect_private_key"] = str(self.key)
            out[base + "enable_mtls"] = True
            if listen:
                out[base + "listen_certificate"] = str(self.cert)
                out[base + "listen_private_key"] = str(self.key)
        return out


_Endpoints = Annotated[list[str], NoDecode]


class ZenohSettings(BaseModel):
    """How the daemon joins Zenoh (multicast scouting is always off)."""

    model_config = ConfigDict(extra="forbid")

    allow_remote: bool = Field(
        False, description="accept endpoints other than tcp|tls/127.0.0.1 and unix sockets"
    )
    allow_plain_listen: bool = Field(
        False,
        description="with allow_remote: accept a non-loopback listen endpoint without TLS "
        "(tcp/...; unauthenticated, logged as a warning)",
    )
    mode: Literal["peer", "client", "router"] = "peer"
    listen: _Endpoints = Field(default_factory=list, description="endpoints to listen on")
    connect: _Endpoints = Field(
        default_factory=lambda: ["tcp/127.0.0.1:7447"], description="endpoints to connect to"
    )
    tls: TlsSettings = Field(default_factory=TlsSettings)

    @field_validator("listen", "connect", mode="before")
    @classmethod
    def _split(cls, v: Any) -> Any:
        """An environment value: a JSON list, or endpoints separated by commas."""
        if isinstance(v, str):
            import json

            if v.lstrip().startswith("["):
                return json.loads(v)
            return [e.strip() for e in v.split(",") if e.strip()]
        return v

    @field_validator("listen", "connect")
    @classmethod
    def _endpoints(cls, v: list[str], info: ValidationInfo) -> list[str]:
        remote = bool(info.data.get("allow_remote", False))
        plain = bool(info.data.get("allow_plain_listen", False))
        listen = info.field_name == "listen"
        try:
            return [
                check_endpoint(
                    e, allow_remote=remote, field=f"[{k}]", listen=listen, allow_plain_listen=plain
                )
                for k, e in enumerate(v)
            ]
        except EndpointError as err:
            raise ValueError(str(err)) from None

    @model_validator(mode="after")
    def _client_connects(self) -> ZenohSettings:
        if self.mode == "client" and not self.connect:
            raise ValueError("a client needs at least one connect endpoint")
        if any(e.startswith("tls/") for e in self.connect) and self.tls.root_ca is None:
            raise ValueError("tls.root_ca: a tls/ connect endpoint needs the CA certificate")
        if any(e.startswith("tls/") for e in self.listen) and self.tls.cert is None:
            raise ValueError("tls.cert: a tls/ listen endpoint needs a certificate and key")
        return self

    def to_zenoh(self):
        """The :class:`zenoh.Config` for these settings (``service.zenoh_util.make_config``)."""
        return make_config(
            self.mode,
            self.listen,
            self.connect,
            allow_remote=self.allow_remote,
            allow_plain_listen=self.allow_plain_listen,
            extra=self.tls.to_zenoh(listen=bool(self.listen)),
        )

    def open_session(self):
        """``zenoh.open`` on these settings.

        Raises :class:`AuthError` (exit code :data:`EXIT_REFUSED`) when a connect endpoint
        refused the TLS handshake or its certificate is not trusted, else :class:`SessionError`
        (:data:`EXIT_UNREACHABLE`); both name the endpoint and the reason. Zenoh's own error
        does not say why, so each connect endpoint is probed once (``diagnose_link``).
        """
        import zenoh

        try:
            return zenoh.open(self.to_zenoh())
        except zenoh.ZError as e:
            reasons = []
            for ep in self.connect:
                kind, why = diagnose_link(ep, self.tls.root_ca, self.tls.cert, self.tls.key)
                if kind == "refused":
                    raise AuthError(f"connection to {ep} refused: {why}") from e
                reasons.append(f"{ep}: {why}")
            detail = "; ".join(reasons) if reasons else str(e)
            raise SessionError(f"cannot open a Zenoh session ({self.mode}): {detail}") from e


class SessionError(ConnectionError):
    """A Zenoh session that could not be opened (the router is not reachable)."""

    exit_code = EXIT_UNREACHABLE


class AuthError(SessionError):
    """A connection the router refused at the TLS handshake, or a router not trusted."""

    exit_code = EXIT_REFUSED


class PrognosticsSettings(BaseModel):
    """Operating periods and auto-commissioning of the daemon (docs/prognostics.md)."""

    model_config = ConfigDict(extra="forbid")

    period_window_s: float = Field(600.0, gt=0, description="close a period after this long [s]")
    flight_gap_s: float = Field(
        1800.0, gt=0, description="gap rule: a longer gap between periods starts a new flight [s]"
    )
    period_silence_s: float = Field(
        5.0, gt=0, description="a sample gap longer than this closes a period [s]"
    )
    auto_commission_s: float | None = Field(
        None,
        gt=0,
        description="commission an actuator without a baseline from its first this-many "
        "seconds of healthy-looking data (None = off; docs/prognostics.md, the risk)",
    )
    auto_commission_min_in_band: float = Field(
        0.8, gt=0, le=1, description="... healthy-looking: no alarm and this share of NIS in band"
    )


class ClockSettings(BaseModel):
    """Time plausibility of each stream's samples (``service.daemon.intake.ClockCheck``)."""

    model_config = ConfigDict(extra="forbid")

    factor: float = Field(
        2.0, ge=1, le=1e3, description="a sample may lead by factor x seq gap x period"
    )
    tol_s: float = Field(0.5, gt=0, le=3600, description="plus this tolerance [s]")
    future_s: float = Field(
        5.0, gt=0, le=86400, description="live data: max lead on the receiving clock [s]"
    )
    resync_n: int = Field(
        5, ge=1, le=10000, description="consistent samples that re-synchronise a jumped clock"
    )


class GroupSettings(BaseModel):
    """A monitor group (``service.daemon.group``): daemons of one ``name`` share the units
    their ``key_expr`` receives, each unit monitored by exactly one live member."""

    model_config = ConfigDict(extra="forbid")

    name: str = Field(..., pattern=_NAME, description="group name")
    join_s: float = Field(
        1.0, gt=0, le=60, description="wait this long for the other members before owning [s]"
    )
    takeover_s: float = Field(
        2.0, ge=0, le=60, description="messages of others' units kept for a takeover [s]"
    )
    unmonitored_s: float = Field(
        5.0,
        gt=0,
        le=600,
        description="a unit whose measurements arrive with no health output from any member "
        "for this long raises 'unmonitored' [s]",
    )
    stations: list[str] = Field(
        [],
        description="stations whose daemons may be members (besides this one's own); a "
        "token of any other station is ignored and counted (docs/security.md)",
    )


class FoxgloveSettings(BaseModel):
    """The live Foxglove WebSocket server (``service.edge.foxglove_feed``, docs/dashboard.md):
    loopback unless ``allow_remote`` (docs/security.md, "HTTP")."""

    model_config = ConfigDict(extra="forbid")

    listen: str = Field("127.0.0.1:8765", description="HOST:PORT of the WebSocket server")
    allow_remote: bool = Field(
        False, description="allow a non-loopback host (only behind an authenticating TLS proxy)"
    )
    queue_size: int = Field(
        20_000, ge=1, le=10_000_000, description="messages waiting for the feeder at most"
    )
    backlog: int = Field(
        1024, ge=1, le=1_000_000, description="messages buffered per client (oldest dropped)"
    )
    every: int = Field(
        10, ge=1, le=100_000, description="send one row in N per topic (events: all; 1 = all)"
    )
    max_connections: int = Field(
        16, ge=1, le=4096, description="WebSocket clients at once (beyond: refused, 503)"
    )
    allowed_origins: list[str] = Field(
        [],
        description="browser origins allowed besides the server's own, e.g. "
        "'https://app.foxglove.dev' (docs/security.md)",
    )
    max_message_bytes: int = Field(
        65536, ge=1024, le=1 << 26, description="a client's message at most (beyond: cut) [bytes]"
    )
    message_s: float = Field(
        10.0, gt=0, le=3600, description="an unfinished client frame or message is cut after [s]"
    )
    max_backlog_bytes: int = Field(
        1 << 20,
        ge=4096,
        le=1 << 30,
        description="bytes waiting for a client at most (beyond: the client is dropped)",
    )
    idle_s: float = Field(
        60.0, gt=0, le=86400,
        description="a viewer that sends nothing this long is cut; it is pinged after a "
        "third of it (a browser answers by itself) [s]",
    )  # fmt: skip
    max_per_address: int = Field(
        0, ge=0, le=4096,
        description="viewer slots one address holds at most (0: max_connections // 2)",
    )  # fmt: skip
    max_pending: int = Field(
        64, ge=1, le=65536,
        description="connections in their handshake at once (beyond: the oldest dropped); "
        "they do not count against max_connections",
    )  # fmt: skip

    @model_validator(mode="after")
    def _loopback(self) -> FoxgloveSettings:
        from service.edge.listen import check_listen

        check_listen(
            self.listen, allow_remote=self.allow_remote, flag="listen",
            what="the Foxglove server", allow="allow_remote = true",
        )  # fmt: skip
        return self

    def host_port(self) -> tuple[str, int]:
        """(host, port) of ``listen``."""
        from service.edge.listen import check_listen

        return check_listen(self.listen, allow_remote=self.allow_remote)

    def guard_limits(self):
        """The ``service.edge.foxglove_guard.GuardLimits`` of these settings."""
        from service.edge.foxglove_guard import GuardLimits

        return GuardLimits(
            max_connections=self.max_connections, allowed_origins=tuple(self.allowed_origins),
            max_message_bytes=self.max_message_bytes, message_s=self.message_s,
            max_backlog_bytes=self.max_backlog_bytes, allow_remote=self.allow_remote,
            idle_s=self.idle_s, max_per_address=self.max_per_address,
            max_pending=self.max_pending,
        )  # fmt: skip


class MetricsSettings(BaseModel):
    """The daemon's OpenMetrics endpoint (``service.edge.metrics``, docs/dashboard.md,
    "Prometheus"): loopback unless ``allow_remote`` (docs/security.md, "HTTP")."""

    model_config = ConfigDict(extra="forbid")

    listen: str = Field("127.0.0.1:9464", description="HOST:PORT of the /metrics endpoint")
    allow_remote: bool = Field(
        False, description="allow a non-loopback host (only behind an authenticating TLS proxy)"
    )
    max_connections: int = Field(
        8, ge=1, le=1024, description="connections served at once (beyond: 503, closed)"
    )
    idle_s: float = Field(
        5.0, gt=0, le=300, description="a connection idle this long is closed [s]"
    )
    max_per_s: float = Field(
        10.0, gt=0, le=10000, description="requests served a second at most (beyond: 503)"
    )

    @model_validator(mode="after")
    def _loopback(self) -> MetricsSettings:
        from service.edge.listen import check_listen

        check_listen(
            self.listen, allow_remote=self.allow_remote, flag="listen",
            what="the metrics endpoint", allow="allow_remote = true",
        )  # fmt: skip
        return self

    def host_port(self) -> tuple[str, int]:
        """(host, port) of ``listen``."""
        from service.edge.listen import check_listen

        return check_listen(self.listen, allow_remote=self.allow_remote)


class ServiceConfig(BaseModel):
    """Settings of ``servowatch run`` (and defaults for demo and replay)."""

    model_config = ConfigDict(extra="forbid")

    station: str = Field("ground1", pattern=_NAME, description="station name")
    shard: str = Field("0", pattern=_NAME, description="shard of the fleet")
    zenoh: ZenohSettings = Field(default_factory=ZenohSettings)
    key_expr: str = Field("fleet/**/meas", min_length=1, description="measurements to watch")
    log_dir: Path = Field(
        DEFAULT_LOG_DIR,
        description="directory of the MCAP logs (beside the default store "
        "servowatch-data/health.sqlite)",
    )
    log: LogSettings = Field(default_factory=LogSettings)
    log_name: str = Field("servowatch", min_length=1, description="MCAP file name prefix")
    rotate_bytes: int | None = Field(256 * 2**20, gt=0, description="rotate after this size")
    rotate_s: float | None = Field(3600.0, gt=0, description="rotate after this long [s]")
    flush_s: float = Field(1.0, gt=0, le=60, description="MCAP flush period [s]")
    publish_every: int = Field(10, ge=1, description="publish est/res/health every N samples")
    log_every: int = Field(
        1, ge=1, description="log est/residual every N outputs (events always; 1 = all)"
    )
    silence_s: float = Field(2.0, gt=0, description="an actuator is silent after this long [s]")
    max_units_per_aircraft: int = Field(
        64,
        ge=1,
        le=1000,
        description="units of one aircraft tracked at most (further ones refused and counted)",
    )
    unit_expire_s: float = Field(
        3600.0, gt=0, description="a unit silent this long leaves the unit table [s]"
    )
    queue_size: int = Field(200_000, ge=1, description="receive queue length (messages)")
    max_bytes: int = Field(65536, ge=64, description="largest accepted message [bytes]")
    baseline: Path | None = Field(None, description="calibration baseline file (None=default)")
    store: str | None = Field(
        None,
        min_length=1,
        description="health store: SQLite path or postgresql:// URL; None: `servowatch run` "
        "uses $SERVOWATCH_STORE or servowatch-data/health.sqlite; 'off': none",
    )
    prognostics: PrognosticsSettings = Field(default_factory=PrognosticsSettings)
    log_level: Literal["DEBUG", "INFO", "WARNING", "ERROR"] = "INFO"
    monitor: MonitorConfig = Field(default_factory=MonitorConfig)
    clock: ClockSettings = Field(default_factory=ClockSettings)
    group: GroupSettings | None = Field(
        None, description="share the units with the other daemons of a monitor group"
    )
    foxglove: FoxgloveSettings | None = Field(
        None, description="serve the channels live to Foxglove (None: no server)"
    )
    metrics: MetricsSettings | None = Field(
        None, description="serve OpenMetrics for Prometheus on /metrics (None: no endpoint)"
    )


def _loc(err: Mapping[str, Any]) -> str:
    return ".".join(str(x) for x in err.get("loc", ())) or "(root)"


def _raise_validation(e: ValidationError, source: str | None) -> typing.NoReturn:
    first = e.errors()[0]
    more = f" (and {e.error_count() - 1} more)" if e.error_count() > 1 else ""
    raise ConfigError(first["msg"] + more, _loc(first), source) from None


def _environment(environ: Mapping[str, str] | None) -> MappingEnvSource:
    """pydantic-settings' environment source over ``environ`` (tests) or ``os.environ``."""
    return MappingEnvSource(
        ServiceConfig,  # a BaseModel: only its fields are read
        environ,
        case_sensitive=False,
        env_prefix=ENV_PREFIX,
        env_nested_delimiter="__",
        env_parse_none_str="null",
    )


def _merge(base: dict[str, Any], over: Mapping[str, Any]) -> dict[str, Any]:
    """``base`` with ``over`` laid on top, tables merged key by key."""
    out = dict(base)
    for k, v in over.items():
        if isinstance(v, Mapping) and isinstance(out.get(k), dict):
            out[k] = _merge(out[k], v)
        else:
            out[k] = v
    return out


def _variable(environ: Mapping[str, str], loc: list[str]) -> tuple[str, str] | None:
    """The ``SERVOWATCH_*`` variable (and its value) that set the field at ``loc``, if any."""
    upper = {k.upper(): v for k, v in environ.items()}
    for n in range(len(loc), 0, -1):
        var = ENV_PREFIX + "__".join(loc[:n]).upper()
        if var in upper:
            return var, upper[var]
    return None


def _get(data: Mapping[str, Any], loc: tuple[str, ...]) -> Any:
    for k in loc:
        data = data[int(k)] if isinstance(data, list) else data[k]
    return data


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
        overrides = _environment(environ)()
    except SettingsError as e:  # a JSON value that does not parse
        field = str(e).split('"')[1] if '"' in str(e) else None
        hit = _variable(env, [field]) if field else None
        raise ConfigError(f"invalid value: {e}", field, hit[0] if hit else "environment") from None
    merged = _merge(data, overrides)
    hit = bool_in_number(ServiceConfig, merged)
    if hit is not None:  # pydantic would read true as 1 (rotate_bytes = true: 1 byte)
        got = _get(merged, hit)
        raise ConfigError(
            f"expected a number, got the boolean {str(got).lower()}", ".".join(hit), source
        )
    try:
        return ServiceConfig.model_validate(merged)
    except ValidationError as e:
        # name the variable when the failing field came from the environment
        first = e.errors()[0]
        hit = _variable(env, [str(x) for x in first.get("loc", ())])
        if hit is not None:
            raise ConfigError(f"{first['msg']} (got {hit[1]!r})", _loc(first), hit[0]) from None
        _raise_validation(e, source)
