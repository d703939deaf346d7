"""The private endpoint `cfstack fly` puts its emulator child on (link.transports.zenoh_session.PrivateEndpoint):
a Unix socket in a fresh folder of its own where the system has them and the path fits, else a free loopback TCP
port, and `close()` removes the folder. (That frames cross it whole, in lockstep and realtime, is
tests/link/test_zenoh_process.py's; that `fly` uses it, tests/groundstation/test_emulator_child.py's.)"""

from __future__ import annotations

import stat
import tempfile
from pathlib import Path

import pytest

from link.transports import zenoh_session
from link.transports.zenoh_session import (
    HAS_UNIX_SOCKETS,
    UNIX_SOCKET_NAME,
    UNIX_SOCKET_PATH_MAX_BYTES,
    PrivateEndpoint,
)

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
    monkeypatch.setattr(zenoh_session, "HAS_UNIX_SOCKETS", False)
    private = PrivateEndpoint()
    assert private.folder is None and private.endpoint.startswith("tcp/127.0.0.1:")
