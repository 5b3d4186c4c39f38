"""MAVLink 2 on the Simulator <-> Navigator link: the codec, the live proxy and the generator's endpoints.

- :mod:`scart_bench.generator.mavlink.codec`: frame splitting and checking, topic <-> MAVLink message mapping;
- :mod:`scart_bench.generator.mavlink.proxy`: the man-in-the-middle that runs the SCART layer on a live link;
- :mod:`scart_bench.generator.mavlink.link`: hooks that make the built-in generator speak MAVLink over UDP
  (flight-controller side and mission-computer side as two endpoints);
- :mod:`scart_bench.generator.mavlink.recording`: the proxied flight in the dataset layout.

pymavlink is an optional dependency (``pip install scart-bench[mavlink]``); importing these
modules without it raises :class:`MavlinkMissing`.
"""

from __future__ import annotations

from scart_bench.errors import ScartBenchError

INSTALL_HINT = "pip install scart-bench[mavlink]"
#: default addresses: PX4's onboard (mission computer) link, on loopback
DEFAULT_LISTEN = "udp:127.0.0.1:14540"
DEFAULT_FORWARD = "udp:127.0.0.1:14541"


class EndpointError(ScartBenchError):
    """An address that is not ``udp:HOST:PORT``."""


def parse_endpoint(text: str, option: str = "address") -> tuple[str, int]:
    """``udp:HOST:PORT`` (or ``HOST:PORT``) as ``(host, port)``; here, free of heavy imports, so that a
    command can bind its socket before its slow start-up."""
    spec = text[4:] if text.startswith("udp:") else text
    host, sep, port = spec.rpartition(":")
    if not sep or not host or not port.isdigit() or not 0 <= int(port) <= 65535:
        raise EndpointError(f"{option} {text!r}: expected udp:HOST:PORT, e.g. udp:127.0.0.1:14540")
    return host, int(port)


class MavlinkMissing(ImportError):
    """pymavlink is not installed."""


def require_pymavlink():
    """The pymavlink MAVLink 2 ``common`` dialect module, or a clear MavlinkMissing error."""
    try:
        from pymavlink.dialects.v20 import common
    except ImportError as exc:
        raise MavlinkMissing(f"the MAVLink proxy needs pymavlink: {INSTALL_HINT}") from exc
    return common
