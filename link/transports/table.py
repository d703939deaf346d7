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
# Schemes that route by channel name (one address carries every channel); the others are point-to-point:
# the address is the channel, so each vehicle needs its own.
KEYED_SCHEMES = frozenset({"zenoh", "mem"})
# Schemes whose receive() hands over whole frames, one sample per send (serial gives byte chunks).
DATAGRAM_SCHEMES = frozenset({"zenoh", "mem", "udpin", "udpout"})


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


def transport_options(connection: str, zenoh_options: dict) -> dict:
    """The options open_transport takes for `connection`: the zenoh session's for a zenoh connection, none for
    the others (they take none of zenoh's)."""
    return zenoh_options if parse_connection(connection)[0] == "zenoh" else {}


def for_vehicle(connection: str, vehicle_id: int) -> str:
    """The connection string of vehicle `vehicle_id`'s own link, from the one given for the fleet: keyed
    schemes carry every vehicle on one address (the keys tell them apart); UDP gives vehicle N the port
    PORT+N-1 (CrazySim's and PX4 SITL's convention for many vehicles); a serial device is one vehicle's."""
    scheme, address = parse_connection(connection)
    if scheme in KEYED_SCHEMES or vehicle_id == 1:
        return connection
    if scheme in ("udpin", "udpout"):
        host, sep, port_text = address.rpartition(":")
        if sep and port_text.isdigit():
            port = int(port_text) + vehicle_id - 1
            if port > 65535:
                raise UserError(f"'{connection}': no UDP port left for vehicle {vehicle_id} (PORT+{vehicle_id - 1} "
                                f"> 65535)")
            return f"{scheme}:{host}:{port}"
        return connection  # malformed: the transport names the problem when it opens
    raise UserError(f"'{connection}': a {scheme} link carries one vehicle, not vehicle {vehicle_id} "
                    "(use udpin/udpout or zenoh for a fleet)")


def far_end(connection: str) -> str:
    """The connection string the other end of a link opens: udpin and udpout swap on the same address, a
    keyed scheme is the same string; a serial device has no far end this machine can name (UserError)."""
    scheme, address = parse_connection(connection)
    if scheme in KEYED_SCHEMES:
        return connection
    if scheme in ("udpin", "udpout"):
        return f"{'udpout' if scheme == 'udpin' else 'udpin'}:{address}"
    raise UserError(f"'{connection}': the far end of a {scheme} line is another device; start `cfstack emulator "
                    "--radio-link ...` on it yourself and connect to it")


def check_radio_link(connection: str, vehicles: int, clock: str) -> None:
    """One-line UserError for a radio link no emulator can run on: an unknown scheme, a point-to-point
    address that cannot carry the fleet, or a byte stream under the lockstep clock (whose ticks count the
    samples of each channel: a serial line delivers bytes cut anywhere, so nothing can count them)."""
    scheme, _ = parse_connection(connection)
    for_vehicle(connection, vehicles)
    if clock == "lockstep" and scheme not in DATAGRAM_SCHEMES:
        raise UserError(f"radio link '{connection}': the lockstep clock counts whole frames, and a {scheme} "
                        "line delivers a byte stream; use --clock realtime (or a udp/zenoh radio link)")


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
