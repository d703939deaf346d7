"""zenoh's own threads run in the background (link.transports.zenoh_process: SCHED_BATCH, niceness 19) where a
process asks for it (lockstep) or CFSTACK_ZENOH_THREADS says so, and ours never do. Each case is a fresh process
(zenoh starts its threads once per process): two sessions, one listening and one connecting, exchange a frame,
so zenoh has started its link's transmit and receive threads too; then the test reads every thread's policy and
niceness off /proc (_threads_of). Then which way `cfstack fly` goes, in each clock, read the same way.
The same choice makes a lockstep process's sessions offer zenoh's low-latency transport: frames cross between
processes whichever end offers it, and a sample longer than it sends whole is refused in one line."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from link.transports import open_transport, zenoh_process
from link.transports.zenoh_process import BACKGROUND_NICE, THREADS_ENV, TRANSPORT_ENV, to_background
from link.transports.zenoh_session import LOW_LATENCY_MAX_SAMPLE_BYTES, PrivateEndpoint, ZenohSettings
from model.errors import UserError

REPO = Path(__file__).resolve().parents[2]
ZENOH_RUNTIMES = ("app", "net", "acc", "tx", "rx")  # zenoh's runtimes name their threads NAME-N

pytestmark = pytest.mark.skipif(not hasattr(os, "SCHED_BATCH") or not Path("/proc/self/task").is_dir(),
                                reason="SCHED_BATCH and /proc are Linux's")

PROBE = r"""
import json, sys, time
from link.transports import open_transport
from link.transports.zenoh_process import use_lockstep_settings
port = int(sys.argv[1])
if sys.argv[2] != "default":
    use_lockstep_settings(sys.argv[2] == "background")
listener = open_transport("zenoh", rx="test/threads", listen=[f"tcp/127.0.0.1:{port}"])
talker = open_transport("zenoh", tx="test/threads", connect=[f"tcp/127.0.0.1:{port}"])
talker.wait_for_subscribers(10.0)
talker.send(b"frame")
deadline = time.monotonic() + 10.0
frames = []
while not frames and time.monotonic() < deadline:
    frames = listener.receive(0.1)
print(json.dumps([f.decode() for f in frames]), flush=True)
sys.stdin.read()  # the test reads our threads meanwhile; it closes our stdin when done
"""


def run_probe(free_tcp_port, asked: str = "background", env_value: str | None = None,
              prefix: tuple[str, ...] = ()) -> list[dict]:
    """The probe's threads once its link is up. asked: what the process asks for (use_lockstep_settings:
    "background" for lockstep, "normal" for realtime), or "default" (it does not ask)."""
    env = dict(os.environ, PYTHONPATH=str(REPO))
    env.pop(THREADS_ENV, None)
    if env_value is not None:
        env[THREADS_ENV] = env_value
    probe = subprocess.Popen([*prefix, sys.executable, "-c", PROBE, str(free_tcp_port()), asked],
                             stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
    try:
        frames = probe.stdout.readline()
        threads = _threads_of(probe.pid)
    finally:
        _, err = probe.communicate(timeout=60)  # closes its stdin: it exits
    assert probe.returncode == 0, err
    assert json.loads(frames) == ["frame"]  # the link was up: its transmit and receive threads exist
    return threads


def zenoh_threads(threads: list[dict]) -> list[dict]:
    found = [t for t in threads if not t["python"] and t["name"].split("-")[0] in ZENOH_RUNTIMES]
    assert {t["name"].split("-")[0] for t in found} >= {"tx", "rx", "net"}, threads
    return found


def background(thread: dict) -> bool:
    if (thread["policy"], thread["nice"]) == (os.SCHED_BATCH, BACKGROUND_NICE):
        return True
    assert (thread["policy"], thread["nice"]) == (os.SCHED_OTHER, 0), thread  # neither: half done
    return False


def test_asked_for_zenohs_threads_run_in_the_background_and_ours_do_not(free_tcp_port):
    threads = run_probe(free_tcp_port)
    assert all(background(t) for t in zenoh_threads(threads))
    python = [t for t in threads if t["python"]]
    assert python and not any(background(t) for t in python)


@pytest.mark.parametrize(("asked", "env_value", "expected"), [
    ("default", None, False),  # zenoh's own way unless asked
    ("background", "normal", False),  # the environment overrides the process
    ("normal", "background", True),
    ("default", "background", True),
])
def test_the_environment_overrides_what_the_process_asks(free_tcp_port, asked, env_value, expected):
    zenoh = zenoh_threads(run_probe(free_tcp_port, asked, env_value))
    assert [background(t) for t in zenoh] == [expected] * len(zenoh)


def test_a_niced_process_keeps_its_niceness_and_zenoh_still_goes_below_it(free_tcp_port):
    threads = run_probe(free_tcp_port, prefix=("nice", "-n", "5"))
    assert all(t["nice"] == 5 for t in threads if t["python"])
    assert all(t["nice"] == BACKGROUND_NICE for t in zenoh_threads(threads))


def test_an_unknown_setting_is_one_line_naming_the_variable(tmp_path):
    env = dict(os.environ, **{THREADS_ENV: "fast"})
    done = subprocess.run([sys.executable, "-m", "cfstack", "fly", "--trajectory", "hover", "--log", str(tmp_path)],
                          capture_output=True, text=True, env=env, timeout=60)
    assert done.returncode == 2
    lines = done.stderr.strip().splitlines()
    assert lines == [f"cfstack fly: {THREADS_ENV}='fast': must be one of background, normal"], done.stderr


def test_a_refused_policy_is_one_warning_and_the_thread_stays_as_it_was(monkeypatch, caplog):
    def refuse(*_):
        raise PermissionError(1, "Operation not permitted")

    tid = threading.get_native_id()
    before = os.sched_getscheduler(tid), os.getpriority(os.PRIO_PROCESS, tid)
    monkeypatch.setattr(os, "sched_setscheduler", refuse)
    monkeypatch.setattr(os, "setpriority", refuse)
    to_background(tid)
    assert (os.sched_getscheduler(tid), os.getpriority(os.PRIO_PROCESS, tid)) == before
    assert [r.getMessage() for r in caplog.records] == [
        "could not put zenoh's threads in the background (Operation not permitted): they run as the process does; "
        f"{THREADS_ENV}=normal skips the attempt"]


def _threads_of(pid: int) -> list[dict]:
    """pid's threads: name, policy, niceness; a Python thread is named after the program, zenoh's are not."""
    threads = []
    for tid in map(int, os.listdir(f"/proc/{pid}/task")):
        try:
            name = Path(f"/proc/{pid}/task/{tid}/comm").read_text().strip()
            threads.append({"name": name, "python": name.startswith("python"),
                            "policy": os.sched_getscheduler(tid), "nice": os.getpriority(os.PRIO_PROCESS, tid)})
        except (FileNotFoundError, ProcessLookupError):
            pass  # a thread that ended meanwhile
    return threads


def _linked_threads(pid: int, timeout_s: float = 60.0) -> list[dict]:
    """pid's threads once zenoh runs its link (transmit and receive threads up)."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        threads = _threads_of(pid)
        if {t["name"].split("-")[0] for t in threads} >= {"tx", "rx"}:
            return threads
        time.sleep(0.05)
    raise AssertionError(f"process {pid}: no zenoh link threads within {timeout_s} s")


@pytest.mark.parametrize(("clock", "expected"), [("lockstep", True), ("realtime", False)])
def test_fly_puts_zenohs_threads_in_the_background_in_lockstep_only(tmp_path, clock, expected):
    env = dict(os.environ)
    env.pop(THREADS_ENV, None)
    fly = subprocess.Popen([sys.executable, "-m", "cfstack", "fly", "--trajectory", "hover", "--clock", clock,
                            "--log", str(tmp_path)], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=env)
    try:
        ground = _linked_threads(fly.pid)
        children = Path(f"/proc/{fly.pid}/task/{fly.pid}/children").read_text().split()
        assert children, "fly's emulator child is gone"  # the ground station's link is up: so is its emulator
        emulator = _linked_threads(int(children[0]))
    finally:
        fly.kill()
        fly.wait(timeout=30)
    for threads in (ground, emulator):
        zenoh = zenoh_threads(threads)
        assert [background(t) for t in zenoh] == [expected] * len(zenoh)
        assert not any(background(t) for t in threads if t["python"])


# --- the transport a session offers ---------------------------------------------------------------------


def _offered(monkeypatch, lockstep: bool, env_value: str | None = None, **settings) -> tuple[str, str]:
    """(transport/unicast/lowlatency, transport/unicast/qos/enabled) of the config a session would open with."""
    monkeypatch.setattr(zenoh_process, "_lockstep", lockstep)
    if env_value is None:
        monkeypatch.delenv(TRANSPORT_ENV, raising=False)
    else:
        monkeypatch.setenv(TRANSPORT_ENV, env_value)
    config = ZenohSettings(**settings).to_config()
    return config.get_json("transport/unicast/lowlatency"), config.get_json("transport/unicast/qos/enabled")


@pytest.mark.parametrize(("lockstep", "env_value", "offered"), [
    (True, None, ("true", "false")),  # lockstep: low latency, QoS off as zenoh requires for it
    (False, None, ("false", "true")),  # realtime: zenoh's defaults
    (True, "universal", ("false", "true")),  # the environment overrides the process
    (False, "lowlatency", ("true", "false")),
])
def test_a_lockstep_process_offers_the_low_latency_transport(monkeypatch, lockstep, env_value, offered):
    assert _offered(monkeypatch, lockstep, env_value) == offered


def test_a_config_file_decides_the_transport_alone(monkeypatch, tmp_path):
    config_file = tmp_path / "zenoh.json5"
    config_file.write_text("{ mode: 'peer' }")
    assert _offered(monkeypatch, True, config_file=str(config_file)) == ("false", "true")


def test_an_unknown_transport_setting_is_one_line_naming_the_variable(tmp_path):
    env = dict(os.environ, **{TRANSPORT_ENV: "fast"})
    done = subprocess.run([sys.executable, "-m", "cfstack", "fly", "--trajectory", "hover", "--log", str(tmp_path)],
                          capture_output=True, text=True, env=env, timeout=60)
    assert done.returncode == 2
    assert done.stderr.strip().splitlines() == [
        f"cfstack fly: {TRANSPORT_ENV}='fast': must be one of lowlatency, universal"], done.stderr


ECHO = r"""
import sys
from link.transports import open_transport
from link.transports.zenoh_process import use_lockstep_settings
endpoint, lockstep = sys.argv[1], sys.argv[2] == "lockstep"
use_lockstep_settings(lockstep)
echo = open_transport("zenoh", tx="test/back", rx="test/out", listen=[endpoint])
print("ready", flush=True)
while True:
    for frame in echo.receive(1.0):
        if frame == b"stop":
            sys.exit(0)
        echo.send(frame)
"""


CALLER = r"""
import json, sys
from link.transports import open_transport
from link.transports.zenoh_process import use_lockstep_settings
endpoint, lockstep, sizes = sys.argv[1], sys.argv[2] == "lockstep", json.loads(sys.argv[3])
use_lockstep_settings(lockstep)
caller = open_transport("zenoh", tx="test/out", rx="test/back", connect=[endpoint])
caller.wait_for_subscribers(20.0)
back = []
for size in sizes:
    frame = bytes([size % 251]) * size
    caller.send(frame)
    back += [len(f) for f in caller.receive(10.0) if f == frame]
caller.send(b"stop")
print(json.dumps(back))
"""


def _echo_sizes(endpoint: str, echo_lockstep: bool, caller_lockstep: bool, sizes: list[int]) -> list[int]:
    """Frames of these sizes sent to an echo in another process (listening on endpoint) and back; the sizes
    that came back whole."""
    env = dict(os.environ, PYTHONPATH=str(REPO))
    clock = {True: "lockstep", False: "realtime"}
    echo = subprocess.Popen([sys.executable, "-c", ECHO, endpoint, clock[echo_lockstep]],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
    try:
        assert echo.stdout.readline().strip() == "ready"
        caller = subprocess.run([sys.executable, "-c", CALLER, endpoint, clock[caller_lockstep], json.dumps(sizes)],
                                capture_output=True, text=True, timeout=120, env=env)
        assert caller.returncode == 0, caller.stderr
        return json.loads(caller.stdout.strip().splitlines()[-1])
    finally:
        echo.kill()
        echo.wait(timeout=30)


@pytest.mark.parametrize(("echo_lockstep", "caller_lockstep"), [(True, True), (True, False), (False, True)])
def test_frames_cross_between_processes_whichever_end_offers_low_latency(free_tcp_port, echo_lockstep,
                                                                        caller_lockstep):
    sizes = [60, 8192, LOW_LATENCY_MAX_SAMPLE_BYTES]  # a command, a packed tick, the longest sample allowed
    assert _echo_sizes(f"tcp/127.0.0.1:{free_tcp_port()}", echo_lockstep, caller_lockstep, sizes) == sizes


@pytest.mark.parametrize("lockstep", [True, False])
def test_frames_cross_between_processes_on_a_private_endpoint(lockstep):
    """`cfstack fly`'s endpoint between its ground station and emulator child (a Unix socket here)."""
    private = PrivateEndpoint()
    try:
        assert private.endpoint.startswith("unixsock-stream/")  # Linux has them (this module's skip)
        sizes = [60, 8192, LOW_LATENCY_MAX_SAMPLE_BYTES]
        assert _echo_sizes(private.endpoint, lockstep, lockstep, sizes) == sizes
    finally:
        private.close()


def test_a_low_latency_session_refuses_a_sample_it_would_lose_in_one_line(monkeypatch, free_tcp_port):
    monkeypatch.setattr(zenoh_process, "_lockstep", True)
    monkeypatch.delenv(TRANSPORT_ENV, raising=False)
    port = free_tcp_port()
    with open_transport("zenoh", tx="test/long", listen=[f"tcp/127.0.0.1:{port}"]) as transport:
        with pytest.raises(UserError) as refused:
            transport.send(b"x" * (LOW_LATENCY_MAX_SAMPLE_BYTES + 1))
    assert str(refused.value) == (f"zenoh key test/long: a {LOW_LATENCY_MAX_SAMPLE_BYTES + 1} B sample is longer "
                                  f"than the {LOW_LATENCY_MAX_SAMPLE_BYTES} B a low-latency zenoh session sends "
                                  "whole (CFSTACK_ZENOH_TRANSPORT=universal lifts it)")


def test_the_refusal_names_the_config_file_that_chose_low_latency(monkeypatch, free_tcp_port, tmp_path):
    """A --config file decides the transport alone, so the environment variable would not lift the limit."""
    monkeypatch.setattr(zenoh_process, "_lockstep", True)
    monkeypatch.setenv(TRANSPORT_ENV, "universal")  # ignored: the file decides
    config_file = tmp_path / "zenoh.json5"
    config_file.write_text("{ transport: { unicast: { lowlatency: true, qos: { enabled: false } } } }")
    port = free_tcp_port()
    with open_transport("zenoh", tx="test/long", listen=[f"tcp/127.0.0.1:{port}"],
                        config_file=str(config_file)) as transport:
        transport.send(b"x" * LOW_LATENCY_MAX_SAMPLE_BYTES)  # the longest it sends whole
        with pytest.raises(UserError) as refused:
            transport.send(b"x" * (LOW_LATENCY_MAX_SAMPLE_BYTES + 1))
    assert str(refused.value) == (f"zenoh key test/long: a {LOW_LATENCY_MAX_SAMPLE_BYTES + 1} B sample is longer "
                                  f"than the {LOW_LATENCY_MAX_SAMPLE_BYTES} B a low-latency zenoh session sends "
                                  f"whole ({config_file} turns on transport/unicast/lowlatency; false there lifts it)")
