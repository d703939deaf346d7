"""One end of a MAVLink link: a transport, a codec for sending, a parser for receiving, statistics, a tlog.

Takes in: messages to send (link.messages dataclasses), byte chunks from the transport, a clock
(seconds; the caller's: wall or simulation time).
Gives out: `receive()` -> list of link.messages.Received (message, system id, sequence, receive time,
signed flag; `extra` holds component_id, target_system, msgid and, for a repeated or late frame,
"sequence": "duplicate" / "late"); `stats` (LinkStats of both directions); every frame sent and every
frame delivered is appended to the tlog if one is given.

The endpoint answers nothing by itself (no automatic TIMESYNC replies or heartbeats): the caller decides
what to send. Duplicates are delivered (and flagged): dropping them is the caller's choice.
"""

from __future__ import annotations

from collections.abc import Callable

from link import deliver_kernel
from link.mavlink.codec import Codec, FrameParser
from link.mavlink.tlog import RECORD_HEADER_LEN, TlogWriter
from link.messages import Message, Received
from link.stats import REORDER_WINDOW, SEQUENCE_MODULUS, LinkStats
from link.transports.base import Transport

STREAM_SCHEMES = frozenset({"serial"})  # transports that deliver byte chunks rather than whole frames


class Endpoint:
    def __init__(
        self,
        transport: Transport,
        codec: Codec,
        parser: FrameParser | None = None,
        *,
        clock: Callable[[], float],
        tlog: TlogWriter | None = None,
        stats: LinkStats | None = None,
        shared_clock: bool = False,
        datagram: bool | None = None,
    ):
        """`parser` defaults to FrameParser(codec) (same limits and signing). `shared_clock`: the peer
        stamps messages with the same clock (lockstep simulation), so frame ages are measurable before
        any TIMESYNC. `datagram`: each received chunk is whole frames (default: unless the transport's
        scheme is a byte stream such as serial), so a frame cut short is dropped at once."""
        self.transport = transport
        self.codec = codec
        self.parser = parser if parser is not None else FrameParser(codec)
        self.clock = clock
        self.tlog = tlog
        self.stats = stats if stats is not None else LinkStats(shared_clock=shared_clock)
        self.stats.attach_parser(self.parser)
        self.datagram = (transport.scheme not in STREAM_SCHEMES) if datagram is None else datagram

    def __repr__(self) -> str:
        return f"Endpoint({self.transport.describe()}, {self.codec!r})"

    def send(self, msg: Message, target_system: int = 0) -> bytes:
        """Encode and send one message; returns the frame (also when the transport refused it)."""
        frame = self.codec.encode(msg, target_system)
        self.send_frame(frame)
        return frame

    def send_frame(self, frame: bytes) -> bool:
        """Send an already-encoded frame (e.g. relaying); False if the transport refused it."""
        ok = self.transport.send(frame)
        self.stats.record_sent(len(frame), ok)
        if ok and self.tlog is not None:
            self.tlog.write(frame)
        return ok

    def receive(self, timeout_s: float = 0.0) -> list[Received]:
        """Everything that arrived, waiting at most `timeout_s` for the first chunk."""
        return self.deliver(self.transport.receive(timeout_s))

    def deliver(self, chunks: list[bytes]) -> list[Received]:
        """Decode, count and log chunks already taken from the transport (receive() is
        deliver(transport.receive())): a caller may hold chunks back and deliver them later, at the
        receive time its clock then gives."""
        if not chunks:
            return []
        received_s = self.clock()
        decode = self.parser.feed_fields  # tuples, not Decoded records: each frame becomes a Received here
        final, stats, tlog = self.datagram, self.stats, self.tlog
        out: list[Received] = []
        for chunk in chunks:
            _deliver_fields(decode(chunk, final), stats, tlog, received_s, out)
        return out

    def close(self) -> None:
        """Close the transport and the tlog."""
        self.transport.close()
        if self.tlog is not None:
            self.tlog.close()

    def __enter__(self) -> Endpoint:
        if not self.transport.is_open:
            self.transport.open()
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def deliver_fields(fields: list[tuple], stats: LinkStats, tlog: TlogWriter | None, received_s: float,
                   out: list[Received]) -> None:
    """Each frame of `fields` (FrameParser.feed_fields' tuples) counted into `stats`, written to `tlog` and appended
    to `out` as a Received stamped received_s (the compiled twin: link.deliver_kernel)."""
    record = stats.record_frame
    for message, system_id, component_id, sequence, msgid, signed, frame, target, _ in fields:
        verdict = record(system_id, component_id, sequence, len(frame), received_s, getattr(message, "time_s", None))
        if tlog is not None:
            tlog.write(frame)
        extra = {"component_id": component_id, "target_system": target, "msgid": msgid}
        if verdict != "new":
            extra["sequence"] = verdict
        out.append(Received(message, system_id, sequence, received_s, signed, extra))


if deliver_kernel.COMPILED:
    deliver_kernel.configure(Received, SEQUENCE_MODULUS, REORDER_WINDOW, RECORD_HEADER_LEN)
_deliver_fields = deliver_kernel.deliver_fields if deliver_kernel.COMPILED else deliver_fields
