"""Publishing: what a vehicle's steps produce, held until its tick and sent packed into few samples.

Takes in: frames stamped with the step count at which a non-lookahead emulator would publish them, on
four channels (downlink through the radio, mocap and truth on the ground network, CRTP packets through
the vehicle's CRTP radio), and the transports to send them on.
Gives out: the samples on each transport, and the count of samples per channel that each lockstep clock
tick announces (ClockTick). A tick's frames go out in one burst, packed per key into as few samples as
possible (pack_samples), then the tick record, which counts samples. CRTP packets have no length
field, so each is a sample of its own (as each is a datagram over UDP).
"""

from __future__ import annotations

from collections import deque

from link.clock import ClockTick
from link.transports import Transport

# Frames published together (one tick's, or one realtime step's) share a sample up to this size: far
# below a UDP datagram (65,507 B) and zenoh's default batch (65,535 B).
MAX_SAMPLE_BYTES = 8192

DOWNLINK, MOCAP, TRUTH, CRTP = 0, 1, 2, 3  # outbox channels, in ClockTick count order
CHANNELS = 4


class Outbox:
    """The frames one vehicle has produced and not yet published, as (step_no, channel, frame).

    `queue` is appended to directly by the vehicle's step (the hot path); `take_due(n)` hands out the
    frames stamped <= n, and `send()` publishes them packed per channel, counting samples in
    `published`."""

    def __init__(self):
        self.queue: deque[tuple[int, int, bytes]] = deque()
        self.published = [0] * CHANNELS  # samples published per channel (DOWNLINK, MOCAP, TRUTH, CRTP)
        self.senders: list[Transport | None] = [None] * CHANNELS  # per channel; None until opened (CRTP: off)

    def take_due(self, step_no: int) -> list[tuple[int, bytes]]:
        """(channel, frame) of every queued frame stamped at or before step_no, in order."""
        queue = self.queue
        due = []
        while queue and queue[0][0] <= step_no:
            _, channel, frame = queue.popleft()
            due.append((channel, frame))
        return due

    def send(self, frames: list[tuple[int, bytes]]) -> None:
        """Publish frames, the ones of each channel packed into as few samples as MAX_SAMPLE_BYTES
        allows (in order), counting the samples in `published` (what the clock ticks announce)."""
        batches: tuple[list[bytes], ...] = ([], [], [], [])
        for channel, frame in frames:
            batches[channel].append(frame)
        for channel, batch in enumerate(batches):
            if batch and self.senders[channel] is not None:
                for sample in (batch if channel == CRTP else pack_samples(batch)):
                    # counted only when the medium took it: a udpin radio link has no peer to send to until
                    # the ground station's first datagram, and a tick must not announce what never left
                    if self.senders[channel].send(sample):
                        self.published[channel] += 1

    def tick_message(self, tick: int, time_ns: int) -> ClockTick:
        return ClockTick(tick, time_ns, *self.published)


def pack_samples(frames: list[bytes]) -> list[bytes]:
    """Whole frames, in order, concatenated into samples of at most MAX_SAMPLE_BYTES (a longer frame
    alone). One zenoh put costs far more than its bytes (measured ~6-9 us each on this kind of machine),
    and the receiving parser takes any number of whole frames per datagram."""
    if len(frames) == 1:
        return frames
    samples, current, size = [], [], 0
    for frame in frames:
        if current and size + len(frame) > MAX_SAMPLE_BYTES:
            samples.append(b"".join(current))
            current, size = [], 0
        current.append(frame)
        size += len(frame)
    samples.append(b"".join(current))
    return samples
