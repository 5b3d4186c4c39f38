"""The sitl's UDP socket, bound before anything slow is imported.

``scart-bench sitl`` spends seconds importing numpy, pandas and the generator before the vehicle
runs. Binding the port first means that a datagram arriving meanwhile (a one-shot client's
single HEARTBEAT) waits in the socket's buffer and is read by the first poll, instead of being
refused by a closed port. This module imports only the standard library and the project's errors.
"""

from __future__ import annotations

import socket

#: receive buffer of the vehicle's socket: a burst of setpoints or mission items never overflows it
RECV_BUFFER = 4 << 20


class SitlError(ValueError):
    """The SITL cannot be set up as asked (bad address, a scenario off the link, port in use)."""


def bind_udp(listen: tuple[str, int]) -> socket.socket:
    """A non-blocking UDP socket bound to ``listen`` (IPv6 when the host has a colon); SitlError if it cannot."""
    family = socket.AF_INET6 if ":" in listen[0] else socket.AF_INET
    try:
        sock = socket.socket(family, socket.SOCK_DGRAM)
    except OSError as exc:
        raise SitlError(f"cannot bind udp:{listen[0]}:{listen[1]}: {exc.strerror or exc}") from exc
    try:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, RECV_BUFFER)
        sock.bind(listen)
        sock.setblocking(False)
    except (OSError, OverflowError) as exc:
        sock.close()
        raise SitlError(f"cannot bind udp:{listen[0]}:{listen[1]}: {getattr(exc, 'strerror', None) or exc}") from exc
    return sock
