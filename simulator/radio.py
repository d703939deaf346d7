"""The simulated radio: one impaired, one-way channel carrying opaque frames in simulation time.

Takes in: a `RadioProfile` (model.radio: model/params/radio/*.toml, or any TOML file), a seeded
numpy.random.Generator, for model "crazyradio" the `EsbAir` the channel shares with the opposite direction
(its own when none is given), and frames (bytes, e.g. MAVLink 2 frames of 12..280 bytes) offered with
`push(frame, t_s)` at non-decreasing simulation times t_s (s).
Gives out: `pop_due(t_s)`: the frames whose delivery time is <= t_s, in delivery order (ties keep
offer order), each possibly bit-corrupted or duplicated; `next_delivery_s()` and `min_latency_s`
for the emulator's lookahead; `stats`, a per-frame `ledger`, and `radio_status()` (RADIO_STATUS fields).

Every random decision is drawn inside `push`, in offer order, from the generator given: the same
seed and the same pushes give byte-identical deliveries, whatever the pattern of `pop_due` calls.

What happens to frame i offered at t_i (s), in this order:
 1. Queue. The channel carries one frame at a time, first come first served. Frame i starts when
    the channel is free, s_i = max(t_i, e_{i-1}), and occupies it for a service time
        S_i = 8 L_i / B  (+ its ESB air time, model "esb-duplex"),
    L_i in bytes, B = `queue.bandwidth_bps` (no serialisation term when B = 0), e_i = s_i + S_i.
    Model "crazyradio" instead: the frame's packets take the next transactions of the shared `EsbAir`
    (one packet per transaction and direction, see EsbAir), s_i is its first transaction's start and e_i
    the arrival of its last packet: at the vehicle when its uplink packet is on the air, at the host when
    the downlink packet's transaction ends. A packet whose transaction fails takes the next one; after
    `host_retries` failed transactions in a row the frame is lost (cause "retries").
    A frame that would have to wait while `queue.capacity_frames` frames already wait is dropped
    (cause "queue") and takes no channel time.
 2. Loss on the air (the frame still used the channel):
    - model "esb-duplex": the frame travels in n = ceil(L / d) nRF24 packets (d data bytes each),
      every attempt of a packet fails (packet or ACK lost) with probability p, and a packet is sent
      at most ARC + 1 times; the frame is lost (cause "retries") when any packet fails them all:
          P(lost) = 1 - (1 - p^(ARC+1))^n.
      One attempt lasts T_set + T_oa(packet) + T_set + T_oa(ACK) when it succeeds and
      T_set + T_oa(packet) + ARD when it fails, with the nRF24L01+ time on air
          T_oa = (8 (preamble + address + payload + CRC) + packet-control bits) / air rate.
    - bursty loss (cause "burst"): a Gilbert-Elliott chain stepped once per frame on the air; a frame
      is lost with probability loss_good or loss_bad by the state it meets, then the state moves
      (good -> bad with p_good_to_bad, bad -> good with p_bad_to_good). The first state is drawn
      from the stationary law, pi_bad = p_gb / (p_gb + p_bg), so the mean loss is
      pi_bad loss_bad + (1 - pi_bad) loss_good from the first frame; bad sojourns last 1 / p_bg
      frames on average.
    - i.i.d. loss (cause "iid") with `loss.probability`.
 3. Delay. Delivery at d_i = e_i + base + J_i (+ `reorder_delay_s` with `reorder_probability`),
    J_i the jitter: uniform on [-j, j] or normal(0, j) cut at +-clip j, and in both cases conditioned
    on base + J_i >= 0 (no frame arrives before it was sent). With `preserve_order`, d_i is raised
    to the previous delivery time so frames never overtake each other.
 4. Duplication: with `duplication.probability` a second copy is delivered right after the first.
 5. Corruption, per delivered copy: with `corruption.frame_probability` exactly `bits_per_frame`
    distinct bits flip, plus Binomial(8 L, `bit_error_rate`) more; the receiver's CRC must reject it.
Uniform draws come from the generator in blocks (one numpy call per 4096); without keep_ledger no
per-frame record (FrameFate) is built, and the draws and deliveries are the same either way.
"""

from __future__ import annotations

import heapq
import itertools
import math
from array import array
from collections import Counter, deque
from dataclasses import dataclass, field
from enum import StrEnum

import numpy as np

from model.radio import CrazyradioLink, RadioProfile

UINT8_UNKNOWN = 255  # MAVLink RADIO_STATUS: UINT8_MAX means "invalid/unknown"
RSSI_MAX = 254  # MAVLink RADIO_STATUS rssi range is 0..254
UINT16_WRAP = 1 << 16  # rx_errors and fixed are uint16 counters that wrap
TIME_EPS_S = 1e-9  # simulation times closer than this are the same instant
_UNIFORM_BLOCK = 4096  # uniforms drawn per call to the generator (speed only; the stream is the same)
# Air outcomes kept beyond a status window: those of frames offered after a status's cutoff (see radio_status:
# a few milliseconds of frames, far fewer than this), so the window before the cutoff is always whole.
AIR_OUTCOMES_SLACK = 4096


class DropCause(StrEnum):
    IID = "iid"
    BURST = "burst"
    QUEUE = "queue"
    RETRIES = "retries"


@dataclass(frozen=True, slots=True)
class FrameFate:
    """What the channel decided for one offered frame (decided in full at push time)."""

    offered_s: float
    size_bytes: int
    drop_cause: DropCause | None = None
    delivery_s: tuple[float, ...] = ()  # one entry per delivered copy (two when duplicated)
    flipped_bits: tuple[int, ...] = ()  # bits flipped in each copy (0 = intact)
    retransmissions: int = 0  # Crazyradio packet retransmissions spent on this frame

    @property
    def delivered(self) -> bool:
        return bool(self.delivery_s)

    @property
    def duplicated(self) -> bool:
        return len(self.delivery_s) > 1

    @property
    def corrupted(self) -> bool:
        return any(self.flipped_bits)


@dataclass
class RadioStats:
    """Counters of one channel. Decisions (offered, dropped, duplicated) count at push; what the far
    end saw (delivered, corrupted, reordered, bytes_delivered, latency) counts at pop."""

    offered: int = 0
    delivered: int = 0  # delivered copies, duplicates included
    dropped: Counter = field(default_factory=Counter)  # DropCause -> frames
    duplicated: int = 0
    corrupted: int = 0  # delivered copies with at least one flipped bit
    reordered: int = 0  # delivered copies that arrive after a frame offered later
    repaired: int = 0  # delivered copies whose frame needed Crazyradio retransmissions
    bytes_offered: int = 0
    bytes_delivered: int = 0
    latency_s: array = field(default_factory=lambda: array("d"))  # delay of each delivered copy, s

    @property
    def dropped_total(self) -> int:
        return sum(self.dropped.values())

    def latency_percentile_s(self, q: float) -> float:
        return float(np.percentile(self.latency_s, q)) if self.latency_s else math.nan

    @property
    def latency_p50_s(self) -> float:
        return self.latency_percentile_s(50.0)

    @property
    def latency_p99_s(self) -> float:
        return self.latency_percentile_s(99.0)

    @property
    def latency_mean_s(self) -> float:
        return float(np.mean(self.latency_s)) if self.latency_s else math.nan


def _uniform_stream(rng: np.random.Generator):
    """U(0,1) draws from the generator, fetched _UNIFORM_BLOCK at a time (one numpy call per block, not
    per draw): an iterator whose next() is a C call. Blocks are drawn lazily, so the stream, and where it
    interleaves with the generator's other calls, is a pure function of the seed and the pushes."""
    return itertools.chain.from_iterable(iter(lambda: rng.random(_UNIFORM_BLOCK).tolist(), None))



UPLINK, DOWNLINK = "uplink", "downlink"
_TRIM_SLOTS = 4096  # transactions kept before the air drops those every direction has passed (memory only)


class EsbAir:
    """One Crazyradio's transactions, shared by the two directions of one vehicle's radio (model "crazyradio").

    Transaction k starts at s_k and lasts max(USB interval, its air): F_k failed attempts of T_fail each and,
    when an attempt succeeds (F_k <= ARC), one successful attempt T_ok; F_k = ARC + 1 means every attempt
    failed and the transaction carried nothing. P(F_k >= j) = p^j (capped at ARC + 1), drawn by inversion in
    transaction order from the air's own generator; s_0 is uniform on [0, USB interval) (the USB frame phase).
    So the transactions are the same whatever the traffic and whichever direction asks first (in lockstep the
    downlink runs ahead of the uplink). Attempts are timed with full packets both ways (T_ok = Tstby2a +
    T_oa(31 bytes) + Tstby2a + T_oa(ACK payload)): an upper bound, which binds only when retries stretch a
    transaction past the USB interval. Each direction carries at most one packet per successful transaction,
    its packets in order (`plan`): an uplink packet arrives when it is on the air, s_k + F_k T_fail +
    Tstby2a + T_oa(packet); a downlink packet (the ACK payload) reaches the host when its transaction ends.
    """

    def __init__(self, link: CrazyradioLink, rng: np.random.Generator):
        self.link = link
        self._uniform = _uniform_stream(rng).__next__
        self._usb_s = link.usb_interval_s
        full = link.data_bytes_per_packet
        self._ok_s = link.attempt_ok_s(full)
        self._failed_s = link.attempt_failed_s(full)
        self._attempts = link.auto_retransmit_count + 1
        self._host_retries = link.host_retries
        p = link.packet_loss_probability
        self._p, self._keep = p, 1.0 - p
        self._log_p = math.log(p) if 0.0 < p < 1.0 else None
        self._on_air_s = [link.settling_s + link.time_on_air_s(link.header_bytes_per_packet + b)
                          for b in range(full + 1)]
        self._starts: deque[float] = deque()
        self._failures: deque[int] = deque()
        self._first = 0  # index of _starts[0]
        self._next_start_s = self._uniform() * self._usb_s
        self._cursors: dict[str, int] = {}  # per direction: its next transaction
        self.transactions_failed = 0

    def _append(self) -> None:
        p = self._p
        if p == 0.0:
            failures = 0
        elif p == 1.0:
            failures = self._attempts
        else:
            u = self._uniform()
            failures = 0 if u < self._keep else min(self._attempts, max(1, int(math.log(1.0 - u) / self._log_p)))
        start = self._next_start_s
        self._starts.append(start)
        self._failures.append(failures)
        if failures == self._attempts:
            self.transactions_failed += 1
        air_s = failures * self._failed_s + (self._ok_s if failures < self._attempts else 0.0)
        self._next_start_s = start + (air_s if air_s > self._usb_s else self._usb_s)

    def _trim(self) -> None:
        """Drop transactions every direction has passed; a direction that has not used the air yet (absent from
        _cursors) keeps them all, so nothing a later push may need is ever gone."""
        keep_from = min(min(self._cursors.values()), self._first + len(self._starts) - _TRIM_SLOTS)
        while self._first < keep_from:
            self._starts.popleft()
            self._failures.popleft()
            self._first += 1

    def _slot(self, k: int) -> tuple[float, int]:
        i = k - self._first
        while i >= len(self._starts):
            self._append()
        return self._starts[i], self._failures[i]

    def plan(self, direction: str, size_bytes: int, ready_s: float) -> tuple[float, float, int, bool, int]:
        """Where a frame of size_bytes, ready at ready_s (s), goes: (start of its first transaction s, arrival of
        its last packet s, ESB retransmissions, lost after host_retries failed transactions, the direction's next
        transaction). Pure but for drawing transactions: `commit` takes the cursor once the frame is admitted."""
        d = self.link.data_bytes_per_packet
        full, last = divmod(size_bytes, d)
        if last == 0 and full > 0:
            full, last = full - 1, d
        k = max(self._cursors.get(direction, 0), self._first)
        start, failures = self._slot(k)
        while start < ready_s - TIME_EPS_S:
            k += 1
            start, failures = self._slot(k)
        first_start, arrival_s, retransmissions = start, start, 0
        attempts, usb_s = self._attempts, self._usb_s
        for packet in range(full + 1):
            failed_in_a_row = 0
            while True:
                start, failures = self._slot(k)
                k += 1
                if failures < attempts:
                    break
                retransmissions += attempts
                failed_in_a_row += 1
                if failed_in_a_row >= self._host_retries:
                    return first_start, start, retransmissions, True, k
            retransmissions += failures
            if direction == UPLINK:
                arrival_s = start + failures * self._failed_s + self._on_air_s[last if packet == full else d]
            else:
                air_s = failures * self._failed_s + self._ok_s
                arrival_s = start + (air_s if air_s > usb_s else usb_s)
        return first_start, arrival_s, retransmissions, False, k

    def commit(self, direction: str, next_transaction: int) -> None:
        self._cursors[direction] = next_transaction
        if len(self._starts) > 2 * _TRIM_SLOTS and len(self._cursors) == 2:
            self._trim()


class RadioChannel:
    """One direction of one vehicle's radio. See the module docstring for the model."""

    def __init__(self, profile: RadioProfile, rng: np.random.Generator, name: str = "",
                 keep_ledger: bool = True, air: EsbAir | None = None, direction: str = UPLINK):
        if direction not in (UPLINK, DOWNLINK):
            raise ValueError(f"radio {name!r}: direction must be {UPLINK!r} or {DOWNLINK!r}, not {direction!r}")
        self.profile = profile
        self.name = name
        self.rng = rng
        self.direction = direction
        if profile.model == "crazyradio" and air is None:
            air = EsbAir(profile.crazyradio, rng)
        self.air = air if profile.model == "crazyradio" else None
        self.stats = RadioStats()
        self.ledger: list[FrameFate] = []
        self.keep_ledger = keep_ledger
        self._uniform = _uniform_stream(rng).__next__
        # (delivery s, copy seq, offer index, bytes, corrupted, offered s, repaired); seq is unique,
        # so tuples never compare beyond it.
        self._heap: list[tuple[float, int, int, bytes, bool, float, bool]] = []
        self._copy_seq = 0  # tie-breaker: copies scheduled earlier leave first
        self._last_push_s = -math.inf
        self._lost = False  # the last push's frame was dropped
        self._channel_free_s = -math.inf
        self._waiting_starts: deque[float] = deque()  # start times of admitted frames (some may have started)
        self._last_delivery_s = -math.inf
        self._latest_index_delivered = -1
        # (offered s, not lost) of the frames put on the air, newest last
        self._air_outcomes: deque[tuple[float, bool]] = deque(
            maxlen=profile.status_window_frames + AIR_OUTCOMES_SLACK)
        self._status_window = profile.status_window_frames
        self._read_profile(profile)
        burst = profile.burst
        self._burst_bad = burst.enabled and self._uniform() < burst.stationary_bad

    def _read_profile(self, profile: RadioProfile) -> None:
        """The profile's numbers as attributes, read once (push reads them for every frame)."""
        self._lo_jitter, self._hi_jitter = profile.jitter_bounds_s
        self._min_latency_s = profile.min_latency_s
        self._base_s = profile.base_latency_s
        self._jitter_law = profile.jitter if profile.jitter_s > 0.0 else None
        if self._jitter_law == "normal":
            from scipy.special import ndtr, ndtri  # here: the other laws need no scipy (emulator start-up)

            self._ndtri = ndtri
            self._cdf_lo = float(ndtr(self._lo_jitter / profile.jitter_s))
            self._cdf_hi = float(ndtr(self._hi_jitter / profile.jitter_s))
        self._s_per_byte = 8.0 / profile.bandwidth_bps if profile.bandwidth_bps > 0.0 else 0.0
        self._capacity = profile.queue_capacity_frames
        self._burst = profile.burst if profile.burst.enabled else None
        self._iid_p = profile.loss_probability
        self._reorder_p, self._reorder_s = profile.reorder_probability, profile.reorder_delay_s
        self._preserve_order = profile.preserve_order
        self._duplicate_p = profile.duplicate_probability
        self._corrupts = profile.corrupt_frame_probability > 0.0 or profile.bit_error_rate > 0.0
        cr = profile.crazyradio
        self._packet_bytes: int | None = None  # data bytes per ESB packet; None: model "simple" or "crazyradio"
        if cr is not None and profile.model == "esb-duplex":
            sizes = range(cr.data_bytes_per_packet + 1)
            self._ok_s = [cr.attempt_ok_s(d) for d in sizes]
            self._failed_s = [cr.attempt_failed_s(d) for d in sizes]
            self._packet_bytes = cr.data_bytes_per_packet
            self._attempts = cr.auto_retransmit_count + 1
            p = cr.packet_loss_probability
            self._packet_loss_p = p
            self._log_p = math.log(p) if 0.0 < p < 1.0 else None

    # --- public API ------------------------------------------------------------------------------
    @property
    def min_latency_s(self) -> float:
        """The smallest possible delay of any frame on this channel (s): a true lower bound."""
        return self._min_latency_s

    @property
    def pending(self) -> int:
        return len(self._heap)

    def next_delivery_s(self) -> float | None:
        return self._heap[0][0] if self._heap else None

    def push(self, frame: bytes, t_s: float) -> bool:
        """Offer a frame at simulation time t_s (s); its whole fate is drawn now. False: it is lost (the queue
        or the air dropped it), which a link layer that retries (CRTP on a Crazyradio) acts on."""
        if t_s < self._last_push_s:
            raise ValueError(f"radio {self.name!r}: frame pushed at t={t_s} s, before the previous "
                             f"push at t={self._last_push_s} s (pushes must not go back in time)")
        self._last_push_s = t_s
        if frame.__class__ is not bytes:
            frame = bytes(frame)
        stats = self.stats
        index = stats.offered
        stats.offered = index + 1
        stats.bytes_offered += len(frame)
        self._lost = False
        fate = self._decide(frame, index, t_s)
        if self.keep_ledger:
            self.ledger.append(fate)
        return not self._lost

    def pop_due(self, t_s: float, discard_corrupted: bool = False) -> list[bytes]:
        """Every frame delivered at or before t_s, in delivery order (ties: offer order); with
        discard_corrupted, a corrupted copy is counted (stats.corrupted) and not handed over, as a radio whose
        packets carry their own CRC (the nRF24's, under CRTP) discards it.

        Times within TIME_EPS_S count as equal: offer time + latency carries float rounding (0.1 + 0.02 >
        0.12), and a frame due exactly at a step must not slip to the next one."""
        heap = self._heap
        due = t_s + TIME_EPS_S
        if not heap or heap[0][0] > due:
            return []
        out = []
        stats = self.stats
        latencies = stats.latency_s
        while heap and heap[0][0] <= due:
            delivery_s, _, index, data, corrupted, offered_s, repaired = heapq.heappop(heap)
            stats.delivered += 1
            stats.bytes_delivered += len(data)
            latencies.append(delivery_s - offered_s)
            if corrupted:
                stats.corrupted += 1
                if discard_corrupted:
                    continue
            if repaired:
                stats.repaired += 1
            if index < self._latest_index_delivered:
                stats.reordered += 1
            else:
                self._latest_index_delivered = index
            out.append(data)
        return out

    def radio_status(self, t_s: float | None = None, reverse: RadioChannel | None = None,
                     reverse_offered_by_s: float = math.inf) -> dict[str, int]:
        """RADIO_STATUS fields (link.messages.RadioStatus keyword arguments) for the radio that
        transmits on this channel ("local"); `reverse` is the channel it receives on.

        - remote_rssi: the far end's reception = round(254 * r), r the share of the last
          `status.window_frames` frames put on the air here that were not lost (queue drops excluded);
          255 (unknown) before any frame.
        - rssi, rx_errors, fixed: the local reception, taken from `reverse`: rssi as above, over the frames
          `reverse` was offered at or before reverse_offered_by_s (a lockstep emulator running ahead may not
          have offered later ones yet: the cutoff keeps the figure independent of when they came),
          rx_errors = corrupted copies delivered, fixed = delivered copies that needed Crazyradio
          retransmissions (uint16 counters that wrap). Without `reverse` they come from this channel
          (path loss is reciprocal, so the link is taken as symmetric).
        - tx_buffer_pct: MAVLink txbuf, the FREE share of this channel's queue at t_s (default: the
          last push time): 100 * (1 - waiting / capacity); 100 with an empty or zero-capacity queue.
        - noise, remote_noise: 255 (unknown): no noise floor is modelled.
        """
        t = self._last_push_s if t_s is None else t_s
        local = reverse if reverse is not None else self
        return {
            "rssi": local._rssi(reverse_offered_by_s if reverse is not None else math.inf),
            "remote_rssi": self._rssi(),
            "tx_buffer_pct": self._tx_buffer_free_pct(t),
            "noise": UINT8_UNKNOWN,
            "remote_noise": UINT8_UNKNOWN,
            "rx_errors": local.stats.corrupted % UINT16_WRAP,
            "fixed": local.stats.repaired % UINT16_WRAP,
        }

    # --- the model -------------------------------------------------------------------------------
    def _decide(self, frame: bytes, index: int, t_s: float) -> FrameFate | None:
        """Draw the frame's fate (steps 1-5 of the module docstring) and schedule its copies; the
        FrameFate only when the ledger is kept."""
        size = len(frame)
        air = self.air
        if air is not None:
            start_s, end_s, retransmissions, lost, next_transaction = air.plan(
                self.direction, size, t_s + size * self._s_per_byte)
            cause = DropCause.RETRIES if lost else None
        else:
            free_s = self._channel_free_s
            start_s = t_s if t_s >= free_s else free_s
        if start_s > t_s and not self._admit(t_s, start_s):
            self.stats.dropped[DropCause.QUEUE] += 1
            self._lost = True
            return FrameFate(t_s, size, DropCause.QUEUE) if self.keep_ledger else None
        if air is not None:
            air.commit(self.direction, next_transaction)
        else:
            if self._packet_bytes is None:
                air_s, retransmissions, cause = 0.0, 0, None
            else:
                air_s, retransmissions, cause = self._crazyradio_air(size)
            end_s = self._channel_free_s = start_s + size * self._s_per_byte + air_s
        uniform = self._uniform
        burst = self._burst
        if burst is not None:  # the chain steps for every frame on the air, whatever else happens
            bad = self._burst_bad
            if uniform() < (burst.loss_bad if bad else burst.loss_good) and cause is None:
                cause = DropCause.BURST
            if uniform() < (burst.p_bad_to_good if bad else burst.p_good_to_bad):
                self._burst_bad = not bad
        p = self._iid_p
        if p > 0.0 and uniform() < p and cause is None:
            cause = DropCause.IID
        self._air_outcomes.append((t_s, cause is None))
        if cause is not None:
            self.stats.dropped[cause] += 1
            self._lost = True
            return FrameFate(t_s, size, cause, retransmissions=retransmissions) if self.keep_ledger else None
        delivery_s = self._delivery_time(t_s, end_s)
        copies = 1
        if self._duplicate_p > 0.0 and uniform() < self._duplicate_p:
            copies = 2
            self.stats.duplicated += 1
        repaired = retransmissions > 0
        if copies == 1 and not self._corrupts and not self.keep_ledger:  # the common case, short
            seq = self._copy_seq
            self._copy_seq = seq + 1
            heapq.heappush(self._heap, (delivery_s, seq, index, frame, False, t_s, repaired))
            return None
        flips = []
        for _ in range(copies):
            data, flipped = self._corrupt(frame) if self._corrupts else (frame, 0)
            flips.append(flipped)
            seq = self._copy_seq
            self._copy_seq = seq + 1
            heapq.heappush(self._heap, (delivery_s, seq, index, data, flipped > 0, t_s, repaired))
        if not self.keep_ledger:
            return None
        return FrameFate(t_s, size, None, (delivery_s,) * copies, tuple(flips), retransmissions)

    def _admit(self, t_s: float, start_s: float) -> bool:
        """FIFO with `capacity_frames` places for frames waiting for the channel (start_s > t_s: this
        frame would wait). Starts at or before t_s are frames already on the air: no longer waiting."""
        waiting = self._waiting_starts
        while waiting and waiting[0] <= t_s:
            waiting.popleft()
        if len(waiting) >= self._capacity:
            return False
        waiting.append(start_s)
        return True

    def _crazyradio_air(self, size: int) -> tuple[float, int, DropCause | None]:
        """(air time s, retransmissions, RETRIES if lost) of the frame's packets sent one after the
        other: full packets of d data bytes, then the rest (one packet at least). Failed attempts per
        packet are geometric, P(K >= k) = p^k, drawn by inversion K = floor(ln(1 - U) / ln p); K = 0
        exactly when U < 1 - p, which needs no logarithm."""
        d = self._packet_bytes
        full, last = divmod(size, d)
        if last == 0 and full > 0:
            full, last = full - 1, d
        ok_s = self._ok_s
        p = self._packet_loss_p
        if p == 0.0:
            return full * ok_s[d] + ok_s[last], 0, None
        attempts = self._attempts
        if p == 1.0:  # every attempt of the first packet fails
            return attempts * self._failed_s[d if full else last], attempts - 1, DropCause.RETRIES
        keep = 1.0 - p
        uniform = self._uniform
        air_s, retransmissions = 0.0, 0
        data = d
        for k in range(full + 1):
            if k == full:
                data = last
            u = uniform()
            if u < keep:
                air_s += ok_s[data]
                continue
            failures = int(math.log(1.0 - u) / self._log_p)
            if failures >= attempts:
                return air_s + attempts * self._failed_s[data], retransmissions + attempts - 1, DropCause.RETRIES
            air_s += failures * self._failed_s[data] + ok_s[data]
            retransmissions += failures
        return air_s, retransmissions, None

    def _delivery_time(self, t_s: float, end_s: float) -> float:
        delay = self._base_s
        law = self._jitter_law
        if law is not None:
            u = self._uniform()
            if law == "uniform":
                delay += self._lo_jitter + u * (self._hi_jitter - self._lo_jitter)
            else:  # truncated normal by inversion: exact, one draw, no rejection loop
                q = self._cdf_lo + u * (self._cdf_hi - self._cdf_lo)
                jitter_s = self.profile.jitter_s
                delay += min(max(float(self._ndtri(q)) * jitter_s, self._lo_jitter), self._hi_jitter)
        if self._reorder_p > 0.0 and self._uniform() < self._reorder_p:
            delay += self._reorder_s
        # max(): floating-point rounding must never beat the advertised lower bound.
        delivery_s = end_s + delay
        floor_s = t_s + self._min_latency_s
        if delivery_s < floor_s:
            delivery_s = floor_s
        last_s = self._last_delivery_s
        if delivery_s > last_s:
            self._last_delivery_s = delivery_s
        elif self._preserve_order:
            delivery_s = last_s
        return delivery_s

    def _corrupt(self, frame: bytes) -> tuple[bytes, int]:
        """(copy, number of distinct bits flipped)."""
        profile = self.profile
        flips = 0
        if profile.corrupt_frame_probability > 0.0 and self._uniform() < profile.corrupt_frame_probability:
            flips = profile.corrupt_bits_per_frame
        if profile.bit_error_rate > 0.0:
            flips += int(self.rng.binomial(8 * len(frame), profile.bit_error_rate))
        flips = min(flips, 8 * len(frame))
        if flips == 0:
            return frame, 0
        data = bytearray(frame)
        for bit in self.rng.choice(8 * len(frame), size=flips, replace=False).tolist():
            data[bit >> 3] ^= 1 << (bit & 7)
        return bytes(data), flips

    def _rssi(self, offered_by_s: float = math.inf) -> int:
        """round(254 r), r the share not lost of the last status-window frames offered at or before
        offered_by_s; 255 (unknown) before any."""
        delivered = counted = 0
        for offered_s, ok in reversed(self._air_outcomes):
            if offered_s > offered_by_s:
                continue
            delivered += ok
            counted += 1
            if counted == self._status_window:
                break
        return UINT8_UNKNOWN if counted == 0 else round(RSSI_MAX * delivered / counted)

    def _tx_buffer_free_pct(self, t_s: float) -> int:
        capacity = self.profile.queue_capacity_frames
        if capacity == 0:
            return 100
        waiting = sum(1 for start in self._waiting_starts if start > t_s)
        return round(100.0 * (1.0 - waiting / capacity))
