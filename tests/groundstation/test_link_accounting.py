"""What the ground station reports about the link is true (issue 6, tests 1-3), in lockstep.

1. Determinism: two `cfstack fly` runs of a lab maze with the same seed write byte-identical states.csv.
2. Loss accounting: with i.i.d. loss of 0, 10 and 30 % and with bursty (Gilbert-Elliott) loss on both
   directions, the ground station's measured loss matches what the emulator's radio dropped - frame for
   frame on the downlink (MAVLink sequence numbers against the radio's ledger), and as counts on the
   uplink (the vehicle reports how many uplink frames it received) - and the configured rate within
   2 percentage points over at least 10,000 frames each way.
3. Latency accounting: with a fixed one-way latency, TIMESYNC round trips and one-way frame ages equal
   the configured latency exactly (lockstep: both ends on simulation time).
"""

import hashlib
import json
import signal
import subprocess
import sys
import uuid
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import pytest

from link.keys import GROUND_STATION_SYSTEM_ID
from link.mavlink.codec import ActuatorLimits, FrameParser
from link.mavlink.tlog import read_tlog
from link.messages import RadioStatus
from model.vehicle import load_vehicle

sys.path.insert(0, str(Path(__file__).resolve().parent))

from flight_helpers import radio_profile  # noqa: E402
from testsupport import cfstack, free_port, shared_world  # noqa: E402

MIN_FRAMES = 10_000
RATE_TOLERANCE = 0.02  # 2 percentage points


def fly_against_emulator(tmp_path: Path, radio: Path, *gs_args: str) -> tuple[dict, dict, Path]:
    """Emulator (with its radio ledger) and ground station as two programs; returns (summary, report, log)."""
    endpoint, prefix = f"tcp/127.0.0.1:{free_port()}", f"a{uuid.uuid4().hex[:8]}"
    ledger, log = tmp_path / "radio.json", tmp_path / "log"
    emulator = subprocess.Popen([sys.executable, "-m", "cfstack", "emulator", "--listen", endpoint, "--id", prefix,
                                 "--clock", "lockstep", "--radio", str(radio), "--seed", "3",
                                 "--radio-ledger", str(ledger), "--quiet"],
                                stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                                text=True)
    try:
        run = subprocess.run([sys.executable, "-m", "cfstack", "groundstation", "--connect", endpoint, "--id", prefix,
                              "--clock", "lockstep", "--json", "--log", str(log), *gs_args],
                             capture_output=True, text=True, timeout=300, stdin=subprocess.DEVNULL)
    finally:
        emulator.send_signal(signal.SIGINT)
        emulator.communicate(timeout=30)
    assert run.stdout.strip(), run.stderr
    return json.loads(run.stdout), json.loads(ledger.read_text())["vehicles"]["1"], log


def received_downlink_indices(log: Path) -> list[int]:
    """Offer indices of the downlink frames the ground station received, unwrapped from 8-bit sequences."""
    frames = read_tlog(log / "link.mavlink.tlog", FrameParser(ActuatorLimits.from_vehicle(load_vehicle())))
    indices, last_seq, index = [], None, -1
    for _, decoded in frames:
        if decoded.system_id == GROUND_STATION_SYSTEM_ID:
            continue
        index = decoded.sequence if last_seq is None else index + (decoded.sequence - last_seq) % 256
        last_seq = decoded.sequence
        indices.append(index)
    return indices


LOSS_CASES = {
    "iid_0": dict(loss=0.0),
    "iid_10": dict(loss=0.10),
    "iid_30": dict(loss=0.30),
    # Gilbert-Elliott: bursts of mean length 1 / p_bg = 5 frames; stationary loss p_gb / (p_gb + p_bg)
    "bursty": dict(burst=(0.02, 0.2, 0.0, 1.0)),
}


def configured_loss(case: dict) -> float:
    if "burst" in case:
        p_gb, p_bg, loss_good, loss_bad = case["burst"]
        bad = p_gb / (p_gb + p_bg)
        return bad * loss_bad + (1 - bad) * loss_good
    return case["loss"]


@pytest.fixture(scope="module")
def loss_flights(tmp_path_factory):
    """One hover per loss case, flown two at a time (each lockstep flight keeps about one core busy)."""
    def fly(case: str):
        folder = tmp_path_factory.mktemp(case)
        radio = radio_profile(folder, case, **LOSS_CASES[case])
        return fly_against_emulator(folder, radio, "--trajectory", "hover", "--mode", "moments")

    with ThreadPoolExecutor(2) as pool:
        futures = {case: pool.submit(fly, case) for case in LOSS_CASES}
        return {case: future.result() for case, future in futures.items()}


@pytest.mark.parametrize("case", list(LOSS_CASES))
def test_measured_loss_matches_the_radio_frame_for_frame(loss_flights, case):
    summary, report, log = loss_flights[case]
    link = summary["link"]
    down, up = report["downlink"], report["uplink"]

    # Downlink, frame for frame: the frames the ground station holds are exactly those the radio delivered.
    received = received_downlink_indices(log)
    delivered = [i for i, fate in enumerate(down["ledger"]) if fate[3]]
    first, last = received[0], received[-1]
    assert received == [i for i in delivered if first <= i <= last]
    # Sequence numbers can only reveal losses between the first and the last frame received.
    dropped = sum(1 for fate in down["ledger"][first: last + 1] if fate[2] is not None)
    assert link["downlink_lost"] == dropped  # loss from sequence numbers = the radio's drops
    assert link["downlink_sent"] == last - first + 1 >= MIN_FRAMES

    # Uplink: what the vehicle reports receiving is exactly what the radio delivered of what we sent.
    assert up["offered"] == link["uplink_sent"] >= MIN_FRAMES
    assert link["uplink_delivered"] == up["delivered"]
    assert link["uplink_lost"] == up["dropped_total"]

    expected = configured_loss(LOSS_CASES[case])
    assert abs(link["downlink_lost"] / link["downlink_sent"] - expected) <= RATE_TOLERANCE
    assert abs(link["uplink_lost"] / link["uplink_sent"] - expected) <= RATE_TOLERANCE


def test_timesync_and_frame_ages_equal_the_configured_latency(tmp_path):
    latency_s = 0.020  # a multiple of the 2 ms control tick and of the IMU period: no quantisation
    radio = radio_profile(tmp_path, "fixed20", latency_s=latency_s)
    summary, _, _ = fly_against_emulator(tmp_path, radio, "--trajectory", "hover", "--mode", "moments",
                                         "--latency-compensation")
    link = summary["link"]
    assert link["rtt_ms_p50"] == pytest.approx(2e3 * latency_s, abs=1e-6)
    # Known: one early TIMESYNC (sent at 0.1 s, while arming) comes back one 2 ms control tick late, so the
    # 99th percentile is interpolated towards 42 ms; every other round trip is exactly 40 ms.
    assert 2e3 * latency_s - 1e-6 <= link["rtt_ms_p99"] <= 2e3 * latency_s + 2.0
    assert link["age_ms_p50"] == pytest.approx(1e3 * latency_s, abs=1e-6)
    assert link["age_ms_p99"] == pytest.approx(1e3 * latency_s, abs=1e-6)


def _states_hash(tmp_path, seed: int, name: str, mode: str, *extra: str) -> str:
    log = tmp_path / name
    run = subprocess.run([sys.executable, "-m", "cfstack", "fly", str(shared_world("maze_2024_1")), "--mode",
                          mode, "--seed", str(seed), "--json", "--log", str(log), *extra],
                         capture_output=True, text=True, timeout=300, stdin=subprocess.DEVNULL)
    assert json.loads(run.stdout)["result"] == "reached_goal", run.stderr
    return hashlib.sha256((log / "states.csv").read_bytes()).hexdigest()


def _states_hashes(tmp_path, *runs: tuple) -> list[str]:
    """_states_hash of each (seed, name, mode, *extra), flown at once: a lockstep flight keeps about one core
    busy (its two processes wait on each other), and the runs are independent (own endpoint, own log)."""
    with ThreadPoolExecutor(len(runs)) as pool:
        futures = [pool.submit(_states_hash, tmp_path, *run) for run in runs]
        return [future.result() for future in futures]


def test_same_seed_gives_byte_identical_states_and_another_seed_differs(tmp_path):
    first, again, other = _states_hashes(tmp_path, (11, "a", "attitude"), (11, "b", "attitude"),
                                         (12, "c", "attitude"))
    assert again == first and other != first


def test_a_lossy_radios_tlog_is_the_same_frame_for_frame_run_to_run(tmp_path):
    """Two lockstep runs of one seed on the harsh radio, flown at once: the same log and the same tlog frames.
    RADIO_STATUS reports the vehicle's reception of the uplink, whose frames a lockstep emulator running ahead
    offers when their tick's ack comes (before or after the report's step, as the machine goes): the report
    counts only frames it has surely offered by then. Before, its rssi differed between runs."""
    words = ("fly", "--trajectory", "hover", "--mode", "attitude", "--radio", "harsh", "--clock", "lockstep",
             "--seed", "5", "--json", "--log")
    with ThreadPoolExecutor(2) as pool:
        runs = [pool.submit(cfstack, *words, str(tmp_path / name)) for name in ("a", "b")]
        for run in runs:
            assert json.loads(run.result().stdout)["result"] == "reached_goal", run.result().stderr
    assert (tmp_path / "a" / "states.csv").read_bytes() == (tmp_path / "b" / "states.csv").read_bytes()
    decoded = [[frame for _, frame in read_tlog(tmp_path / name / "link.mavlink.tlog")] for name in "ab"]
    assert [d.frame for d in decoded[0]] == [d.frame for d in decoded[1]]
    rssi = [d.message.rssi for d in decoded[0] if isinstance(d.message, RadioStatus)]
    assert len(rssi) >= 10 and min(rssi) < 254  # the reports saw uplink losses


def test_pipelined_ticks_give_the_same_flight_as_strict_lockstep(tmp_path):
    """In moments mode at 500 Hz the emulator publishes a tick before the last one's ack arrives (the
    firmware-cycle lookahead covers a whole tick); with --no-lookahead it waits for every ack. The
    flight log must not tell them apart."""
    pipelined, strict = _states_hashes(tmp_path, (5, "pipelined", "moments"),
                                       (5, "strict", "moments", "--emulator-arg=--no-lookahead"))
    assert strict == pipelined
