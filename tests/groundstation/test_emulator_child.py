"""`cfstack fly`'s emulator child on its private endpoint (link.transports.zenoh_session.PrivateEndpoint): it
listens on a Unix socket in a folder of its own, the folder goes when the child is stopped, and a flight refused
before its child starts leaves none."""

from __future__ import annotations

import os
import stat
import subprocess
import sys
import time
from pathlib import Path

import pytest

from groundstation import cli
from link.transports.zenoh_session import HAS_UNIX_SOCKETS, UNIX_SOCKET_NAME

unix_only = pytest.mark.skipif(not HAS_UNIX_SOCKETS, reason="this system has no Unix sockets")


def _sockets(folder: Path) -> list[Path]:
    return [p for p in folder.glob(f"cfstack-*/{UNIX_SOCKET_NAME}") if stat.S_ISSOCK(p.stat().st_mode)]


@unix_only
def test_fly_meets_its_emulator_on_a_unix_socket_and_removes_it(short_tempdir):
    """fly's emulator child (groundstation.cli.emulator_child, which `fly` and `step` start in either clock)
    listens on a Unix socket in its own folder, and the folder goes when the child is stopped."""
    args = cli._parsed(cli.fly_parser(), ["--trajectory", "hover"])
    with cli.emulator_child(args, None, False, {}) as child:
        deadline = time.monotonic() + 60.0
        while not _sockets(short_tempdir) and child.failure() is None and time.monotonic() < deadline:
            time.sleep(0.02)
        listening = _sockets(short_tempdir)
        assert child.failure() is None
    assert [f"unixsock-stream/{path}" for path in listening] == [child.endpoint]  # the child listened there
    assert list(short_tempdir.iterdir()) == []  # and the folder went with it


@unix_only
def test_a_fly_refused_before_its_emulator_starts_leaves_no_folder(tmp_path):
    temp = tmp_path / "tmp"
    temp.mkdir()
    fly = subprocess.run([sys.executable, "-m", "cfstack", "fly", "--trajectory", "hover", "--link", "crtp",
                          "--uri", "radio://0/80/2M", "--log", str(tmp_path / "log")],
                         capture_output=True, text=True, env=dict(os.environ, TMPDIR=str(temp)), timeout=120)
    assert fly.returncode == 2
    assert "argument --uri" in fly.stderr.strip().splitlines()[-1]
    assert list(temp.iterdir()) == []
