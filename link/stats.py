"""Link statistics: frame counts, loss from MAVLink sequence numbers, latency from TIMESYNC.

Takes in: frames sent (`record_sent`), frames received (`record_received` with the Decoded record, the
receive time and the message's sample time), authentic frames the parser did not deliver
(`record_undelivered`, so their sequence numbers do not look lost), the parser's drop counters
(`attach_parser`), and TIMESYNC round trips (`TimeSyncTracker`).
Gives out: `LinkStats.snapshot()` -> `LinkSnapshot`, a frozen record with `as_dict()` (flat, for JSON and
CSV logs) and `summary()` (one line for a terminal).

Definitions:
- lost: sequence numbers skipped per (system id, component id) stream. Sequences are 8-bit; each one is
  unwrapped to the value nearest the newest seen (so gaps and late frames up to 127 apart are told
  apart). A late frame filling a gap un-counts one lost frame and counts one reordered frame; a frame
  whose sequence was already seen counts as a duplicate. Gaps older than 128 frames are final.
  A run of 128 or more lost frames in a row is ambiguous (sequences wrap) and is undercounted.
- loss_ratio = lost / (lost + unique frames received).
- TIMESYNC (requester side): RTT = t_reply_rx - ts1; clock offset = (ts1 + t_reply_rx)/2 - tc1, i.e.
  offset = local clock - remote clock (PX4's convention), assuming a symmetric path.
- one-way age of a frame = receive time - sample time - offset (seconds), computed when the clocks are
  shared (lockstep simulation, one machine: offset 0 until TIMESYNC measures one) or once TIMESYNC has
  given an offset. The offset used is the median of the last `OFFSET_MEDIAN_OF` samples.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Callable
from dataclasses import asdict, dataclass

import numpy as np

from link.messages import TimeSync

SEQUENCE_MODULUS = 256
REORDER_WINDOW = 128  # half the sequence space: nearer is "late", farther is "ahead"
OFFSET_MEDIAN_OF = 16
DEFAULT_SAMPLE_WINDOW = 10_000  # latency samples kept for percentiles


class SequenceTracker:
    """Loss, duplicates and reordering from 8-bit sequence numbers, per (system, component) stream."""

    def __init__(self):
        self.lost = 0
        self.duplicates = 0
        self.reordered = 0
        self.unique = 0
        # stream key (system id * 256 + component id, both 8-bit) ->
        # [newest unwrapped sequence, missing set, missing in order (lazy deletes)]
        self._streams: dict[int, list] = {}

    def observe(self, system_id: int, component_id: int, sequence: int) -> str:
        """Record one frame; returns "new", "late" (filled a gap), or "duplicate"."""
        key = (system_id << 8) | component_id  # an int key: no tuple to build per frame
        stream = self._streams.get(key)
        if stream is None:
            self._streams[key] = [sequence, set(), deque()]
            self.unique += 1
            return "new"
        newest = stream[0]
        delta = (sequence - newest + REORDER_WINDOW) % SEQUENCE_MODULUS - REORDER_WINDOW
        if delta > 0:
            unwrapped = newest + delta
            stream[0] = unwrapped
            order = stream[2]
            if delta > 1:
                gap = range(newest + 1, unwrapped)
                stream[1].update(gap)
                order.extend(gap)
                self.lost += delta - 1
            if order:
                horizon = unwrapped - REORDER_WINDOW
                while order and order[0] < horizon:  # too old to come back: stays lost
                    stream[1].discard(order.popleft())
            self.unique += 1
            return "new"
        missing = stream[1]
        unwrapped = newest + delta
        if delta < 0 and unwrapped in missing:
            missing.discard(unwrapped)
            self.lost -= 1
            self.reordered += 1
            self.unique += 1
            return "late"
        self.duplicates += 1
        return "duplicate"


@dataclass(frozen=True)
class TimeSyncSample:
    rtt_s: float
    offset_s: float  # local clock - remote clock


@dataclass(frozen=True)
class LinkSnapshot:
    """Statistics of one endpoint at one moment. Latencies in ms; NaN where there is no sample."""

    tx_frames: int
    tx_bytes: int
    tx_errors: int
    rx_frames: int
    rx_bytes: int
    rx_lost: int
    rx_duplicates: int
    rx_reordered: int
    rx_loss_ratio: float
    crc_failures: int
    signature_failures: int
    unsigned_rejected: int
    bad_signatures: int
    replays_rejected: int
    garbage_bytes: int
    unknown_messages: int
    unsupported_messages: int
    dropped_frames: int
    rtt_samples: int
    rtt_p50_ms: float
    rtt_p99_ms: float
    clock_offset_ms: float
    age_samples: int
    age_p50_ms: float
    age_p99_ms: float

    def as_dict(self) -> dict[str, int | float]:
        return asdict(self)

    def summary(self) -> str:
        return (
            f"tx {self.tx_frames} fr {self.tx_bytes} B | rx {self.rx_frames} fr {self.rx_bytes} B, "
            f"lost {self.rx_lost} ({100.0 * self.rx_loss_ratio:.2f} %), dup {self.rx_duplicates}, "
            f"reord {self.rx_reordered}, crc {self.crc_failures}, sig {self.signature_failures}, "
            f"dropped {self.dropped_frames} | rtt p50/p99 {self.rtt_p50_ms:.3f}/{self.rtt_p99_ms:.3f} ms, "
            f"offset {self.clock_offset_ms:.3f} ms, "
            f"age p50/p99 {self.age_p50_ms:.3f}/{self.age_p99_ms:.3f} ms"
        )


def _percentiles_ms(samples: deque) -> tuple[float, float]:
    if not samples:
        return math.nan, math.nan
    p50, p99 = np.percentile(np.fromiter(samples, float, len(samples)), [50.0, 99.0])
    return float(p50) * 1e3, float(p99) * 1e3


class LinkStats:
    """Both directions of one endpoint. `shared_clock`: sender and receiver read the same clock."""

    def __init__(self, shared_clock: bool = False, sample_window: int = DEFAULT_SAMPLE_WINDOW):
        self.shared_clock = shared_clock
        self.tx_frames = 0
        self.tx_bytes = 0
        self.tx_errors = 0
        self.rx_frames = 0
        self.rx_frame_bytes = 0
        self.sequences = SequenceTracker()
        self.rtt_s: deque[float] = deque(maxlen=sample_window)
        self.offset_s: deque[float] = deque(maxlen=sample_window)
        self.age_s: deque[float] = deque(maxlen=sample_window)
        self._parser = None
        self._offset_estimate: float | None = None

    def attach_parser(self, parser) -> None:
        """Take drop counters (CRC, signatures, garbage...) and received bytes from this FrameParser,
        and have it report the sequence numbers of authentic frames it does not deliver."""
        self._parser = parser
        parser.frame_observer = self.record_undelivered

    # -- recording -------------------------------------------------------------------------------

    def record_sent(self, frame_len: int, ok: bool = True) -> None:
        if ok:
            self.tx_frames += 1
            self.tx_bytes += frame_len
        else:
            self.tx_errors += 1

    def record_received(self, decoded, received_s: float, sample_time_s: float | None = None) -> str:
        """Record a delivered frame (a codec.Decoded); returns its sequence verdict ("new", "late",
        "duplicate"). With a sample time and a usable clock offset, records the frame's one-way age."""
        return self.record_frame(decoded.system_id, decoded.component_id, decoded.sequence, len(decoded.frame),
                                 received_s, sample_time_s)

    def record_frame(self, system_id: int, component_id: int, sequence: int, frame_len: int,
                     received_s: float, sample_time_s: float | None = None) -> str:
        """record_received from the frame's header fields and length (no Decoded record needed)."""
        self.rx_frames += 1
        self.rx_frame_bytes += frame_len
        if sample_time_s is not None:
            offset = self._offset_estimate  # clock_offset_s, read without the property call (per frame)
            if offset is None and self.shared_clock:
                offset = 0.0
            if offset is not None:
                self.age_s.append(received_s - sample_time_s - offset)
        return self.sequences.observe(system_id, component_id, sequence)

    def record_undelivered(self, system_id: int, component_id: int, sequence: int) -> None:
        self.sequences.observe(system_id, component_id, sequence)

    def record_timesync(self, sample: TimeSyncSample) -> None:
        self.rtt_s.append(sample.rtt_s)
        self.offset_s.append(sample.offset_s)
        recent = list(self.offset_s)[-OFFSET_MEDIAN_OF:]
        self._offset_estimate = float(np.median(recent))

    @property
    def clock_offset_s(self) -> float | None:
        """local - remote clock (s): measured by TIMESYNC, else 0 for a shared clock, else None."""
        if self._offset_estimate is not None:
            return self._offset_estimate
        return 0.0 if self.shared_clock else None

    # -- reading ---------------------------------------------------------------------------------

    def snapshot(self) -> LinkSnapshot:
        seq = self.sequences
        counters = self._parser.counters if self._parser is not None else None

        def parser_count(name: str) -> int:
            return getattr(counters, name) if counters is not None else 0

        rtt_p50, rtt_p99 = _percentiles_ms(self.rtt_s)
        age_p50, age_p99 = _percentiles_ms(self.age_s)
        offset = self._offset_estimate
        seen = seq.lost + seq.unique
        return LinkSnapshot(
            tx_frames=self.tx_frames,
            tx_bytes=self.tx_bytes,
            tx_errors=self.tx_errors,
            rx_frames=self.rx_frames,
            rx_bytes=parser_count("bytes_in") if counters is not None else self.rx_frame_bytes,
            rx_lost=seq.lost,
            rx_duplicates=seq.duplicates,
            rx_reordered=seq.reordered,
            rx_loss_ratio=seq.lost / seen if seen else 0.0,
            crc_failures=parser_count("crc_failures"),
            signature_failures=parser_count("signature_failures"),
            unsigned_rejected=parser_count("unsigned_rejected"),
            bad_signatures=parser_count("bad_signatures"),
            replays_rejected=parser_count("replays_rejected"),
            garbage_bytes=parser_count("garbage_bytes"),
            unknown_messages=parser_count("unknown_messages"),
            unsupported_messages=parser_count("unsupported_messages"),
            dropped_frames=parser_count("dropped_frames"),
            rtt_samples=len(self.rtt_s),
            rtt_p50_ms=rtt_p50,
            rtt_p99_ms=rtt_p99,
            clock_offset_ms=offset * 1e3 if offset is not None else math.nan,
            age_samples=len(self.age_s),
            age_p50_ms=age_p50,
            age_p99_ms=age_p99,
        )


class TimeSyncTracker:
    """TIMESYNC both ways: builds requests, answers peers' requests, turns replies into samples.

    Clocks are read through `clock()` (seconds) and sent as integer nanoseconds. A reply is used only if
    its ts1 matches a request this tracker sent (TIMESYNC is broadcast: other nodes' replies are
    ignored and counted in `foreign_replies`). A responder whose clock reads exactly 0 answers tc1 = 1 ns,
    because tc1 = 0 marks a request.
    """

    def __init__(self, clock: Callable[[], float], stats: LinkStats | None = None, max_outstanding: int = 64):
        self.clock = clock
        self.stats = stats
        self.max_outstanding = max_outstanding
        self.foreign_replies = 0
        self.samples: deque[TimeSyncSample] = deque(maxlen=DEFAULT_SAMPLE_WINDOW)
        self._outstanding: dict[int, None] = {}

    def _now_ns(self) -> int:
        return int(round(self.clock() * 1e9))

    def request(self) -> TimeSync:
        origin = self._now_ns()
        self._outstanding[origin] = None
        while len(self._outstanding) > self.max_outstanding:  # forget the oldest unanswered
            del self._outstanding[next(iter(self._outstanding))]
        return TimeSync(remote_ns=0, origin_ns=origin)

    def answer(self, request: TimeSync) -> TimeSync:
        """The responder's reply: tc1 = our clock (ns), ts1 = the request's ts1."""
        return TimeSync(remote_ns=max(1, self._now_ns()), origin_ns=request.origin_ns)

    def on_reply(self, reply: TimeSync) -> TimeSyncSample | None:
        if reply.origin_ns not in self._outstanding:
            self.foreign_replies += 1
            return None
        del self._outstanding[reply.origin_ns]
        now = self._now_ns()
        sample = TimeSyncSample(
            rtt_s=(now - reply.origin_ns) / 1e9,
            offset_s=((reply.origin_ns + now) / 2 - reply.remote_ns) / 1e9,
        )
        self.samples.append(sample)
        if self.stats is not None:
            self.stats.record_timesync(sample)
        return sample

    def handle(self, msg: TimeSync) -> TimeSync | None:
        """A request -> the reply to send back; a reply -> recorded, None."""
        if msg.remote_ns == 0:
            return self.answer(msg)
        self.on_reply(msg)
        return None
