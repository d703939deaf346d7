"""The private endpoint `cfstack fly` puts its emulator child on (link.transports.zenoh_session.PrivateEndpoint):
a Unix socket in a fresh folder of its own where the system has them and the path fits, else a free loopback TCP
port; the folder is gone once `cfstack fly` returns, a refused flight included. (That frames cross it whole, in
lockstep and realtime, is tests/link/test_zenoh_process.py's.)"""

from __future__ import annotations

import os
import socket
import stat
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pytest

from link.transports import zenoh_session
from link.transports.zenoh_session import UNIX_SOCKET_NAME, UNIX_SOCKET_PATH_MAX_BYTES, PrivateEndpoint

HAS_UNIX_SOCKETS = hasattr(socket, "AF_UNIX") and sys.platform != "win32"
unix_only = pytest.mark.skipif(not HAS_UNIX_SOCKETS, reason="this system has no Unix sockets")


@unix_only
def test_it_is_a_unix_socket_in_a_folder_only_we_may_enter(tmp_path, monkeypatch):
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    first, second = PrivateEndpoint(), PrivateEndpoint()
    try:
        for private in (first, second):
            folder = Path(private.folder)
            assert private.endpoint == f"unixsock-stream/{folder / UNIX_SOCKET_NAME}"
            assert folder.parent == tmp_path and folder.is_dir()
            assert stat.S_IMODE(folder.stat().st_mode) == 0o700
        assert first.endpoint != second.endpoint  # two flights at once never share one
    finally:
        first.close()
        second.close()
    assert list(tmp_path.iterdir()) == []
    first.close()  # again: nothing left to do


@unix_only
def test_a_path_too_long_for_a_unix_socket_falls_back_to_tcp_and_leaves_nothing(tmp_path, monkeypatch):
    deep = tmp_path / ("d" * (UNIX_SOCKET_PATH_MAX_BYTES - len(str(tmp_path))))
    deep.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(deep))
    private = PrivateEndpoint()
    assert private.folder is None
    host, port = private.endpoint.removeprefix("tcp/").rsplit(":", 1)
    assert host == "127.0.0.1" and 0 < int(port) < 65536
    assert list(deep.iterdir()) == []
    private.close()


def test_without_unix_sockets_it_is_a_loopback_tcp_port(monkeypatch):
    monkeypatch.setattr(zenoh_session.sys, "platform", "win32")
    private = PrivateEndpoint()
    assert private.folder is None and private.endpoint.startswith("tcp/127.0.0.1:")


def _fly(tmp_path: Path, *args: str) -> tuple[subprocess.Popen, Path]:
    temp = tmp_path / "tmp"
    temp.mkdir()
    env = dict(os.environ, TMPDIR=str(temp))
    fly = subprocess.Popen([sys.executable, "-m", "cfstack", "fly", *args, "--log", str(tmp_path / "log")],
                           stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, env=env)
    return fly, temp


def _sockets(folder: Path) -> list[Path]:
    return [p for p in folder.glob(f"cfstack-*/{UNIX_SOCKET_NAME}") if stat.S_ISSOCK(p.stat().st_mode)]


@unix_only
def test_fly_meets_its_emulator_on_a_unix_socket_and_removes_it(tmp_path):
    """In lockstep (a realtime flight starts its child the same way, EmulatorChild, and takes 30 s)."""
    fly, temp = _fly(tmp_path, "--trajectory", "hover", "--clock", "lockstep")
    try:
        deadline = time.monotonic() + 60.0
        while not _sockets(temp) and fly.poll() is None and time.monotonic() < deadline:
            time.sleep(0.02)
        listening = _sockets(temp)
        _, err = fly.communicate(timeout=300)
    finally:
        if fly.poll() is None:
            fly.kill()
            fly.wait()
    assert fly.returncode == 0, err
    assert len(listening) == 1  # the emulator child listened there while it flew
    assert list(temp.iterdir()) == []  # and the folder went with it


@unix_only
def test_a_fly_refused_before_its_emulator_starts_leaves_no_folder(tmp_path):
    fly, temp = _fly(tmp_path, "--trajectory", "hover", "--link", "crtp", "--uri", "radio://0/80/2M")
    _, err = fly.communicate(timeout=120)
    assert fly.returncode == 2
    assert "argument --uri" in err.strip().splitlines()[-1]
    assert list(temp.iterdir()) == []
