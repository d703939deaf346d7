"""The simulated radio against its definitions: each impairment measured at the far end over >= 10,000
frames matches the configured law, with tolerances from the sampling standard deviation (4 sigma).
"""

from __future__ import annotations

import binascii
import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest
from scipy.stats import truncnorm

from link.messages import RadioStatus
from model.errors import ConfigError
from model.radio import GilbertElliott, load_radio_profile
from simulator.radio import DropCause, RadioChannel

SIGMAS = 4.0
PROFILES = ("ideal", "crazyradio", "esb-duplex", "lab", "harsh")
RADIO_DIR = Path(__file__).resolve().parents[2] / "model" / "params" / "radio"


def ideal(**changes):
    return dataclasses.replace(load_radio_profile("ideal"), **changes)


def binomial_tolerance(p: float, n: int) -> float:
    """SIGMAS standard deviations of a share estimated from n Bernoulli(p) trials."""
    return SIGMAS * math.sqrt(p * (1.0 - p) / n)


def frame_of(i: int, size: int = 40) -> bytes:
    """A frame that names its offer index in its first 4 bytes."""
    return i.to_bytes(4, "little") + bytes(size - 4)


def run(channel: RadioChannel, n: int, spacing_s: float, size: int = 40, pop_every: int = 1):
    """Offer n frames spacing_s apart, popping as we go; returns [(pop time, frame)]."""
    seen = []
    for i in range(n):
        t = i * spacing_s
        channel.push(frame_of(i, size), t)
        if i % pop_every == 0:
            seen += [(t, f) for f in channel.pop_due(t)]
    seen += [(math.inf, f) for f in channel.pop_due(math.inf)]
    return seen


def delays(channel: RadioChannel) -> np.ndarray:
    return np.array([d - fate.offered_s for fate in channel.ledger for d in fate.delivery_s])


def dropped_flags(channel: RadioChannel) -> np.ndarray:
    return np.array([fate.drop_cause is not None for fate in channel.ledger])


def run_lengths(flags: np.ndarray, value: bool) -> np.ndarray:
    """Lengths of the maximal runs of `value`, without the runs cut by either end of the record."""
    padded = np.concatenate([[False], flags == value, [False]]).astype(int)
    edges = np.flatnonzero(np.diff(padded))
    starts, ends = edges[0::2], edges[1::2]
    inner = (starts > 0) & (ends < len(flags))
    return (ends - starts)[inner]


# --- ideal ---------------------------------------------------------------------------------------


def test_ideal_profile_delivers_everything_unchanged_at_once():
    channel = RadioChannel(load_radio_profile("ideal"), np.random.default_rng(0))
    assert channel.min_latency_s == 0.0
    rng = np.random.default_rng(1)
    sent = [rng.bytes(int(rng.integers(12, 281))) for _ in range(10_000)]
    for i, frame in enumerate(sent):
        t = i * 0.001
        channel.push(frame, t)
        assert channel.next_delivery_s() == t
        assert channel.pop_due(t) == [frame]
    s = channel.stats
    assert (s.offered, s.delivered, s.dropped_total, s.duplicated, s.corrupted, s.reordered) == (
        10_000, 10_000, 0, 0, 0, 0)
    assert s.bytes_delivered == s.bytes_offered == sum(map(len, sent))
    assert s.latency_p50_s == s.latency_p99_s == s.latency_mean_s == 0.0


def test_frames_offered_together_leave_in_offer_order():
    channel = RadioChannel(ideal(base_latency_s=0.01), np.random.default_rng(0))
    for i in range(50):
        channel.push(frame_of(i), 1.0)
    assert channel.pop_due(1.0099) == []
    assert channel.pop_due(1.01) == [frame_of(i) for i in range(50)]


def test_pushing_back_in_time_is_refused():
    channel = RadioChannel(ideal(), np.random.default_rng(0), name="uplink 1")
    channel.push(b"x" * 20, 2.0)
    with pytest.raises(ValueError, match="uplink 1"):
        channel.push(b"x" * 20, 1.0)


# --- loss ----------------------------------------------------------------------------------------


@pytest.mark.parametrize("p", [0.10, 0.30])
def test_iid_loss_rate_matches_probability(p):
    n = 20_000
    channel = RadioChannel(ideal(loss_probability=p), np.random.default_rng(7))
    seen = run(channel, n, 0.001)
    measured = 1.0 - len(seen) / n
    assert abs(measured - p) <= min(binomial_tolerance(p, n), 0.015)
    assert channel.stats.dropped == {DropCause.IID: n - len(seen)}
    # i.i.d.: a loss says nothing about the next frame's fate.
    flags = dropped_flags(channel)
    after_loss = flags[1:][flags[:-1]]
    assert abs(after_loss.mean() - p) <= binomial_tolerance(p, after_loss.size)


def gilbert_elliott_sd_of_mean(ge: GilbertElliott, n: int) -> float:
    """Standard deviation of the mean loss of n frames of a stationary two-state chain:
    Var(sum X)/n -> m (1 - m) + 2 (l_b - l_g)^2 pi_b pi_g lam / (1 - lam), lam = 1 - p_gb - p_bg."""
    pi_b = ge.p_good_to_bad / (ge.p_good_to_bad + ge.p_bad_to_good)
    m = pi_b * ge.loss_bad + (1 - pi_b) * ge.loss_good
    lam = 1.0 - ge.p_good_to_bad - ge.p_bad_to_good
    var = m * (1 - m) + 2 * (ge.loss_bad - ge.loss_good) ** 2 * pi_b * (1 - pi_b) * lam / (1 - lam)
    return math.sqrt(var / n)


def test_gilbert_elliott_mean_loss_and_geometric_bursts():
    p_gb, p_bg = 0.05, 0.2
    ge = GilbertElliott(p_good_to_bad=p_gb, p_bad_to_good=p_bg, loss_good=0.0, loss_bad=1.0)
    n = 50_000
    channel = RadioChannel(ideal(burst=ge), np.random.default_rng(3))
    run(channel, n, 0.001, pop_every=100)
    flags = dropped_flags(channel)
    stationary = p_gb / (p_gb + p_bg) * 1.0 + p_bg / (p_gb + p_bg) * 0.0
    assert abs(flags.mean() - stationary) <= SIGMAS * gilbert_elliott_sd_of_mean(ge, n)
    assert channel.stats.dropped == {DropCause.BURST: int(flags.sum())}
    # With loss 1 in bad and 0 in good, loss runs are the bad sojourns: geometric, mean 1 / p_bg.
    for value, p_leave in ((True, p_bg), (False, p_gb)):
        lengths = run_lengths(flags, value)
        sd = math.sqrt(1 - p_leave) / p_leave
        assert abs(lengths.mean() - 1 / p_leave) <= SIGMAS * sd / math.sqrt(lengths.size)
        for k in (1, 2, 3):  # P(L = k) = (1 - p)^(k-1) p
            pk = (1 - p_leave) ** (k - 1) * p_leave
            assert abs(np.mean(lengths == k) - pk) <= binomial_tolerance(pk, lengths.size)


def test_harsh_profile_loses_thirty_percent_in_bursts():
    profile = load_radio_profile("harsh")
    ge = profile.burst
    assert ge.mean_loss == pytest.approx(0.30)
    n = 40_000
    channel = RadioChannel(profile, np.random.default_rng(11))
    run(channel, n, 0.002, pop_every=100)
    flags = dropped_flags(channel)
    assert abs(flags.mean() - 0.30) <= SIGMAS * gilbert_elliott_sd_of_mean(ge, n)
    # Bursty, not i.i.d.: a loss is followed by another more often than the mean loss rate.
    assert flags[1:][flags[:-1]].mean() > 0.30 + 0.1


# --- latency and order ---------------------------------------------------------------------------


def test_uniform_jitter_spans_base_plus_minus_jitter():
    base, j, n = 0.050, 0.010, 20_000
    channel = RadioChannel(ideal(base_latency_s=base, jitter_s=j, preserve_order=False),
                           np.random.default_rng(5))
    run(channel, n, 0.1, pop_every=50)  # 100 ms apart: no overtaking, no interaction
    d = np.array(channel.stats.latency_s)
    assert d.size == n
    assert abs(d.mean() - base) <= SIGMAS * (j / math.sqrt(3)) / math.sqrt(n)
    assert d.min() >= base - j - 1e-12 and d.max() <= base + j + 1e-12
    # The extremes come within x of the bounds unless (1 - x / 2j)^n is tiny (1e-9 here).
    x = 2 * j * (1 - 1e-9 ** (1 / n))
    assert d.min() <= base - j + x and d.max() >= base + j - x
    assert d.min() >= channel.min_latency_s
    assert channel.stats.latency_p50_s == pytest.approx(np.median(d))


def test_normal_jitter_is_a_normal_cut_at_its_bounds():
    base, sigma, clip, n = 0.020, 0.004, 3.0, 20_000
    profile = ideal(base_latency_s=base, jitter="normal", jitter_s=sigma, normal_clip_sigmas=clip,
                    preserve_order=False)
    channel = RadioChannel(profile, np.random.default_rng(6))
    run(channel, n, 0.1, pop_every=50)
    d = np.array(channel.stats.latency_s)
    law = truncnorm(-clip, clip, loc=base, scale=sigma)
    assert abs(d.mean() - law.mean()) <= SIGMAS * law.std() / math.sqrt(n)
    assert abs(d.std() / law.std() - 1) <= SIGMAS / math.sqrt(2 * n) * 1.5  # sd of a sample sd, ~1/sqrt(2n)
    assert d.min() >= base - clip * sigma - 1e-12 and d.max() <= base + clip * sigma + 1e-12
    assert channel.min_latency_s == pytest.approx(base - clip * sigma)


def test_jitter_never_delivers_before_sending():
    # Base below the jitter half-width: the law is conditioned on delay >= 0.
    channel = RadioChannel(ideal(base_latency_s=0.002, jitter_s=0.010, preserve_order=False),
                           np.random.default_rng(8))
    run(channel, 10_000, 0.05, pop_every=50)
    d = np.array(channel.stats.latency_s)
    assert channel.min_latency_s == 0.0
    assert d.min() >= 0.0 and d.max() <= 0.012 + 1e-12
    assert abs(d.mean() - 0.006) <= SIGMAS * (0.012 / math.sqrt(12)) / math.sqrt(d.size)


def test_reordering_happens_only_when_configured():
    n, spacing = 10_000, 0.002
    # Jitter far above the spacing, but order preserved: never reordered, delivery times monotone.
    kept = RadioChannel(ideal(base_latency_s=0.02, jitter_s=0.01, preserve_order=True),
                        np.random.default_rng(1))
    seen = run(kept, n, spacing)
    assert kept.stats.reordered == 0
    assert [int.from_bytes(f[:4], "little") for _, f in seen] == list(range(n))
    # No jitter, no explicit reordering: in order even with preserve_order off.
    plain = RadioChannel(ideal(base_latency_s=0.02, preserve_order=False), np.random.default_rng(1))
    run(plain, n, spacing)
    assert plain.stats.reordered == 0
    # Jitter without preserve_order: frames overtake.
    jittered = RadioChannel(ideal(base_latency_s=0.02, jitter_s=0.01, preserve_order=False),
                            np.random.default_rng(1))
    run(jittered, n, spacing)
    assert jittered.stats.reordered > 0
    # Explicit reordering with delay 1.5 spacings: frame i is overtaken exactly when it is delayed
    # and frame i+1 is not, so the reordered share is p (1 - p).
    p = 0.1
    explicit = RadioChannel(ideal(reorder_probability=p, reorder_delay_s=1.5 * spacing, preserve_order=False),
                            np.random.default_rng(2))
    run(explicit, n, spacing)
    share = p * (1 - p)
    assert abs(explicit.stats.reordered / n - share) <= binomial_tolerance(share, n)


# --- duplication and corruption -------------------------------------------------------------------


def test_duplication_rate_and_copies():
    p, n = 0.05, 20_000
    channel = RadioChannel(ideal(duplicate_probability=p), np.random.default_rng(4))
    seen = [f for _, f in run(channel, n, 0.001)]
    duplicated = len(seen) - n
    assert channel.stats.duplicated == duplicated == sum(fate.duplicated for fate in channel.ledger)
    assert abs(duplicated / n - p) <= binomial_tolerance(p, n)
    # Every frame arrives, a duplicate right after its original, byte for byte.
    assert sorted(set(seen)) == sorted(frame_of(i) for i in range(n))
    repeats = [a == b for a, b in zip(seen, seen[1:], strict=False)]
    assert sum(repeats) == duplicated


def with_crc(payload: bytes) -> bytes:
    # CRC-16 with the CCITT polynomial x^16 + x^12 + x^5 + 1, the one of MAVLink's CRC-16/MCRF4XX.
    return payload + binascii.crc_hqx(payload, 0xFFFF).to_bytes(2, "little")


def crc_ok(frame: bytes) -> bool:
    return with_crc(frame[:-2]) == frame


def test_corruption_flips_exactly_k_bits_at_the_configured_rate_and_a_crc_catches_it():
    p, k, n = 0.1, 3, 20_000
    channel = RadioChannel(ideal(corrupt_frame_probability=p, corrupt_bits_per_frame=k),
                           np.random.default_rng(9))
    sent = [with_crc(frame_of(i, 60)) for i in range(n)]
    received = []
    for i, frame in enumerate(sent):
        channel.push(frame, i * 0.001)
        received += channel.pop_due(i * 0.001)
    corrupted = 0
    for original, got in zip(sent, received, strict=True):
        flipped = sum(bin(a ^ b).count("1") for a, b in zip(original, got, strict=True))
        assert flipped in (0, k)
        assert crc_ok(got) == (flipped == 0)  # a 16-bit CCITT CRC detects every error of <= 3 bits
        corrupted += flipped > 0
    assert channel.stats.corrupted == corrupted
    assert abs(corrupted / n - p) <= binomial_tolerance(p, n)


def test_bit_error_rate_flips_bits_independently():
    ber, size, n = 2e-4, 100, 20_000
    channel = RadioChannel(ideal(bit_error_rate=ber), np.random.default_rng(10))
    frame = bytes(size)
    flips = []
    for i in range(n):
        channel.push(frame, float(i))
        (got,) = channel.pop_due(float(i))
        flips.append(sum(bin(b).count("1") for b in got))
    flips = np.array(flips)
    bits = 8 * size
    assert abs(flips.mean() - bits * ber) <= SIGMAS * math.sqrt(bits * ber * (1 - ber) / n)
    p_any = 1 - (1 - ber) ** bits
    assert abs(np.mean(flips > 0) - p_any) <= binomial_tolerance(p_any, n)


# --- bandwidth and queue --------------------------------------------------------------------------


def test_bandwidth_limits_throughput_and_a_full_queue_drops():
    bandwidth, size = 100_000.0, 100  # 8 ms per frame
    service = 8 * size / bandwidth
    channel = RadioChannel(ideal(bandwidth_bps=bandwidth, queue_capacity_frames=10, base_latency_s=0.003),
                           np.random.default_rng(0))
    n = 10_000
    run(channel, n, 0.005, size=size)  # offered at 160 kbit/s
    times = np.sort([d for fate in channel.ledger for d in fate.delivery_s])
    assert np.all(np.diff(times) >= service - 1e-12)  # never two frames closer than one serialisation
    # Over any span, delivered bits <= bandwidth x span + one frame.
    for lag in (1, 10, 100, 1000):
        span = times[lag:] - times[:-lag]
        assert np.all(8 * size * lag <= bandwidth * span + 8 * size + 1e-6)
    assert 8 * size * (times.size - 1) / (times[-1] - times[0]) <= bandwidth * (1 + 1e-9)
    # The surplus (160 - 100 kbit/s) is dropped at the queue, and only there.
    s = channel.stats
    assert set(s.dropped) == {DropCause.QUEUE}
    assert abs(s.dropped[DropCause.QUEUE] / n - (1 - 100 / 160)) < 0.01  # minus the queue's final fill
    assert max(s.latency_s) <= 0.003 + 11 * service + 1e-9  # waits behind at most 10 frames + own


def test_queue_holds_capacity_frames_behind_the_one_on_the_air():
    channel = RadioChannel(ideal(bandwidth_bps=100_000.0, queue_capacity_frames=5), np.random.default_rng(0))
    for i in range(50):
        channel.push(frame_of(i, 100), 0.0)
    causes = [fate.drop_cause for fate in channel.ledger]
    assert causes == [None] * 6 + [DropCause.QUEUE] * 44
    assert channel.radio_status(0.0)["tx_buffer_pct"] == 0
    # At 16.5 ms frame 2 is on the air (16..24 ms): frames 3, 4, 5 wait, 2 of 5 places are free.
    assert channel.radio_status(0.0165)["tx_buffer_pct"] == 40
    assert channel.radio_status(1.0)["tx_buffer_pct"] == 100


# --- esb-duplex (the Crazyradio's packets, each direction on its own air) --------------------------------------


def crazyradio_expectations(profile, size: int) -> tuple[float, float, float, float]:
    """(P(lost), mean delay of a delivered frame, delay with no retry, delay with ARC retries of every
    packet), jitter aside, from the nRF24L01+ definitions:
    T_oa = (8 (preamble + address + payload + CRC) + PCF bits) / rate; an attempt that succeeds takes
    Tstby2a + T_oa(packet) + Tstby2a + T_oa(ACK), one that fails Tstby2a + T_oa(packet) + ARD."""
    cr = profile.crazyradio
    p, arc = cr.packet_loss_probability, cr.auto_retransmit_count

    def toa(payload):
        return (8 * (cr.preamble_bytes + cr.address_bytes + payload + cr.crc_bytes)
                + cr.packet_control_bits) / cr.air_rate_bps

    packets = math.ceil(size / cr.data_bytes_per_packet)
    data = [cr.data_bytes_per_packet] * (packets - 1) + [size - cr.data_bytes_per_packet * (packets - 1)]
    ok = [2 * cr.settling_s + toa(cr.header_bytes_per_packet + d) + toa(cr.ack_payload_bytes) for d in data]
    failed = [cr.settling_s + toa(cr.header_bytes_per_packet + d) + cr.auto_retransmit_delay_s for d in data]
    retries_given_success = sum(k * p**k * (1 - p) for k in range(arc + 1)) / (1 - p ** (arc + 1))
    lost = 1 - (1 - p ** (arc + 1)) ** packets
    mean = profile.base_latency_s + sum(ok) + retries_given_success * sum(failed)
    fastest = profile.base_latency_s + sum(ok)
    return lost, mean, fastest, fastest + arc * sum(failed)


def test_esb_duplex_loss_and_delay_grow_with_frame_size_as_the_formula_says():
    profile = dataclasses.replace(load_radio_profile("esb-duplex"), jitter_s=0.0)
    profile = dataclasses.replace(profile, crazyradio=dataclasses.replace(profile.crazyradio,
                                                                          packet_loss_probability=0.3))
    n = 10_000
    measured = {}
    for size in (20, 280):
        channel = RadioChannel(profile, np.random.default_rng(size))
        run(channel, n, 0.05, size=size, pop_every=20)  # 50 ms apart: the queue is always empty
        lost_share = 1 - channel.stats.delivered / n
        lost, mean, fastest, _ = crazyradio_expectations(profile, size)
        assert channel.stats.dropped == {DropCause.RETRIES: n - channel.stats.delivered}
        assert abs(lost_share - lost) <= binomial_tolerance(lost, n)
        d = np.array(channel.stats.latency_s)
        assert abs(d.mean() - mean) <= SIGMAS * d.std() / math.sqrt(d.size)
        assert d.min() == pytest.approx(fastest, abs=1e-12)  # some frames need no retry at all
        assert fastest >= channel.min_latency_s
        measured[size] = (lost_share, d.mean())
    assert measured[280][0] > measured[20][0] and measured[280][1] > measured[20][1]


def test_esb_duplex_profile_is_a_few_milliseconds_one_way():
    profile = load_radio_profile("esb-duplex")
    channel = RadioChannel(profile, np.random.default_rng(0))
    size = 40  # a typical MAVLink frame: two radio packets
    run(channel, 10_000, 0.01, size=size)
    d = np.array(channel.stats.latency_s)
    _, _, fastest, slowest = crazyradio_expectations(profile, size)
    j = profile.jitter_s
    assert fastest - j - 1e-12 <= d.min() and d.max() <= slowest + j + 1e-12
    assert 0.001 <= np.median(d) <= 0.003  # "1-3 ms one way"
    fixed = sum(f.retransmissions > 0 for f in channel.ledger if f.delivered)
    assert 0 < channel.radio_status()["fixed"] == fixed


# --- shipped profiles, determinism, ledger --------------------------------------------------------


def test_lab_profile_is_twenty_to_twenty_six_milliseconds_in_order():
    channel = RadioChannel(load_radio_profile("lab"), np.random.default_rng(0))
    run(channel, 10_000, 0.002)
    d = np.array(channel.stats.latency_s)
    assert 0.020 - 1e-12 <= d.min() and d.max() <= 0.026 + 1e-12
    assert channel.stats.reordered == 0
    p = load_radio_profile("lab").loss_probability
    assert abs(channel.stats.dropped_total / 10_000 - p) <= binomial_tolerance(p, 10_000)


@pytest.mark.parametrize("name", PROFILES)
def test_min_latency_is_a_true_lower_bound(name):
    channel = RadioChannel(load_radio_profile(name), np.random.default_rng(2))
    rng = np.random.default_rng(3)
    t = 0.0
    for _ in range(5_000):
        t += float(rng.exponential(0.002))
        channel.push(rng.bytes(int(rng.integers(12, 281))), t)
        assert all(d >= t + channel.min_latency_s for d in channel.ledger[-1].delivery_s)
        channel.pop_due(t)
        due = channel.next_delivery_s()
        assert due is None or due > t
    channel.pop_due(math.inf)
    assert min(channel.stats.latency_s) >= channel.min_latency_s
    assert channel.next_delivery_s() is None


@pytest.mark.parametrize("name", PROFILES)
def test_same_seed_same_ledger_different_seed_different(name):
    def ledger(seed):
        channel = RadioChannel(load_radio_profile(name), np.random.default_rng(seed))
        seen = run(channel, 3_000, 0.002, size=100, pop_every=7)
        return channel.ledger, [f for _, f in seen]

    first, again, other = ledger(42), ledger(42), ledger(43)
    assert first == again
    if name != "ideal":  # the ideal radio draws nothing: every seed gives the same fates
        assert first[0] != other[0]


@pytest.mark.parametrize("name", PROFILES)
def test_keeping_no_ledger_changes_nothing_the_far_end_sees(name):
    def far_end(keep_ledger):
        channel = RadioChannel(load_radio_profile(name), np.random.default_rng(9), keep_ledger=keep_ledger)
        rng = np.random.default_rng(10)
        seen = []
        for i in range(3_000):
            t = i * 0.001
            channel.push(rng.bytes(int(rng.integers(12, 281))), t)
            seen += [(t, f) for f in channel.pop_due(t)]
        seen += [(math.inf, f) for f in channel.pop_due(math.inf)]
        s = channel.stats
        return seen, (s.delivered, s.dropped, s.duplicated, s.corrupted, s.reordered, s.repaired,
                      list(s.latency_s)), channel.radio_status(), len(channel.ledger)

    kept, dropped = far_end(True), far_end(False)
    assert kept[:3] == dropped[:3]
    assert (kept[3], dropped[3]) == (3_000, 0)


def test_ledger_matches_what_the_far_end_saw_frame_for_frame():
    profile = dataclasses.replace(load_radio_profile("harsh"), corrupt_frame_probability=0.0)
    channel = RadioChannel(profile, np.random.default_rng(12))
    seen = run(channel, 10_000, 0.004, pop_every=3)
    expected = sorted(((d, i) for i, fate in enumerate(channel.ledger) for d in fate.delivery_s),
                      key=lambda pair: pair[0])  # stable: ties keep offer order
    assert [int.from_bytes(f[:4], "little") for _, f in seen] == [i for _, i in expected]
    # Each frame came out at the first pop_due call at or after its delivery time.
    pop_times = sorted({t for t, _ in seen})
    for (popped_at, _), (delivery_s, _) in zip(seen, expected, strict=True):
        assert delivery_s <= popped_at
        earlier = [t for t in pop_times if t < popped_at]
        assert not earlier or delivery_s > earlier[-1]
    s = channel.stats
    assert s.offered == 10_000 and s.delivered == len(seen)
    assert s.offered + s.duplicated == s.delivered + s.dropped_total
    assert s.dropped == {DropCause.BURST: sum(f.drop_cause is DropCause.BURST for f in channel.ledger)}


def test_radio_status_reports_the_link_as_the_ledger_shows_it():
    window = 100
    down = RadioChannel(ideal(loss_probability=0.3, status_window_frames=window,
                              corrupt_frame_probability=0.05), np.random.default_rng(1))
    up = RadioChannel(ideal(status_window_frames=window), np.random.default_rng(2))
    assert down.radio_status()["rssi"] == 255  # nothing sent yet: unknown
    run(down, 1_000, 0.001)
    run(up, 10, 0.001)
    recent = [f.drop_cause is None for f in down.ledger[-window:]]
    status = RadioStatus(**down.radio_status(reverse=up))
    assert status.remote_rssi == round(254 * sum(recent) / window)
    assert status.rssi == 254  # the uplink lost nothing
    assert status.rx_errors == 0  # corruption happened on the downlink, seen by the far end
    symmetric = down.radio_status()
    assert symmetric["rssi"] == symmetric["remote_rssi"] == status.remote_rssi
    assert symmetric["rx_errors"] == down.stats.corrupted == sum(f.corrupted for f in down.ledger) > 0
    assert status.tx_buffer_pct == 100 and status.noise == status.remote_noise == 255


def test_the_vehicles_reception_counts_only_uplink_frames_offered_by_the_cutoff():
    """A lockstep emulator running ahead may have offered some of a tick's uplink frames and not others when
    it reports (fleet.VehicleNode._push_radio_status): rssi covers the window of frames offered by the cutoff,
    as the ledger shows them, whatever was offered after it."""
    window = 50
    down = RadioChannel(ideal(status_window_frames=window), np.random.default_rng(1))
    up = RadioChannel(ideal(loss_probability=0.3, status_window_frames=window), np.random.default_rng(2))
    run(down, 10, 0.001)
    run(up, 400, 0.001)  # offered at 0, 1, ..., 399 ms
    cutoff_s = 0.2995  # frames 0..299 offered by then
    fates = [f.drop_cause is None for f in up.ledger if f.offered_s <= cutoff_s][-window:]
    assert len(fates) == window and sum(fates) < window
    expected = round(254 * sum(fates) / window)
    assert down.radio_status(reverse=up, reverse_offered_by_s=cutoff_s)["rssi"] == expected
    later = [f.drop_cause is None for f in up.ledger[-window:]]
    assert down.radio_status(reverse=up)["rssi"] == round(254 * sum(later) / window)  # no cutoff: the newest
    assert down.radio_status(reverse=up, reverse_offered_by_s=-1.0)["rssi"] == 255  # none offered by then


# --- configuration errors -------------------------------------------------------------------------


def write_variant(tmp_path, base: str, old: str, new: str) -> Path:
    text = (RADIO_DIR / f"{base}.toml").read_text()
    assert old in text
    path = tmp_path / "variant.toml"
    path.write_text(text.replace(old, new, 1))
    return path


@pytest.mark.parametrize("base, old, new, field", [
    ("lab", "probability = 0.01", "probability = 1.5", "loss.probability"),
    ("lab", "probability = 0.01", "", "loss.probability: missing"),
    ("lab", "probability = 0.01", "probability = 0.01\nprobabilty = 0.2", "loss.probabilty: unknown field"),
    ("lab", "preserve_order = true", 'preserve_order = "yes"', "latency.preserve_order"),
    ("lab", "reorder_probability = 0.0", "reorder_probability = 0.1", "latency.reorder_probability"),
    ("lab", 'model = "simple"', 'model = "crazyradio"', "crazyradio: missing"),
    ("lab", 'model = "simple"', 'model = "wifi"', "model"),
    ("lab", 'jitter = "uniform"', 'jitter = "normal"', "latency.normal_clip_sigmas: missing"),
    ("crazyradio", 'model = "crazyradio"', 'model = "simple"', "crazyradio: given"),
    ("crazyradio", "usb_interval_s = 0.001", "", "crazyradio.usb_interval_s: missing"),
    ("crazyradio", "host_retries = 100", "host_retries = 0", "crazyradio.host_retries"),
    ("esb-duplex", 'model = "esb-duplex"', 'model = "crazyradio"', "crazyradio.usb_interval_s: missing"),
    ("esb-duplex", "packet_loss_probability = 0.02", "packet_loss_probability = 0.02\nhost_retries = 5",
     "crazyradio.host_retries: unknown field"),
    ("crazyradio", "packet_loss_probability = 0.02", "packet_loss_probability = -0.1",
     "crazyradio.packet_loss_probability"),
    ("harsh", "p_bad_to_good = 0.25", "p_bad_to_good = 2", "burst.p_bad_to_good"),
    ("harsh", "capacity_frames = 0", "capacity_frames = 2.5", "queue.capacity_frames"),
])
def test_bad_profile_files_give_one_line_errors_naming_file_and_field(tmp_path, base, old, new, field):
    path = write_variant(tmp_path, base, old, new)
    with pytest.raises(ConfigError) as err:
        load_radio_profile(path)
    message = str(err.value)
    assert str(path) in message and field in message and "\n" not in message


def test_unknown_profile_name_lists_the_built_in_ones():
    with pytest.raises(ConfigError, match="crazyradio, esb-duplex, harsh, ideal, lab"):
        load_radio_profile("carrier-pigeon")


@pytest.mark.parametrize("name", PROFILES)
def test_shipped_profiles_load_and_cite_a_source(name):
    profile = load_radio_profile(name)
    assert profile.name == name and len(profile.source) > 40
