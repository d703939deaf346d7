"""The `crazyradio` profile's half-duplex air (simulator.radio.EsbAir) against its definitions.

One Crazyradio runs one Enhanced ShockBurst transaction per USB interval; each carries at most one packet up
(the dongle's) and one down (on the Crazyflie's ACK). Expected values come from the nRF24L01+ timing
(T_oa = (8 (preamble + address + payload + CRC) + PCF bits) / rate, Tstby2a, ARD), the USB interval and the
per-attempt loss p, never from the code's own output. Tolerances: 4 sampling standard deviations.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from model.air_budget import air_budget
from model.radio import load_radio_profile
from simulator.radio import DOWNLINK, UPLINK, DropCause, EsbAir, RadioChannel

SIGMAS = 4.0
EPS = 1e-12


def profile(**link_changes):
    base = load_radio_profile("crazyradio")
    return dataclasses.replace(base, crazyradio=dataclasses.replace(base.crazyradio, **link_changes))


def toa(cr, payload_bytes: int) -> float:
    """nRF24L01+ time on air of one packet, s (Product Specification 7.3)."""
    return (8 * (cr.preamble_bytes + cr.address_bytes + payload_bytes + cr.crc_bytes)
            + cr.packet_control_bits) / cr.air_rate_bps


def pair(prof, seed: int = 0, keep_ledger: bool = True) -> tuple[RadioChannel, RadioChannel, EsbAir]:
    air = EsbAir(prof.crazyradio, np.random.default_rng(seed))
    up = RadioChannel(prof, np.random.default_rng(seed + 1), "up", keep_ledger, air=air, direction=UPLINK)
    down = RadioChannel(prof, np.random.default_rng(seed + 2), "down", keep_ledger, air=air, direction=DOWNLINK)
    return up, down, air


def latencies(channel: RadioChannel) -> np.ndarray:
    return np.array([d - f.offered_s for f in channel.ledger for d in f.delivery_s])


def test_the_shipped_profile_is_one_transaction_per_millisecond_with_the_data_sheet_timing():
    prof = load_radio_profile("crazyradio")
    cr = prof.crazyradio
    assert prof.model == "crazyradio" and cr.usb_interval_s == 0.001 and cr.host_retries == 100
    # a transaction with full packets both ways fits one USB interval: the USB, not the air, paces the link
    full_transaction_s = 2 * cr.settling_s + toa(cr, 31) + toa(cr, 31)
    assert full_transaction_s == pytest.approx(581e-6, abs=1e-9) and full_transaction_s < cr.usb_interval_s
    # the earliest arrival: an uplink header-only packet sent the instant a transaction starts
    assert prof.min_latency_s == pytest.approx(cr.settling_s + toa(cr, 1), abs=1e-15)


def test_each_direction_carries_one_packet_per_transaction_and_both_share_it():
    """Offered 2000 one-packet frames a second each way, both directions get the same 1000 a second: the
    downlink rides on the uplink's transactions (it does not take transactions of its own)."""
    prof = profile(packet_loss_probability=0.0)
    up, down, _ = pair(prof)
    seconds, spacing_s = 5.0, 0.0005
    for i in range(int(seconds / spacing_s)):
        t = i * spacing_s
        up.push(bytes(20), t)
        down.push(bytes(20), t)
    for channel in (up, down):
        arrivals = np.sort([d for f in channel.ledger for d in f.delivery_s])
        window = arrivals[(arrivals >= 1.0) & (arrivals < seconds)]  # past the start, before the end of offers
        rate = window.size / (seconds - 1.0)
        assert rate == pytest.approx(1.0 / prof.crazyradio.usb_interval_s, abs=2.0)
        assert channel.stats.dropped[DropCause.QUEUE] > 0  # the rest waited and overflowed the queue
    gaps_up = np.diff(np.sort([d for f in up.ledger for d in f.delivery_s]))
    assert gaps_up.min() >= prof.crazyradio.usb_interval_s - EPS  # never two uplink packets in one transaction


def test_a_long_frame_takes_one_transaction_per_packet():
    """A 280-byte MAVLink frame is ceil(280 / 30) = 10 packets: its last arrives 9 USB intervals after its first
    transaction starts, at the earliest."""
    prof = profile(packet_loss_probability=0.0)
    cr = prof.crazyradio
    up, down, _ = pair(prof)
    t = 0.0123
    up.push(bytes(280), t)
    down.push(bytes(280), t)
    (up_fate,), (down_fate,) = up.ledger, down.ledger
    # uplink: the first transaction starts within one interval; the last packet (10 bytes) is on the air after
    # Tstby2a + T_oa(1 + 10) of the tenth
    last_on_air_s = cr.settling_s + toa(cr, 1 + 280 - 9 * 30)
    assert 9 * cr.usb_interval_s + last_on_air_s - EPS <= up_fate.delivery_s[0] - t
    assert up_fate.delivery_s[0] - t <= 10 * cr.usb_interval_s + last_on_air_s + EPS
    # downlink: the tenth transaction's end, one interval after it started
    assert 10 * cr.usb_interval_s - EPS <= down_fate.delivery_s[0] - t <= 11 * cr.usb_interval_s + EPS


def test_one_way_delay_is_the_wait_for_the_next_transaction_plus_its_air():
    """Single packets at random phases, never two waiting at once (2.5 ms apart + U(0, 1 ms)): the wait for the
    next transaction is uniform on [0, USB interval), so
    the mean uplink delay is interval / 2 + Tstby2a + T_oa(packet) and the downlink's (arrival at the host at
    the transaction's end) interval / 2 + interval."""
    prof = profile(packet_loss_probability=0.0)
    cr = prof.crazyradio
    up, down, _ = pair(prof, seed=4)
    times = np.arange(20_000) * 0.0025 + np.random.default_rng(9).uniform(0.0, 0.001, 20_000)
    for t in times:
        up.push(bytes(14), float(t))
        down.push(bytes(28), float(t))
    usb = cr.usb_interval_s
    on_air = cr.settling_s + toa(cr, 1 + 14)
    d_up, d_down = latencies(up), latencies(down)
    tolerance = SIGMAS * usb / math.sqrt(12 * d_up.size)  # the standard error of a uniform wait's mean
    assert d_up.mean() == pytest.approx(usb / 2 + on_air, abs=tolerance)
    assert d_down.mean() == pytest.approx(usb / 2 + usb, abs=tolerance)
    assert on_air - EPS <= d_up.min() and d_up.max() <= usb + on_air + EPS
    assert usb - EPS <= d_down.min() and d_down.max() <= 2 * usb + EPS
    assert d_up.min() >= up.min_latency_s - EPS and d_down.min() >= down.min_latency_s - EPS


def test_failed_transactions_follow_the_retry_law_and_delay_both_directions_together():
    """Per-attempt loss p: a transaction fails when all ARC + 1 attempts fail, P = p^(ARC+1); then it carries
    nothing either way, and both directions' packets take the next transaction."""
    p = 0.5
    prof = profile(packet_loss_probability=p)
    cr = prof.crazyradio
    up, down, air = pair(prof, seed=11)
    n = 40_000
    spacing_s = 0.004  # sparse: no queueing, each packet takes the first working transaction
    for i in range(n):
        t = i * spacing_s
        up.push(bytes(10), t)
        down.push(bytes(10), t)
    total = air._first + len(air._starts)
    share_failed = air.transactions_failed / total
    expected = p ** (cr.auto_retransmit_count + 1)
    assert share_failed == pytest.approx(expected, abs=SIGMAS * math.sqrt(expected * (1 - expected) / total))
    # offered at the same instant, both packets ride the same transaction: the uplink arrives when its packet
    # is on the air, the downlink when that transaction ends, within one (stretched) transaction of each other
    d_up, d_down = latencies(up), latencies(down)
    failed_attempts_s = (cr.auto_retransmit_count + 1) * cr.attempt_failed_s(30)
    stretched_s = cr.auto_retransmit_count * cr.attempt_failed_s(30) + cr.attempt_ok_s(30)
    assert np.all(d_down > d_up) and np.all(d_down - d_up <= stretched_s + EPS)
    # a packet waited through at least one failed transaction exactly as often as the law says
    retried = np.array([f.retransmissions >= cr.auto_retransmit_count + 1 for f in up.ledger])
    assert retried.mean() == pytest.approx(expected, abs=SIGMAS * math.sqrt(expected * (1 - expected) / n))
    assert np.array_equal(retried, [f.retransmissions >= cr.auto_retransmit_count + 1 for f in down.ledger])
    assert d_up.max() >= failed_attempts_s  # those waited a whole failed transaction at least


def test_a_link_that_never_acknowledges_gives_each_packet_up_after_host_retries_transactions():
    prof = profile(packet_loss_probability=1.0, host_retries=7)
    cr = prof.crazyradio
    up, _, air = pair(prof)
    assert up.push(bytes(20), 0.0) is False
    fate = up.ledger[0]
    assert fate.drop_cause == DropCause.RETRIES
    assert fate.retransmissions == 7 * (cr.auto_retransmit_count + 1)
    assert air.transactions_failed == 7


def test_the_result_does_not_depend_on_which_direction_asks_first():
    """In lockstep the downlink is offered ahead of the uplink (lookahead): the transactions, hence every
    delivery, must be the same as when the two are offered in time order. 30 s covers the air's trimming."""
    prof = profile(packet_loss_probability=0.2)
    rng = np.random.default_rng(5)
    up_times = np.sort(rng.uniform(0, 30.0, 15_000))
    down_times = np.sort(rng.uniform(0, 30.0, 15_000))
    sizes = rng.integers(1, 90, 15_000)

    def deliveries(order: str):
        up, down, _ = pair(prof, seed=21)
        if order == "down first":
            for t, s in zip(down_times, sizes, strict=True):
                down.push(bytes(int(s)), float(t))
            for t, s in zip(up_times, sizes, strict=True):
                up.push(bytes(int(s)), float(t))
        else:
            events = sorted([(t, 0, s) for t, s in zip(up_times, sizes, strict=True)]
                            + [(t, 1, s) for t, s in zip(down_times, sizes, strict=True)])
            for t, which, s in events:
                (up if which == 0 else down).push(bytes(int(s)), float(t))
        return [f.delivery_s for f in up.ledger], [f.delivery_s for f in down.ledger]

    assert deliveries("down first") == deliveries("interleaved")


@pytest.mark.parametrize("command_hz, imu_packets_per_sample, fits", [
    (500.0, 1, True),  # CRTP moments: app-channel commands, 1-packet IMU log blocks at 100 Hz
    (500.0, 3, False),  # MAVLink moments: 500 Hz HIGHRES_IMU of 3 packets each
])
def test_the_simulated_air_agrees_with_the_budget_on_what_fits(command_hz, imu_packets_per_sample, fits):
    """The budget (model.air_budget) says whether a traffic fits one Crazyradio; the simulated air must agree:
    traffic that fits is all delivered within a few intervals, traffic that does not queues and is dropped."""
    prof = load_radio_profile("crazyradio")
    cr = prof.crazyradio
    imu_hz = 100.0 if imu_packets_per_sample == 1 else command_hz
    imu_bytes = 28 if imu_packets_per_sample == 1 else 85
    uplink = [(command_hz, 20), (100.0, 29)]
    downlink = [(imu_hz, imu_bytes)]
    budget = air_budget(cr, uplink, downlink, 1.0 / cr.usb_interval_s)
    assert budget.fits is fits
    up, down, _ = pair(prof, seed=2, keep_ledger=False)
    seconds, dt = 10.0, 0.001
    for i in range(int(seconds / dt)):
        t = i * dt
        for channel, traffic in ((up, uplink), (down, downlink)):
            for hz, size in traffic:
                if i % round(1.0 / (hz * dt)) == 0:
                    channel.push(bytes(size), t)
        up.pop_due(t)
        down.pop_due(t)
    worst = max(up.stats.latency_percentile_s(99.0), down.stats.latency_percentile_s(99.0))
    lost = up.stats.dropped_total + down.stats.dropped_total
    if fits:
        assert lost == 0 and worst <= 5 * cr.usb_interval_s
    else:
        assert down.stats.dropped[DropCause.QUEUE] > 0.2 * down.stats.offered  # a third cannot be carried
        assert down.stats.latency_p50_s > 100 * cr.usb_interval_s  # the rest waits behind a full queue
