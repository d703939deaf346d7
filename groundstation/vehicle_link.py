"""The ground station's side of the link to one vehicle.

Takes in: a connection string and zenoh options (the ground network: mocap, truth), optionally a second
one for the radio link (uplink and downlink; default: the first, on the vehicle's keys), the vehicle id and
key prefix, actuator limits and signing, a clock for receive times, and an optional .tlog path.
Gives out: `send(message)` on the uplink; decoded downlink and mocap messages in an inbox (`pump()`:
everything that arrived; or, for the lockstep clock, `fetch()` samples and `deliver(counts)` exactly a
tick's worth of them); the same tick's (simulation-only) truth messages from `take_truth()`, decoded
only when asked, which the flight loop does after the tick's commands are sent (truth is for logs, so its
decoding stays off the lockstep's critical path); sample counts per key and link statistics.
Frames of the tlog are written by `flush_logs()` (the flight loop calls it once per tick, after sending).
Mocap comes from the ground network and truth from the simulator: neither passes the radio.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

from link.endpoint import Endpoint
from link.keys import GROUND_STATION_SYSTEM_ID, VehicleKeys
from link.mavlink.codec import ActuatorLimits, Codec, FrameParser
from link.mavlink.tlog import TlogWriter
from link.messages import Received
from link.transports import open_transport
from link.transports.table import transport_options


@dataclass
class Inbox:
    downlink: list[Received] = field(default_factory=list)
    mocap: list[Received] = field(default_factory=list)
    truth: list[Received] = field(default_factory=list)


class VehicleLink:
    def __init__(self, connection: str, keys: VehicleKeys, limits: ActuatorLimits, clock: Callable[[], float],
                 *, zenoh_options: dict | None = None, signing=None, tlog_path=None, with_truth: bool = True,
                 shared_clock: bool = False, radio_link: str | None = None, radio=None):
        """`shared_clock`: both ends stamp with the same clock (lockstep simulation time), so one-way frame
        ages are measured directly instead of through TIMESYNC's symmetric-path offset. `radio_link`: the
        radio's own connection string (udp, serial, ...: this vehicle's address), None: `connection`.
        `radio`: an opened endpoint of another protocol that speaks cfstack messages (link.crtp.cflib_link's
        CrazyflieRadio) instead of MAVLink on the radio link; the tlog then stays empty (it is MAVLink's)."""
        opts = zenoh_options or {}
        radio_connection = connection if radio_link is None else radio_link
        radio_opts = transport_options(radio_connection, opts)
        self.keys = keys
        self.clock = clock
        self.tlog = TlogWriter(tlog_path, buffered=True) if tlog_path and radio is None else None
        if radio is None:
            codec = Codec(system_id=GROUND_STATION_SYSTEM_ID, limits=limits, signing=signing)
            radio = Endpoint(open_transport(radio_connection, tx=keys.uplink, rx=keys.downlink, **radio_opts), codec,
                             FrameParser(codec, signing=signing), clock=clock, tlog=self.tlog,
                             shared_clock=shared_clock)
        self.radio = radio
        self.speaks_crtp = getattr(radio, "protocol", "mavlink") == "crtp"  # a lockstep tick's count: crtp_published
        ground = Codec(system_id=GROUND_STATION_SYSTEM_ID, limits=limits)
        self.mocap = Endpoint(open_transport(connection, rx=keys.mocap, **opts), ground,
                              FrameParser(ground), clock=clock)
        self.truth = None
        if with_truth:
            self.truth = Endpoint(open_transport(connection, rx=keys.truth, **opts), ground,
                                  FrameParser(ground), clock=clock)
        self.inbox = Inbox()
        self.last_sent_s: float | None = None
        self._streams = [self.radio, self.mocap, self.truth]  # raw_counts() order
        self._held: list[list[bytes]] = [[], [], []]  # samples taken from the transports, not yet delivered
        self._truth_due: int | None = None  # truth samples (taken in all) the last deliver() accounted for

    def send(self, message) -> None:
        self.radio.send(message, target_system=self.keys.vehicle_id)
        self.last_sent_s = self.clock()

    @property
    def uplink_sent(self) -> int:
        return self.radio.transport.stats.frames_sent

    def raw_counts(self) -> tuple[int, int, int]:
        """Samples taken so far from the downlink, mocap and truth keys (delivered or held)."""
        return tuple(self._taken(i) for i in range(3))

    def _taken(self, stream: int) -> int:
        endpoint = self._streams[stream]
        return 0 if endpoint is None else endpoint.transport.stats.chunks_received

    def fetch(self, timeout_s: float = 0.0, wait_on: int = 0) -> None:
        """Take whatever samples have arrived, undecoded, waiting at most timeout_s on one stream
        (wait_on: 0 downlink, 1 mocap, 2 truth - the order of raw_counts())."""
        for i, endpoint in enumerate(self._streams):
            if endpoint is not None:
                self._held[i].extend(endpoint.transport.receive(timeout_s if i == wait_on else 0.0))

    def deliver(self, counts: tuple[int, int, int] | None = None) -> None:
        """Decode held downlink and mocap samples into the inbox (stamped now on the clock): all of them,
        or per stream only up to `counts` samples taken in all (a lockstep tick's; later ones stay held).
        The truth samples it accounts for wait, undecoded, for take_truth()."""
        self._deliver(0, self.inbox.downlink, None if counts is None else counts[0])
        self._deliver(1, self.inbox.mocap, None if counts is None else counts[1])
        self._truth_due = None if counts is None else counts[2]

    def take_truth(self) -> list:
        """The truth messages of what the last deliver() accounted for, decoded now (same clock stamp:
        the caller asks within the same tick)."""
        self._deliver(2, self.inbox.truth, self._truth_due)
        truth, self.inbox.truth = self.inbox.truth, []
        return truth

    def _deliver(self, stream: int, box: list, count: int | None) -> None:
        """Decode stream's held samples into box: all, or up to `count` taken in all."""
        endpoint, held = self._streams[stream], self._held[stream]
        if endpoint is None or not held:
            return
        take = len(held) if count is None else max(0, count - (self._taken(stream) - len(held)))
        if take:
            box.extend(endpoint.deliver(held[:take]))
            del held[:take]

    def flush_logs(self) -> None:
        """Hand the tlog records written since the last flush to the operating system (one write)."""
        if self.tlog is not None:
            self.tlog.flush()

    def pump(self, timeout_s: float = 0.0, wait_on: int = 0) -> None:
        """Move whatever has arrived into the inbox, waiting at most timeout_s on one stream."""
        self.fetch(timeout_s, wait_on)
        self.deliver()

    def take(self) -> Inbox:
        """The downlink and mocap messages delivered so far (truth stays for take_truth)."""
        inbox = self.inbox
        self.inbox = Inbox(truth=inbox.truth)
        return inbox

    def close(self) -> None:
        for endpoint in (self.radio, self.mocap, self.truth):
            if endpoint is not None:
                endpoint.transport.close()
        if self.tlog is not None:
            self.tlog.close()
