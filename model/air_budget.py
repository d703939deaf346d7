"""What a stream of traffic costs on one Crazyradio: a half-duplex Enhanced ShockBurst link.

Takes in: a CrazyradioLink (model.radio: the crazyradio profile's timing, from the nRF24L01+ data sheet) and
the traffic of each direction as (frames per second, frame bytes) pairs.
Gives out: AirBudget: radio packets per second each way, the transactions the dongle must run, their air
time per second (1.0 = the air is full), and the same against the dongle's USB cadence.

The link (nRF24L01+ Product Specification 7.3-7.9; cflib radiodriver.py): the dongle (PTX) sends every
packet, the Crazyflie (PRX) answers each with an acknowledgement that may carry one packet of its own
(ACK payload, at most 32 bytes). So the downlink rides on the uplink: a second needs max(U, D) transactions
for U uplink and D downlink packets, the dongle filling the difference with null packets (CRTP 0xFF, which
cflib sends to poll). A frame of L bytes travels in ceil(L / data_bytes_per_packet) packets, each with its
CRTP header byte. A transaction takes T_set + T_oa(up) + T_set + T_oa(ACK); with per-attempt loss p an
attempt fails with probability p, costing T_set + T_oa(up) + ARD, so a transaction takes on average
p / (1 - p) failed attempts more (ARC bounds them; at p = 2 % the bound does not bind).
Each transaction is also one USB exchange; the profile's source has the Crazyradio PA's USB working in 1 ms
intervals, so `usb_load` counts transactions against usb_transactions_per_s.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass

from model.radio import CrazyradioLink

NULL_PACKET_BYTES = 1  # a CRTP null packet is its header alone


@dataclass(frozen=True)
class AirBudget:
    uplink_packets_per_s: float
    downlink_packets_per_s: float
    transactions_per_s: float
    air_s_per_s: float  # air time used per second of flight (the link is full at 1.0)
    usb_load: float  # transactions per second / the USB cadence

    @property
    def fits(self) -> bool:
        return self.air_s_per_s <= 1.0 and self.usb_load <= 1.0


def packets(link: CrazyradioLink, traffic: Iterable[tuple[float, int]]) -> list[tuple[float, int]]:
    """(packets per second, data bytes) of a direction's traffic cut into radio packets."""
    out = []
    d = link.data_bytes_per_packet
    for rate_hz, frame_bytes in traffic:
        full, rest = divmod(frame_bytes, d)
        if full:
            out.append((rate_hz * full, d))
        if rest:
            out.append((rate_hz, rest))
    return out


def air_budget(link: CrazyradioLink, uplink: Iterable[tuple[float, int]], downlink: Iterable[tuple[float, int]],
               usb_transactions_per_s: float) -> AirBudget:
    """The budget of one second of this traffic (see the module docstring)."""
    up, down = packets(link, uplink), packets(link, downlink)
    u, dn = sum(r for r, _ in up), sum(r for r, _ in down)
    n = max(u, dn)
    header = link.header_bytes_per_packet
    # uplink side: the data packets, then null packets for the transactions only the downlink needs
    send_s = sum(r * link.time_on_air_s(header + b) for r, b in up)
    send_s += (n - u) * link.time_on_air_s(NULL_PACKET_BYTES)
    # ACK side: the downlink packets ride on ACKs, the rest are empty ACKs
    ack_s = sum(r * link.time_on_air_s(header + b) for r, b in down) + (n - dn) * link.time_on_air_s(0)
    ok_s = 2.0 * link.settling_s * n + send_s + ack_s
    p = link.packet_loss_probability
    retries = p / (1.0 - p) if p < 1.0 else math.inf
    failed_s = retries * (n * (link.settling_s + link.auto_retransmit_delay_s) + send_s)
    return AirBudget(u, dn, n, ok_s + failed_s, n / usb_transactions_per_s)
