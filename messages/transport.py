"""Zenoh session configuration shared by agents, the simulator and the ground station.

Default (docs/design.md): peer mode on loopback, multicast scouting off, explicit endpoints.
Every process listens on its own TCP port and connects to the ports of the processes it knows;
gossip scouting then spreads the rest. A router (``zenohd``) or TLS is configuration: pass
``mode="client"`` and the router's endpoint in ``connect``, or a full JSON5 file.

The transport lease is shortened from Zenoh's 10 s default so that a killed process loses its
liveliness tokens within about a second, which is what lets agents drop a dead peer within 2 s.
Zenoh's shared-memory transport is off (:data:`SHARED_MEMORY`).
"""

from __future__ import annotations

import json
import re
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

ZENOH_BASE_PORT = 7447
LEASE_MS = 1000
KEEP_ALIVE_PER_LEASE = 4
CONNECT_RETRY = {"period_init_ms": 250, "period_max_ms": 1000, "period_increase_factor": 2.0}
"""How often a lost connection to a configured endpoint is retried: from 0.25 s, at most every
1 s (Zenoh's default backs off to 4 s). With the 1 s lease a daemon stalled for a few seconds
loses every link; with the default it could wait 4 s more for one peer after it resumed."""

SHARED_MEMORY = False
"""Zenoh's shared-memory transport (on by default in Zenoh 1.x). The fleet's processes run on
different computers, and on one (the demo) the first payload over its 3 KiB threshold makes a
session map a shared-memory pool: a peer envelope of 10 vehicles (3.0-3.5 KB, issue 27) grew
every daemon from 72 to 270 MB resident (46 MB for two sessions in a bare test). ``extra``
(``transport/shared_memory/enabled``) or a configuration file turns it back on."""


@dataclass(frozen=True)
class ZenohSettings:
    """How one process joins the fleet's Zenoh network."""

    mode: str = "peer"
    listen: Sequence[str] = ()
    connect: Sequence[str] = ()
    multicast_scouting: bool = False
    lease_ms: int = LEASE_MS
    config_file: str | None = None
    extra: dict[str, Any] = field(default_factory=dict)


class TransportError(ValueError):
    """A Zenoh endpoint, configuration file or session that cannot work; the message is one
    line naming it (callers print it and exit 2, never a traceback)."""


_ENDPOINT = re.compile(r"^(?P<proto>[a-z][a-z0-9-]*)/(?P<addr>[^?#]+)(?:[?#].*)?$")
_IP_PROTOCOLS = frozenset({"tcp", "udp", "tls", "quic", "ws"})
_PROTOCOLS = _IP_PROTOCOLS | {"unixsock-stream", "unixpipe", "serial", "vsock"}


def check_endpoint(endpoint: str) -> str:
    """``endpoint`` if it is a Zenoh endpoint ``<protocol>/<address>[?meta][#config]`` with a
    known protocol and, for IP protocols, ``HOST:PORT`` with a port in 0..65535; else
    :class:`TransportError`."""
    m = _ENDPOINT.match(endpoint)
    if m is None or m["proto"] not in _PROTOCOLS:
        raise TransportError(
            f"zenoh endpoint {endpoint!r}: must be <protocol>/<address> with protocol one of "
            f"{', '.join(sorted(_PROTOCOLS))} (e.g. tcp/127.0.0.1:7447)"
        )
    if m["proto"] in _IP_PROTOCOLS:
        host, sep, port = m["addr"].rpartition(":")
        if not sep or not host or not port.isdigit() or not 0 <= int(port) <= 65535:
            raise TransportError(
                f"zenoh endpoint {endpoint!r}: the address must be HOST:PORT with a port in "
                "0..65535"
            )
    return endpoint


def check_settings(settings: ZenohSettings) -> None:
    """Every endpoint valid and the configuration file readable (:class:`TransportError`)."""
    for e in [*settings.listen, *settings.connect]:
        check_endpoint(e)
    if settings.mode not in ("peer", "client", "router"):
        raise TransportError(f"zenoh mode {settings.mode!r}: must be peer, client or router")
    if settings.config_file and not Path(settings.config_file).is_file():
        raise TransportError(f"zenoh config_file {settings.config_file}: no such file")


def _zenoh_message(exc: BaseException) -> str:
    """Zenoh's error text without its source location (`` at /root/.cargo/...``)."""
    text = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
    return re.sub(r" at /\S+\.rs:\d+\.?", "", text).strip()


def loopback_endpoint(port: int) -> str:
    return f"tcp/127.0.0.1:{port}"


TLS_DEFAULT_LISTEN = "tls/127.0.0.1:0"
"""Where a TLS peer that was given no listen endpoint listens (an ephemeral loopback port: it
reaches the others by connecting to them)."""


def tls_endpoint(endpoint: str) -> str:
    """``tcp/HOST:PORT`` as ``tls/HOST:PORT`` (other protocols unchanged)."""
    return "tls/" + endpoint[4:] if endpoint.startswith("tcp/") else endpoint


def with_mutual_tls(
    settings: ZenohSettings,
    ca: Path,
    cert: Path,
    key: Path,
    access_control: dict[str, Any] | None = None,
) -> ZenohSettings:
    """``settings`` over TLS only, both sides authenticated against the fleet CA ``ca`` with
    this process's ``cert`` and ``key`` (``bearingflock keys init``; docs/flying.md).

    Every ``tcp/`` endpoint becomes ``tls/``; ``transport.link.protocols = ["tls"]`` refuses
    anything else. Names are not checked on connect (the endpoints are addresses; what counts
    is that the fleet CA signed the peer's certificate). A peer whose certificate another CA
    signed, or that has none, fails the handshake; Zenoh then opens the session anyway, with
    no peers, so callers check :func:`peer_count`. ``access_control``: the fleet's ACL
    (:func:`messages.zenoh_acl.fleet_access_control`). A peer given no listen endpoint listens on
    :data:`TLS_DEFAULT_LISTEN` (with TLS only, Zenoh refuses to open a peer without one)."""
    for path in (ca, cert, key):
        if not Path(path).is_file():
            raise ValueError(f"Zenoh TLS: {path} is missing (bearingflock keys init / issue)")
    tls = {
        "transport/link/protocols": ["tls"],
        "transport/link/tls/root_ca_certificate": str(ca),
        "transport/link/tls/listen_certificate": str(cert),
        "transport/link/tls/listen_private_key": str(key),
        "transport/link/tls/connect_certificate": str(cert),
        "transport/link/tls/connect_private_key": str(key),
        "transport/link/tls/enable_mtls": True,
        "transport/link/tls/verify_name_on_connect": False,
    }
    listen = [tls_endpoint(e) for e in settings.listen]
    if not listen and settings.mode == "peer":
        # Zenoh's default listener is tcp/[::]:0, which TLS-only refuses: no session at all
        listen = [TLS_DEFAULT_LISTEN]
    return ZenohSettings(
        mode=settings.mode,
        listen=listen,
        connect=[tls_endpoint(e) for e in settings.connect],
        multicast_scouting=settings.multicast_scouting,
        lease_ms=settings.lease_ms,
        config_file=settings.config_file,
        extra={**settings.extra, **tls, **(access_control or {})},
    )


def peer_count(session: Any) -> int:
    """How many Zenoh peers and routers a session is connected to."""
    return len(list(session.info.peers_zid())) + len(list(session.info.routers_zid()))


def zenoh_config(settings: ZenohSettings) -> Any:
    """Build a ``zenoh.Config`` (Zenoh is imported here, not at module import)."""
    import zenoh

    check_settings(settings)
    try:
        return _build_config(zenoh, settings)
    except zenoh.ZError as exc:
        raise TransportError(f"zenoh configuration: {_zenoh_message(exc)}") from None


def _build_config(zenoh: Any, settings: ZenohSettings) -> Any:
    if settings.config_file:  # the file is the whole configuration (TLS, routers, ...)
        return zenoh.Config.from_file(str(Path(settings.config_file)))
    config = zenoh.Config()
    config.insert_json5("mode", json.dumps(settings.mode))
    if settings.listen:
        config.insert_json5("listen/endpoints", json.dumps(list(settings.listen)))
    if settings.connect:
        config.insert_json5("connect/endpoints", json.dumps(list(settings.connect)))
    config.insert_json5("scouting/multicast/enabled", json.dumps(settings.multicast_scouting))
    config.insert_json5("transport/link/tx/lease", json.dumps(settings.lease_ms))
    config.insert_json5("transport/link/tx/keep_alive", json.dumps(KEEP_ALIVE_PER_LEASE))
    config.insert_json5("connect/retry", json.dumps(CONNECT_RETRY))
    config.insert_json5("transport/shared_memory/enabled", json.dumps(SHARED_MEMORY))
    for key, value in settings.extra.items():
        config.insert_json5(key, json.dumps(value))
    return config


def open_session(settings: ZenohSettings) -> Any:
    """Open a Zenoh session with :func:`zenoh_config`; :class:`TransportError` (one line) for a
    bad endpoint or file, or a session Zenoh cannot open (e.g. a listen port in use)."""
    import zenoh

    config = zenoh_config(settings)
    try:
        return zenoh.open(config)
    except zenoh.ZError as exc:
        raise TransportError(f"zenoh: cannot open the session: {_zenoh_message(exc)}") from None


def publisher_put(session: Any) -> Callable[[str, bytes], None]:
    """A ``put(key, data)`` that declares one publisher per key on first use and reuses it."""
    publishers: dict[str, Any] = {}

    def put(key: str, data: bytes) -> None:
        pub = publishers.get(key)
        if pub is None:
            pub = publishers[key] = session.declare_publisher(key)
        pub.put(data)

    return put
