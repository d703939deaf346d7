"""Radio profiles: what a simulated radio link does to frames, as both sides may read it.

Takes in: a radio profile TOML file (built-in names ideal, crazyradio, esb-duplex, lab, harsh in
model/params/radio/, or any file of the same form).
Gives out: `RadioProfile` (latency and jitter, i.i.d. and bursty loss, duplication, corruption, queue,
the Crazyradio's ESB timing and retries), checked field by field; a wrong or missing field is a
ConfigError naming the file and the field; the default profile of each protocol's radio.

Models: "simple" (latency, loss, queue); "esb-duplex" (each direction on an Enhanced ShockBurst air of its
own: frames cut into nRF24 packets, each retried); "crazyradio" (one dongle: a half-duplex ESB link whose
transactions, one per USB interval, carry at most one packet each way; simulator.radio.EsbAir).
MAVLink flies on esb-duplex by default because its traffic does not fit one Crazyradio
(benchmarks/radio_budget.py); CRTP, the Crazyflie's own protocol, on crazyradio. The channel that applies a
profile in simulation time is
simulator.radio.RadioChannel; a ground station or a sweep reads the profile only to describe or vary it.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from model.config import Params, resolve

MODELS = ("simple", "esb-duplex", "crazyradio")
ESB_MODELS = ("esb-duplex", "crazyradio")  # the models with a [crazyradio] table
DEFAULT_MAVLINK_RADIO = "esb-duplex"
DEFAULT_CRTP_RADIO = "crazyradio"
JITTER_LAWS = ("uniform", "normal")


@dataclass(frozen=True)
class GilbertElliott:
    """Two-state Markov loss, stepped once per frame on the air."""

    p_good_to_bad: float
    p_bad_to_good: float
    loss_good: float
    loss_bad: float

    @property
    def enabled(self) -> bool:
        return self.loss_good > 0.0 or self.loss_bad > 0.0

    @property
    def stationary_bad(self) -> float:
        """pi_bad = p_gb / (p_gb + p_bg); a chain that never moves stays in its first (good) state."""
        total = self.p_good_to_bad + self.p_bad_to_good
        return self.p_good_to_bad / total if total > 0.0 else 0.0

    @property
    def mean_loss(self) -> float:
        pi_bad = self.stationary_bad
        return pi_bad * self.loss_bad + (1.0 - pi_bad) * self.loss_good


@dataclass(frozen=True)
class CrazyradioLink:
    """Crazyradio PA / nRF24 Enhanced ShockBurst timing and retries (see crazyradio.toml for sources)."""

    air_rate_bps: float
    data_bytes_per_packet: int  # frame bytes carried per radio packet (CRTP data)
    header_bytes_per_packet: int  # protocol header in each radio payload (CRTP header)
    preamble_bytes: int
    address_bytes: int
    packet_control_bits: int
    crc_bytes: int
    ack_payload_bytes: int
    settling_s: float  # PLL settling before every transmission and every ACK (nRF24 Tstby2a)
    auto_retransmit_delay_s: float  # ARD: end of a failed transmission to the next attempt
    auto_retransmit_count: int  # ARC: retransmissions after the first attempt
    packet_loss_probability: float  # per attempt: the packet or its ACK is lost
    usb_interval_s: float = 0.0  # model crazyradio: one transaction per USB interval (0: the air alone paces)
    host_retries: int = 0  # model crazyradio: transactions the host runs for one packet before giving it up

    def time_on_air_s(self, payload_bytes: int) -> float:
        """nRF24L01+ T_oa = (8 (preamble + address + payload + CRC) + packet-control bits) / rate."""
        overhead = self.preamble_bytes + self.address_bytes + self.crc_bytes
        return (8 * (overhead + payload_bytes) + self.packet_control_bits) / self.air_rate_bps

    def attempt_ok_s(self, data_bytes: int) -> float:
        """A successful attempt: settle, send, turn around (settle), receive the ACK."""
        packet = self.time_on_air_s(self.header_bytes_per_packet + data_bytes)
        return 2.0 * self.settling_s + packet + self.time_on_air_s(self.ack_payload_bytes)

    def attempt_failed_s(self, data_bytes: int) -> float:
        """A failed attempt: settle, send, wait ARD for an ACK that never comes."""
        packet = self.time_on_air_s(self.header_bytes_per_packet + data_bytes)
        return self.settling_s + packet + self.auto_retransmit_delay_s


@dataclass(frozen=True)
class RadioProfile:
    name: str
    source: str
    model: str  # "simple" or "crazyradio"
    base_latency_s: float
    jitter: str  # "uniform" (half-width jitter_s) or "normal" (standard deviation jitter_s)
    jitter_s: float
    normal_clip_sigmas: float  # normal jitter is cut at +-clip sigma (a bound keeps min_latency_s useful)
    preserve_order: bool
    reorder_probability: float
    reorder_delay_s: float
    loss_probability: float
    burst: GilbertElliott
    duplicate_probability: float
    corrupt_frame_probability: float
    corrupt_bits_per_frame: int
    bit_error_rate: float
    bandwidth_bps: float  # 0 = unlimited
    queue_capacity_frames: int
    status_window_frames: int
    crazyradio: CrazyradioLink | None = None
    path: str = ""

    @property
    def jitter_bounds_s(self) -> tuple[float, float]:
        """(lowest, highest) jitter value J; the lowest keeps base + J >= 0."""
        if self.jitter_s == 0.0:
            return 0.0, 0.0
        half = self.jitter_s if self.jitter == "uniform" else self.normal_clip_sigmas * self.jitter_s
        return max(-self.base_latency_s, -half), half

    @property
    def min_latency_s(self) -> float:
        """A true lower bound of (delivery time - offer time) for any frame."""
        floor = self.base_latency_s + self.jitter_bounds_s[0]
        cr = self.crazyradio
        if self.model == "crazyradio":  # an uplink packet sent the instant a transaction starts
            floor += cr.settling_s + cr.time_on_air_s(cr.header_bytes_per_packet)
        elif cr is not None:
            floor += cr.attempt_ok_s(0)
        return max(0.0, floor)


def _boolean(p: Params, key: str) -> bool:
    # Params has no boolean accessor (model/config.py); same message shape as its own errors.
    if not p.has(key):
        raise p.error(key, "missing")
    value = p.data[key]
    if not isinstance(value, bool):
        raise p.error(key, f"expected true or false, got {value!r}")
    return value


def _only_known_fields(p: Params, allowed: set[str]) -> None:
    """A misspelt field would otherwise be silently ignored."""
    for key in p.data:
        if key not in allowed:
            raise p.error(key, f"unknown field (expected one of {', '.join(sorted(allowed))})")


def _probability(p: Params, key: str) -> float:
    return p.number(key, minimum=0.0, maximum=1.0)


_TOP_FIELDS = {"schema_version", "name", "source", "model", "latency", "loss", "burst", "duplication",
               "corruption", "queue", "status", "crazyradio"}
_LATENCY_FIELDS = {"base_s", "jitter", "jitter_s", "normal_clip_sigmas", "preserve_order",
                   "reorder_probability", "reorder_delay_s"}
_BURST_FIELDS = {"p_good_to_bad", "p_bad_to_good", "loss_good", "loss_bad"}
_CORRUPTION_FIELDS = {"frame_probability", "bits_per_frame", "bit_error_rate"}
_QUEUE_FIELDS = {"bandwidth_bps", "capacity_frames"}
_CRAZYRADIO_FIELDS = {"air_rate_bps", "data_bytes_per_packet", "header_bytes_per_packet", "preamble_bytes",
                      "address_bytes", "packet_control_bits", "crc_bytes", "ack_payload_bytes", "settling_s",
                      "auto_retransmit_delay_s", "auto_retransmit_count", "packet_loss_probability"}
_TRANSACTION_FIELDS = {"usb_interval_s", "host_retries"}  # model crazyradio only


def _table(p: Params, key: str, allowed: set[str]) -> Params:
    table = p.table(key)
    _only_known_fields(table, allowed)
    return table


def _load_crazyradio(t: Params, model: str) -> CrazyradioLink:
    transactions = {}
    if model == "crazyradio":
        transactions = {"usb_interval_s": t.number("usb_interval_s", minimum=0.0),
                        "host_retries": t.integer("host_retries", minimum=1)}
    return CrazyradioLink(
        **transactions,
        air_rate_bps=t.number("air_rate_bps", minimum=1.0),
        data_bytes_per_packet=t.integer("data_bytes_per_packet", minimum=1),
        header_bytes_per_packet=t.integer("header_bytes_per_packet", minimum=0),
        preamble_bytes=t.integer("preamble_bytes", minimum=0),
        address_bytes=t.integer("address_bytes", minimum=0),
        packet_control_bits=t.integer("packet_control_bits", minimum=0),
        crc_bytes=t.integer("crc_bytes", minimum=0),
        ack_payload_bytes=t.integer("ack_payload_bytes", minimum=0),
        settling_s=t.number("settling_s", minimum=0.0),
        auto_retransmit_delay_s=t.number("auto_retransmit_delay_s", minimum=0.0),
        auto_retransmit_count=t.integer("auto_retransmit_count", minimum=0),
        packet_loss_probability=_probability(t, "packet_loss_probability"),
    )


def radio_profile_path(name_or_path: str | Path) -> Path:
    """A .toml path as given, or the built-in profile of that name (model/params/radio/NAME.toml)."""
    return resolve(name_or_path, "model", "params/radio", "radio profile")


def load_radio_profile(name_or_path: str | Path = DEFAULT_CRTP_RADIO) -> RadioProfile:
    """A built-in profile (ideal, crazyradio, esb-duplex, lab, harsh) or a TOML file.

    Raises model.errors.ConfigError naming the file and the field when a field is missing, misspelt
    or out of range.
    """
    path = radio_profile_path(name_or_path)
    p = Params.load(path)
    _only_known_fields(p, _TOP_FIELDS)
    model = p.string("model", choices=MODELS)
    latency = _table(p, "latency", _LATENCY_FIELDS)
    loss = _table(p, "loss", {"probability"})
    burst = _table(p, "burst", _BURST_FIELDS)
    duplication = _table(p, "duplication", {"probability"})
    corruption = _table(p, "corruption", _CORRUPTION_FIELDS)
    queue = _table(p, "queue", _QUEUE_FIELDS)
    status = _table(p, "status", {"window_frames"})

    jitter = latency.string("jitter", choices=JITTER_LAWS)
    preserve_order = _boolean(latency, "preserve_order")
    reorder_probability = _probability(latency, "reorder_probability")
    if preserve_order and reorder_probability > 0.0:
        raise latency.error("reorder_probability", "must be 0 when preserve_order = true")
    crazyradio = None
    if model in ESB_MODELS:
        allowed = _CRAZYRADIO_FIELDS | (_TRANSACTION_FIELDS if model == "crazyradio" else set())
        crazyradio = _load_crazyradio(_table(p, "crazyradio", allowed), model)
    elif p.has("crazyradio"):
        raise p.error("crazyradio", "given, but model is 'simple' (set model = \"crazyradio\" or "
                                    "\"esb-duplex\" to use it)")

    return RadioProfile(
        name=p.string("name"),
        source=p.string("source"),
        model=model,
        base_latency_s=latency.number("base_s", minimum=0.0),
        jitter=jitter,
        jitter_s=latency.number("jitter_s", minimum=0.0),
        normal_clip_sigmas=latency.number("normal_clip_sigmas", minimum=0.1) if jitter == "normal" else 0.0,
        preserve_order=preserve_order,
        reorder_probability=reorder_probability,
        reorder_delay_s=latency.number("reorder_delay_s", minimum=0.0),
        loss_probability=_probability(loss, "probability"),
        burst=GilbertElliott(
            p_good_to_bad=_probability(burst, "p_good_to_bad"),
            p_bad_to_good=_probability(burst, "p_bad_to_good"),
            loss_good=_probability(burst, "loss_good"),
            loss_bad=_probability(burst, "loss_bad"),
        ),
        duplicate_probability=_probability(duplication, "probability"),
        corrupt_frame_probability=_probability(corruption, "frame_probability"),
        corrupt_bits_per_frame=corruption.integer("bits_per_frame", minimum=1),
        bit_error_rate=_probability(corruption, "bit_error_rate"),
        bandwidth_bps=queue.number("bandwidth_bps", minimum=0.0),
        queue_capacity_frames=queue.integer("capacity_frames", minimum=0),
        status_window_frames=status.integer("window_frames", minimum=1),
        crazyradio=crazyradio,
        path=str(path),
    )
