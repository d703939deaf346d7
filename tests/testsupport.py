"""What many tests share: where the course's world files are, and free loopback ports.

Takes in: nothing (the shared worlds are looked for at ../shared/worlds beside the checkout, where CI
puts them).
Gives out: SHARED_WORLDS, `shared_world(name)` (the file, or a visible skip saying why it is absent),
`shared_world_params(*patterns)` (pytest parameters over the matching files, or one skipped parameter
naming the missing folder, so the cases never vanish silently), `free_port(kind)` (the product's
link.transports.base.free_loopback_port), `cfstack(*args)` (the command as a user runs it: a
subprocess, output captured, no stdin, a timeout), `one_line_error(run)` (the refusal's single stderr line),
`wait_for_text(path, text, timeout_s)`, `processes_with(text)` (the command lines of this machine's processes,
other than pytest's, that contain it), and MAVProxy as the real GCS client: `MAVPROXY`, `needs_mavproxy`,
`mavproxy(master, folder)`.
Importable from every test module (pyproject.toml: pytest pythonpath = ["tests"]).
"""

from __future__ import annotations

import contextlib
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from link.transports.base import free_loopback_port as free_port  # noqa: F401 (one helper, re-exported)

SHARED_WORLDS = Path(__file__).resolve().parents[1].parent / "shared" / "worlds"
ABSENT_REASON = f"the course's world files are not at {SHARED_WORLDS} (../shared/worlds beside the checkout)"


def shared_worlds_present() -> bool:
    return SHARED_WORLDS.is_dir()


def shared_world(name: str) -> Path:
    """The path of ../shared/worlds/NAME.json; skips the calling test, saying why, when it is absent."""
    path = SHARED_WORLDS / f"{name}.json"
    if not path.is_file():
        pytest.skip(ABSENT_REASON if not shared_worlds_present() else f"{path} is missing")
    return path


def shared_world_params(*patterns: str) -> list:
    """pytest parameters: the stems of the shared world files matching the glob patterns, in order; one
    skipped parameter with the reason when the folder is absent."""
    if not shared_worlds_present():
        return [pytest.param("absent", marks=pytest.mark.skip(reason=ABSENT_REASON), id="shared-worlds-absent")]
    stems: list[str] = []
    for pattern in patterns:
        stems += sorted(p.stem for p in SHARED_WORLDS.glob(pattern) if p.stem not in stems)
    return stems


def cfstack(*args: str, timeout: float = 240, **kw) -> subprocess.CompletedProcess:
    """`python -m cfstack ARGS` as a user runs it; stdout and stderr captured as text."""
    return subprocess.run([sys.executable, "-m", "cfstack", *args], capture_output=True, text=True,
                          timeout=timeout, stdin=subprocess.DEVNULL, **kw)


def one_line_error(run: subprocess.CompletedProcess) -> str:
    """The one stderr line of a command that refused (exit 2, the usage-error code); asserts both."""
    assert run.returncode == 2, (run.returncode, run.stderr)
    lines = run.stderr.strip().splitlines()
    assert len(lines) == 1, run.stderr
    return lines[0]


def wait_for_text(path: Path, text: str, timeout_s: float) -> bool:
    """True once `text` appears in the file at `path` (polled), False after timeout_s."""
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        if path.exists() and text in path.read_text(errors="replace"):
            return True
        time.sleep(0.1)
    return False


def processes_with(text: str) -> list[str]:
    """The command lines (arguments joined by spaces) of the running processes that contain `text`,
    pytest's own left out."""
    found = []
    for pid in os.listdir("/proc"):
        if pid.isdigit():
            try:
                cmdline = Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode()
            except OSError:  # the process ended while we looked
                continue
            if text in cmdline and "pytest" not in cmdline:
                found.append(cmdline)
    return found


MAVPROXY = shutil.which("mavproxy.py")
needs_mavproxy = pytest.mark.skipif(MAVPROXY is None, reason="MAVProxy is not installed (pip install --no-deps "
                                                             "mavproxy; .ci/run installs it)")


@contextlib.contextmanager
def mavproxy(master: str, folder: Path):
    """MAVProxy as a user starts it headless (`--master=MASTER --daemon --non-interactive`); yields the file of its
    output (folder/mavproxy.out; its tlog is folder/mav.tlog); on leaving, Ctrl-C, then a kill if it lingers."""
    out = folder / "mavproxy.out"
    with out.open("w") as sink:
        proxy = subprocess.Popen([MAVPROXY, f"--master={master}", "--daemon", "--non-interactive",
                                  f"--state-basedir={folder}", f"--logfile={folder / 'mav.tlog'}"],
                                 cwd=folder, stdout=sink, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL)
    try:
        yield out
    finally:
        proxy.send_signal(signal.SIGINT)
        try:
            proxy.wait(timeout=10)
        except subprocess.TimeoutExpired:
            proxy.kill()
            proxy.wait()
