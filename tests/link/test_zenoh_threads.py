"""zenoh's own threads run in the background (link.transports.zenoh_threads: SCHED_BATCH, niceness 19) where a
process asks for it (lockstep) or CFSTACK_ZENOH_THREADS says so, and ours never do. Each case is a fresh process
(zenoh starts its threads once per process): two sessions, one listening and one connecting, exchange a frame,
so zenoh has started its link's transmit and receive threads too; then the test reads every thread's policy and
niceness off /proc (_threads_of). Then which way `cfstack fly` goes, in each clock, read the same way."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from link.transports.zenoh_threads import BACKGROUND_NICE, to_background
from link.transports.zenoh_threads import ENV as ZENOH_THREADS_ENV

REPO = Path(__file__).resolve().parents[2]
ZENOH_RUNTIMES = ("app", "net", "acc", "tx", "rx")  # zenoh's runtimes name their threads NAME-N

pytestmark = pytest.mark.skipif(not hasattr(os, "SCHED_BATCH") or not Path("/proc/self/task").is_dir(),
                                reason="SCHED_BATCH and /proc are Linux's")

PROBE = r"""
import json, sys, time
from link.transports import open_transport
from link.transports.zenoh_threads import use_background_threads
port = int(sys.argv[1])
if sys.argv[2] != "default":
    use_background_threads(sys.argv[2] == "background")
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
    """The probe's threads once its link is up. asked: what the process asks for (use_background_threads), or
    "default" (it does not ask)."""
    env = dict(os.environ, PYTHONPATH=str(REPO))
    env.pop(ZENOH_THREADS_ENV, None)
    if env_value is not None:
        env[ZENOH_THREADS_ENV] = env_value
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
    env = dict(os.environ, **{ZENOH_THREADS_ENV: "fast"})
    done = subprocess.run([sys.executable, "-m", "cfstack", "fly", "--trajectory", "hover", "--log", str(tmp_path)],
                          capture_output=True, text=True, env=env, timeout=60)
    assert done.returncode == 2
    lines = done.stderr.strip().splitlines()
    assert lines == [f"cfstack fly: {ZENOH_THREADS_ENV}='fast': must be one of background, normal"], done.stderr


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
        f"{ZENOH_THREADS_ENV}=normal skips the attempt"]


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
    env.pop(ZENOH_THREADS_ENV, None)
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
