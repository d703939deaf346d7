"""The scheme table: which Transport class a connection string names.

Takes in: a connection string `SCHEME:ADDRESS` (a bare `zenoh` is zenoh with its defaults) and channel
names.
Gives out: the opened Transport. The table is explicit (one row per scheme, like cflib's link drivers but
without trial and error); each row names its module, imported only when a connection uses it, so
`cfstack plot` never loads zenoh and `serial:` alone loads pyserial. Transport modules import
link.transports.base only, never this table: there is no import circle.
"""

from __future__ import annotations

from importlib import import_module

from link.transports.base import Transport
from model.errors import UserError

# scheme -> "module:Class"
SCHEMES: dict[str, str] = {
    "zenoh": "link.transports.zenoh_transport:ZenohTransport",
    "udpin": "link.transports.udp:UdpInTransport",
    "udpout": "link.transports.udp:UdpOutTransport",
    "serial": "link.transports.serial_stream:SerialTransport",
    "mem": "link.transports.mem:MemTransport",
}


def parse_connection(connection: str) -> tuple[str, str]:
    """Split 'scheme:address'. A bare 'zenoh' means zenoh with its defaults."""
    scheme, sep, address = connection.partition(":")
    if not sep and scheme != "zenoh":
        raise UserError(f"connection string '{connection}' has no scheme (expected SCHEME:ADDRESS, "
                        f"schemes: {', '.join(sorted(SCHEMES))})")
    if scheme not in SCHEMES:
        raise UserError(f"unknown transport scheme '{scheme}' in '{connection}' "
                        f"(one of: {', '.join(sorted(SCHEMES))})")
    return scheme, address


def transport_class(scheme: str) -> type[Transport]:
    """The class of a scheme in the table (its module is imported now)."""
    module, _, name = SCHEMES[scheme].partition(":")
    return getattr(import_module(module), name)


def open_transport(connection: str, tx: str | None = None, rx: str | None = None, **options) -> Transport:
    """Build and open the transport a connection string names."""
    scheme, address = parse_connection(connection)
    transport = transport_class(scheme)(address, tx=tx, rx=rx, **options)
    transport.open()
    return transport
