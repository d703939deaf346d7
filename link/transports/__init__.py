"""Transports: byte pipes chosen by connection string through an explicit scheme table.

Takes in: a connection string `SCHEME:ADDRESS` (see SCHEMES) and, for keyed transports, the channel
names to send on and receive from.
Gives out: a `Transport` (open/close, send one frame, receive frames, statistics).
A new radio (e.g. a Crazyradio tunnelling MAVLink in CRTP packets) is one more class and one more row.
"""

from link.transports.base import Transport, TransportStats, open_transport, parse_connection, register_scheme

__all__ = ["Transport", "TransportStats", "open_transport", "parse_connection", "register_scheme"]
