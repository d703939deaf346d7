"""Transports: byte pipes chosen by connection string through an explicit scheme table.

Takes in: a connection string `SCHEME:ADDRESS` (see link.transports.table.SCHEMES) and, for keyed
transports, the channel names to send on and receive from.
Gives out: a `Transport` (open/close, send one frame, receive frames, statistics).
A new radio is one more class (a subclass of link.transports.base.Transport) and one more row in the table.
"""

from link.transports.base import Transport, TransportStats
from link.transports.table import SCHEMES, open_transport, parse_connection

__all__ = ["SCHEMES", "Transport", "TransportStats", "open_transport", "parse_connection"]
