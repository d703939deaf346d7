"""The README's two-process session, exactly as written: `cfstack emulator` and `cfstack groundstation` with
their defaults (realtime clock, zenoh on tcp/127.0.0.1:7447), then what a user does when a ground station
dies mid-flight: the vehicle's watchdog lets it fall, the emulator reports the crash, the next ground station
says so with the way out, and `--reset` reboots the vehicle and flies. Link counters are per session.
The killed session runs on its own endpoint from the module's start, beside the README session (both are
realtime flights: wall clock, not CPU).
"""

import json
import signal
import socket
import subprocess
import sys
import threading
import time
import uuid
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import pytest
from testsupport import cfstack, free_port

from link.transports.zenoh_session import DEFAULT_ENDPOINT

DEFAULT_PORT = int(DEFAULT_ENDPOINT.rsplit(":", 1)[1])
HOVER = ("--trajectory", "hover")


def _port_free(port: int) -> bool:
    with socket.socket() as s:
        try:
            s.bind(("127.0.0.1", port))
        except OSError:
            return False
    return True


class Emulator:
    """`cfstack emulator` with the given options (none: the README's defaults); its stderr lines collected as
    they come."""

    def __init__(self, *options: str):
        self.proc = subprocess.Popen([sys.executable, "-m", "cfstack", "emulator", *options],
                                     stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                                     text=True)
        self.lines: list[str] = []
        threading.Thread(target=self._read, daemon=True).start()

    def _read(self):
        for line in self.proc.stderr:
            self.lines.append(line.rstrip())

    def wait_for(self, text: str, timeout_s: float) -> str:
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            found = [line for line in self.lines if text in line]
            if found:
                return found[-1]
            time.sleep(0.1)
        raise AssertionError(f"no emulator line with {text!r} within {timeout_s} s: {self.lines[-5:]}")

    def stop(self) -> int:
        self.proc.send_signal(signal.SIGINT)
        try:
            return self.proc.wait(timeout=20)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            raise


@pytest.fixture(scope="module")
def emulator():
    if not _port_free(DEFAULT_PORT):
        pytest.skip(f"port {DEFAULT_PORT} (the default endpoint {DEFAULT_ENDPOINT}) is in use on this machine")
    emu = Emulator()
    emu.wait_for("emulator up", 30)
    yield emu
    assert emu.stop() == 0


def groundstation(log: Path, *extra: str) -> tuple[subprocess.CompletedProcess, dict | None]:
    run = cfstack("groundstation", *HOVER, "--json", "--log", str(log), *extra, timeout=120)
    return run, (json.loads(run.stdout) if run.stdout.strip() else None)


def test_the_readme_two_process_session_flies_with_the_defaults(emulator, tmp_path):
    run, summary = groundstation(tmp_path / "log")
    assert run.returncode == 0 and summary["result"] == "reached_goal", run.stderr
    assert "realtime clock" in emulator.wait_for("emulator up", 1)
    link = summary["link"]
    assert 0 < link["uplink_delivered"] <= link["uplink_sent"] and link["uplink_lost"] >= 0


def _last_phase(states: Path) -> str | None:
    """The phase column of the last whole row of a states.csv being written (None before the first row)."""
    lines = states.read_bytes()[-4000:].split(b"\n")[1:-1] if states.exists() else []
    return lines[-1].split(b",")[1].decode() if lines else None


def _killed_then_reset(folder: Path) -> dict:
    """A user's session on their own endpoint: a ground station killed while it flies, the crash the emulator
    reports, the next ground station's refusal, then `--reset`. What each step gave, for the test to judge."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    keys = ("--id", f"k{uuid.uuid4().hex[:8]}")  # its own keys: no other session's frames
    connect = ("--connect", endpoint, *keys)
    emu = Emulator("--listen", endpoint, *keys)
    try:
        emu.wait_for("emulator up", 30)
        first = subprocess.Popen([sys.executable, "-m", "cfstack", "groundstation", *HOVER, *connect,
                                  "--log", str(folder / "a")],
                                 stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        # killed once it tracks the hover point (1 m up, 5.9 s into the flight), not at the end of the hold
        states = folder / "a" / "states.csv"
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline and _last_phase(states) != "track":
            time.sleep(0.2)
        killed_in = _last_phase(states)
        first.send_signal(signal.SIGKILL)
        first.wait(timeout=10)
        # no more setpoints: the firmware's watchdog levels, then stops the motors, and the vehicle falls
        crash_line = emu.wait_for("crashed", 30)
        refused = groundstation(folder / "b", *connect)
        reset = groundstation(folder / "c", *connect, "--reset")
        return {"endpoint": endpoint, "killed_in": killed_in, "crash_line": crash_line, "refused": refused,
                "reset": reset, "emulator_lines": list(emu.lines)}
    finally:
        emu.stop()


@pytest.fixture(scope="module", autouse=True)
def killed_session(tmp_path_factory):
    """The killed-ground-station session, started with the module on its own emulator: it flies (in realtime,
    ~45 s of wall clock, a fraction of a core) while the README session flies on the default endpoint."""
    folder = tmp_path_factory.mktemp("killed")
    with ThreadPoolExecutor(1) as pool:
        yield pool.submit(_killed_then_reset, folder)


def test_a_killed_ground_station_then_a_reset_flies_again(killed_session):
    session = killed_session.result()
    assert session["killed_in"] == "track"
    assert "hit the floor" in session["crash_line"] and "--reset" in session["crash_line"]

    refused, summary = session["refused"]
    assert refused.returncode == 1 and summary["result"] == "crashed"
    message = refused.stderr.strip().splitlines()[-1]
    assert "already reports CRASHED" in message and "--reset" in message

    reset, summary = session["reset"]
    assert reset.returncode == 0 and summary["result"] == "reached_goal", reset.stderr
    assert summary["mission"]["vehicle_resets"] == 1
    assert len([line for line in session["emulator_lines"] if "reset by a ground station's REBOOT" in line]) == 1
    # the vehicle's uplink counters are this session's, not the emulator's lifetime totals
    link = summary["link"]
    assert 0 < link["uplink_delivered"] <= link["uplink_sent"] and link["uplink_lost"] >= 0


@pytest.fixture(scope="module", autouse=True)
def lonely_groundstation(tmp_path_factory):
    """A ground station pointed where nobody listens, started with the module: it waits out its connect
    timeout (10 s of wall clock, mostly asleep) while the other tests fly."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    log = tmp_path_factory.mktemp("lonely") / "log"
    with ThreadPoolExecutor(1) as pool:
        yield endpoint, pool.submit(groundstation, log, "--connect", endpoint)


def test_a_ground_station_with_nobody_to_talk_to_says_where_it_looked(lonely_groundstation):
    endpoint, future = lonely_groundstation
    run, summary = future.result()
    assert run.returncode == 1 and summary["result"] == "aborted"
    lines = [line for line in run.stderr.splitlines() if line.startswith("cfstack groundstation:")]
    assert len(lines) == 1 and "no heartbeat" in lines[0] and endpoint in lines[0] and "--connect" in lines[0]
