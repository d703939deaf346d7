"""The realtime loop (issue 6, tests 3 and 4): the ground station at 500 Hz against the emulator's 1 kHz
physics on the wall clock, for a whole hover flight (~20 s).

Thresholds hold on a busy 2-core machine: the emulator's real-time factor within 1 %, the ground station's
achieved rate within 5 % of nominal, deadline misses below 1 %, and TIMESYNC round trips and one-way frame
ages within 2 ms of a fixed configured radio latency.

Why the ground station's allowance is wider than the emulator's: a ground station that stalls for longer
than a period skips the ticks it missed (RealtimeClock: it never sends a burst of late commands), so every
stall of the process costs its rate, where the emulator's physics catches up. On this project's 2-core VMs
(shared hosts, with steal time) this flight measured 485.9-495.3 Hz (2026-11-27: 485.9 in CI, 495.3 run by
hand with 0.09 s of stalls in all, the longest 43 ms, from a throwaway hook on RealtimeClock.wait; 489.9 after
the loop's garbage collection moved before its first tick), 0.07-0.49 % deadline misses, and the emulator's
factor 1.000 in each.
"""

import json
import re
import signal
import subprocess
import sys
import uuid
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))

from flight_helpers import radio_profile  # noqa: E402
from testsupport import free_port  # noqa: E402

pytestmark = pytest.mark.realtime

LATENCY_S = 0.020
RATE_HZ = 500.0
PHYSICS_HZ = 1000.0
EMULATOR_RATE_TOLERANCE = 0.01
GROUND_RATE_TOLERANCE = 0.05  # skipped ticks: see the module docstring
DEADLINE_MISS_MAX = 0.01
LATENCY_TOLERANCE_MS = 2.0


@pytest.fixture(scope="module")
def realtime_flight(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("realtime")
    radio = radio_profile(tmp, "fixed_latency", latency_s=LATENCY_S)
    endpoint, prefix = f"tcp/127.0.0.1:{free_port()}", f"r{uuid.uuid4().hex[:8]}"
    emulator = subprocess.Popen([sys.executable, "-m", "cfstack", "emulator", "--listen", endpoint, "--id", prefix,
                                 "--clock", "realtime", "--radio", str(radio), "--quiet"],
                                stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                                text=True)
    try:
        run = subprocess.run([sys.executable, "-m", "cfstack", "groundstation", "--connect", endpoint, "--id", prefix,
                              "--clock", "realtime", "--mode", "moments", "--rate", str(RATE_HZ),
                              "--latency-compensation", "--trajectory", "hover", "--json", "--log", str(tmp / "log")],
                             capture_output=True, text=True, timeout=180, stdin=subprocess.DEVNULL)
    finally:
        emulator.send_signal(signal.SIGINT)
        _, err = emulator.communicate(timeout=30)
    assert run.stdout.strip(), run.stderr
    return json.loads(run.stdout), err.strip().splitlines()[-1]


def test_loop_rates_and_deadlines(realtime_flight):
    summary, emulator_line = realtime_flight
    timing = summary["timing"]
    print(f"ground station: {timing}")
    print(emulator_line)
    assert summary["result"] == "reached_goal"
    assert summary["sim_time_s"] >= 20.0
    assert abs(timing["achieved_rate_hz"] / RATE_HZ - 1.0) <= GROUND_RATE_TOLERANCE
    assert timing["deadline_miss_rate"] < DEADLINE_MISS_MAX
    assert timing["tick_ms_p99"] > 0  # reported
    rtf = float(re.search(r"([0-9.]+)x real time", emulator_line).group(1))
    assert abs(rtf - 1.0) <= EMULATOR_RATE_TOLERANCE  # the emulator's 1 kHz physics kept the wall clock's pace


def test_timesync_and_ages_match_the_configured_latency(realtime_flight):
    link = realtime_flight[0]["link"]
    # A TIMESYNC round trip is the radio's latency twice, plus the wait for the emulator's next physics step
    # (it answers there) and for the ground station's next tick (it reads the reply there): on average half
    # of each period, by construction of the two loops, not by load.
    rtt_expected_ms = 2e3 * LATENCY_S + 0.5e3 / PHYSICS_HZ + 0.5e3 / RATE_HZ
    assert abs(link["rtt_ms_p50"] - rtt_expected_ms) <= LATENCY_TOLERANCE_MS
    assert abs(link["age_ms_p50"] - 1e3 * LATENCY_S) <= LATENCY_TOLERANCE_MS
