"""A cflib link driver for CRTP over zenoh: `zenoh://PREFIX/VEHICLE[?connect=ENDPOINT]`.

Takes in: a cflib URI naming the key prefix and vehicle id (`zenoh://cfstack/1`: the emulator's vehicle 1
under the default prefix); the zenoh session it opens on (the ground station's --connect and zenoh
options through `use_session`, or the URI's `connect` query, e.g. `?connect=tcp/127.0.0.1:7447`); CRTP
packets from cflib (`send_packet`).
Gives out: CRTP packets to cflib (`receive_packet`), one per zenoh sample on the vehicle's crtp/downlink
key (link.keys), and its own counters (`stats`: packets sent and taken).

`register()` adds the driver to cflib's table (cflib.crtp.CLASSES), so any cflib script can open
`zenoh://...` after it, as it opens `radio://` or `udp://`; the emulator serves CRTP on these keys in
both clocks (simulator.fleet). needs_resending is False: the emulator's simulated radio resends what its
air loses, as a Crazyradio's link layer does, so cflib's own 0.2 s resend timers (wall clock) stay off.

Lockstep (`gate()`). cflib reads its link in a thread of its own (IncomingPacketHandler) and calls the
log and parameter callbacks from there. To compute a lockstep tick on exactly that tick's packets, the
ground station takes the packets from zenoh itself (`fetch`, counted: the tick records count CRTP
samples), lets cflib have a tick's worth (`release(n)`), and waits until cflib's thread has handled
every one of them (`wait_handled`): it has when it asks this driver for the next packet. Before the
gate (connecting: TOCs, parameters) packets go to cflib as they come.
"""

from __future__ import annotations

import threading
import time
from collections import deque
from urllib.parse import parse_qs, urlparse

from link.keys import MAX_VEHICLE_ID, VehicleKeys
from link.transports import open_transport
from link.transports.base import TransportStats
from link.transports.table import transport_options
from model.errors import UserError

SCHEME = "zenoh://"
NULL_PACKET = b"\xff"  # CRTP's null packet (header 0xff, no data): a Crazyflie answers it with one
PROBE_PERIOD_S = 0.1  # at connect: a null packet this often until the emulator answers
PROBE_TIMEOUT_S = 5.0  # then the connection attempt fails (the caller may try again): an emulator just started
# answers after ~0.5 s here (its imports and zenoh), a busy machine takes longer
PULL_SLICE_S = 0.05  # longest single wait on zenoh by cflib's thread (a gate waits at most this for it)

_session = {"connection": "zenoh", "options": {}}  # the session `zenoh://` URIs open on (use_session)


def use_session(connection: str, zenoh_options: dict) -> None:
    """The zenoh session (connection string and options) that `zenoh://` URIs without `connect` open on."""
    _session.update(connection=connection, options=dict(zenoh_options))


def register() -> None:
    """Make `zenoh://` URIs known to cflib (once)."""
    import cflib.crtp

    if ZenohDriver not in cflib.crtp.CLASSES:
        cflib.crtp.CLASSES.insert(0, ZenohDriver)


def parse_uri(uri: str) -> tuple[VehicleKeys, str, dict]:
    """(the vehicle's keys, connection string, zenoh options) of a `zenoh://PREFIX/VEHICLE[?connect=E]` URI;
    a one-line UserError for a malformed one."""
    parsed = urlparse(uri)
    parts = f"{parsed.netloc}{parsed.path}".strip("/").split("/")
    if len(parts) < 2 or not all(parts) or not parts[-1].isdigit() \
            or not 1 <= int(parts[-1]) <= MAX_VEHICLE_ID:
        raise UserError(f"crtp: '{uri}' is not zenoh://PREFIX/VEHICLE (e.g. zenoh://cfstack/1, vehicle 1.."
                        f"{MAX_VEHICLE_ID})")
    keys = VehicleKeys("/".join(parts[:-1]), int(parts[-1]))
    connect = parse_qs(parsed.query).get("connect")
    if connect:
        return keys, f"zenoh:{','.join(connect)}", {}
    return keys, _session["connection"], _session["options"]


def _driver_base():
    from cflib.crtp.crtpdriver import CRTPDriver

    return CRTPDriver


class ZenohDriver(_driver_base()):
    """cflib's driver interface (cflib.crtp.crtpdriver.CRTPDriver) over a zenoh transport."""

    def __init__(self):
        super().__init__()
        self.needs_resending = False
        self.uri = ""
        self.transport = None
        self.stats = TransportStats()
        self._lock = threading.Condition()
        self._arrived: deque[bytes] = deque()  # taken from zenoh, not yet given to cflib
        self._gated = False
        self._allowed = 0  # gated: how many packets cflib may have had in all
        self._given = 0  # packets given to cflib
        self._handled = 0  # packets cflib's thread has finished with
        self._pulling = False  # cflib's thread is waiting on zenoh (ungated)

    # --- cflib's interface ------------------------------------------------------------------------
    def connect(self, uri, radio_link_statistics_callback, link_error_callback):  # noqa: ARG002 - cflib's
        from cflib.crtp.exceptions import WrongUriType

        if not str(uri).startswith(SCHEME):
            raise WrongUriType("Not a zenoh URI")
        keys, connection, options = parse_uri(uri)
        self.uri = uri
        self.transport = open_transport(connection, tx=keys.crtp_uplink, rx=keys.crtp_downlink,
                                        **transport_options(connection, options))
        self._probe(keys)

    def _probe(self, keys: VehicleKeys) -> None:
        """Null packets until something answers (the emulator answers each with one): zenoh keeps no history,
        and until the sessions have met, cflib's first request would be lost, and cflib does not resend it.
        The answers stay queued for cflib (a null packet is nothing to it) and are counted as received; the
        probes are not counted as sent (some are lost, and the emulator's lockstep counts no null packet)."""
        deadline = time.monotonic() + PROBE_TIMEOUT_S
        while time.monotonic() < deadline:
            self.transport.send(NULL_PACKET)  # not counted: the lockstep acks count no null packet (simulator.fleet)
            if self._take(self.transport.receive(PROBE_PERIOD_S)):
                return
        self.close()
        raise ConnectionError(f"nothing answers on {keys.crtp_uplink} (is an emulator running there?)")

    def send_packet(self, pk) -> None:
        transport = self.transport
        if transport is None:
            return
        data = bytes((pk.header,)) + bytes(pk.data)
        with self._lock:
            if transport.send(data):
                self.stats.record_send(len(data), True)

    def receive_packet(self, wait=0):
        """The next packet for cflib, waiting at most `wait` s (< 0: until one comes); None if none."""
        from cflib.crtp.crtpstack import CRTPPacket

        deadline = None if wait < 0 else time.monotonic() + wait
        while True:
            with self._lock:
                self._handled = self._given  # cflib's thread asks again: it has finished with the last one
                self._lock.notify_all()
                if self._arrived and (not self._gated or self._given < self._allowed):
                    self._given += 1
                    data = self._arrived.popleft()
                    if data:  # an empty sample is counted and released like any, but is no packet
                        return CRTPPacket(data[0], data[1:])
                    continue
                remaining = None if deadline is None else deadline - time.monotonic()
                if remaining is not None and remaining <= 0:
                    return None
                if self._gated or self.transport is None:
                    self._lock.wait(PULL_SLICE_S if remaining is None else min(remaining, PULL_SLICE_S))
                    continue
                self._pulling = True
            try:
                self._take(self.transport.receive(PULL_SLICE_S if remaining is None else min(remaining, PULL_SLICE_S)))
            finally:
                with self._lock:
                    self._pulling = False
                    self._lock.notify_all()

    def get_status(self) -> str:
        return "zenoh"

    def get_name(self) -> str:
        return "zenoh"

    def scan_interface(self, address=None) -> list:  # noqa: ARG002 - cflib's
        return []  # a zenoh URI is named, not found (zenoh://PREFIX/VEHICLE)

    def close(self) -> None:
        transport, self.transport = self.transport, None
        if transport is not None:
            transport.close()
        with self._lock:
            self._lock.notify_all()

    # --- lockstep ---------------------------------------------------------------------------------
    def gate(self, timeout_s: float) -> None:
        """From now on cflib gets only what `release` allows: everything taken so far is released, and
        this returns once cflib's thread has finished with it and no longer waits on zenoh."""
        with self._lock:
            self._gated = True
            if not self._lock.wait_for(lambda: not self._pulling, timeout_s):
                raise UserError(f"crtp: cflib's thread did not leave {self.uri} in {timeout_s:g} s")
            self._allowed = self._given + len(self._arrived)
            self._lock.notify_all()
        self.wait_handled(timeout_s)

    def fetch(self, timeout_s: float = 0.0) -> list[bytes]:
        """Gated: the packets that arrived from zenoh (waiting at most timeout_s for the first), held
        for `release`; returned too, so the caller can count them."""
        transport = self.transport
        return [] if transport is None else self._take(transport.receive(timeout_s))

    def release(self, count: int) -> None:
        """Let cflib have `count` more of the packets taken."""
        with self._lock:
            self._allowed += count
            self._lock.notify_all()

    def wait_handled(self, timeout_s: float) -> None:
        """Until cflib's thread has finished with every packet released (a one-line UserError after timeout_s)."""
        with self._lock:
            done = self._lock.wait_for(
                lambda: self._handled >= min(self._allowed, self._given + len(self._arrived)), timeout_s)
        if not done:
            raise UserError(f"crtp: cflib did not take its packets from {self.uri} within {timeout_s:g} s")

    def _take(self, samples: list[bytes]) -> list[bytes]:
        if samples:
            with self._lock:
                for sample in samples:
                    self.stats.chunks_received += 1
                    self.stats.bytes_received += len(sample)
                    self._arrived.append(bytes(sample))
                self._lock.notify_all()
        return samples
