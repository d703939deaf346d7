"""The private endpoint `cfstack fly` puts its emulator child on (link.transports.zenoh_session.PrivateEndpoint):
a Unix socket in a fresh folder of its own where the system has them and the path fits, else a free loopback TCP
port, and `close()` removes the folder; a folder a killed process left is removed by the next endpoint, also once a
later process has its id, and only such a folder. (That frames cross it whole, in lockstep and realtime, is
tests/link/test_zenoh_process.py's; that `fly` uses it, tests/groundstation/test_emulator_child.py's.)"""

from __future__ import annotations

import os
import stat
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pytest

from link.transports import zenoh_session
from link.transports.zenoh_session import (
    HAS_UNIX_SOCKETS,
    OWNER_FILE,
    UNIX_SOCKET_NAME,
    UNIX_SOCKET_PATH_MAX_BYTES,
    PrivateEndpoint,
    remove_stale_folders,
)

unix_only = pytest.mark.skipif(not HAS_UNIX_SOCKETS, reason="this system has no Unix sockets")
has_proc = pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="no /proc to read processes' states from")


def _proc_stat_fields(pid: int) -> list[bytes]:
    """/proc/PID/stat's fields, numbered as proc(5) numbers them from 1 (index 0 unused); read here, not through
    the code under test."""
    name_end = (raw := Path(f"/proc/{pid}/stat").read_bytes()).rindex(b")")
    return [b"", *raw[:name_end].split(b" (", 1), *raw[name_end + 1:].split()]


@unix_only
def test_it_is_a_unix_socket_in_a_folder_only_we_may_enter(short_tempdir):
    first, second = PrivateEndpoint(), PrivateEndpoint()
    try:
        for private in (first, second):
            folder = Path(private.folder)
            assert private.endpoint == f"unixsock-stream/{folder / UNIX_SOCKET_NAME}"
            assert folder.parent == short_tempdir and folder.is_dir()
            assert stat.S_IMODE(folder.stat().st_mode) == 0o700
        assert first.endpoint != second.endpoint  # two flights at once never share one
    finally:
        first.close()
        second.close()
    assert list(short_tempdir.iterdir()) == []
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


def _dead_pid() -> int:
    """The id of a process that has ended (and been reaped): no process has it now, short of reuse."""
    child = subprocess.Popen([sys.executable, "-c", "pass"])
    child.wait()
    return child.pid


@unix_only
def test_a_folder_left_by_a_killed_process_is_removed_by_the_next_endpoint(short_tempdir):
    dead = _dead_pid()
    left = short_tempdir / f"cfstack-{dead}-abc123"  # as a fly and its child killed with SIGKILL leave it
    left.mkdir()
    (left / UNIX_SOCKET_NAME).touch()
    (left / f"{UNIX_SOCKET_NAME}.lock").touch()  # zenoh's listener's lock file
    (left / OWNER_FILE).write_bytes(b"6480868")  # the killed process's start time
    empty = short_tempdir / f"cfstack-{dead}-def456"  # killed before its child listened
    empty.mkdir()
    private = PrivateEndpoint()
    try:
        assert not left.exists() and not empty.exists()
        assert sorted(short_tempdir.iterdir()) == [Path(private.folder)]
        assert Path(private.folder).name.startswith(f"cfstack-{os.getpid()}-")
    finally:
        private.close()


@unix_only
def test_only_stale_endpoint_folders_are_removed(tmp_path):
    dead = _dead_pid()
    live = tmp_path / f"cfstack-{os.getpid()}-live01"  # a flight of a running process: in use
    live.mkdir()
    (live / UNIX_SOCKET_NAME).touch()
    other_files = tmp_path / f"cfstack-{dead}-other1"  # not only a socket: not ours to judge
    other_files.mkdir()
    (other_files / "notes.txt").write_text("keep")
    not_ours = tmp_path / f"cfstack-{dead}"  # not the endpoint's name pattern (no random part)
    not_ours.mkdir()
    plain_file = tmp_path / f"cfstack-{dead}-file01"  # a file, not a folder
    plain_file.write_text("keep")
    stale = tmp_path / f"cfstack-{dead}-stale1"
    stale.mkdir()
    assert remove_stale_folders(str(tmp_path)) == [str(stale)]
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(
        p.name for p in (live, other_files, not_ours, plain_file))
    assert remove_stale_folders(str(tmp_path / "missing")) == []  # no such parent: nothing, no error


@unix_only
@has_proc
def test_the_folder_of_a_process_that_ended_but_is_not_reaped_yet_is_removed(tmp_path):
    child = subprocess.Popen([sys.executable, "-c", "pass"])  # not waited for: a zombie once it ends
    try:
        deadline = time.monotonic() + 30.0
        while _proc_stat_fields(child.pid)[3] != b"Z":  # field 3: the state
            assert time.monotonic() < deadline, "the child never ended"
            time.sleep(0.01)
        left = tmp_path / f"cfstack-{child.pid}-zombie"
        left.mkdir()
        (left / UNIX_SOCKET_NAME).touch()
        assert remove_stale_folders(str(tmp_path)) == [str(left)]
    finally:
        child.wait()


@unix_only
@has_proc
def test_the_folder_records_its_creators_start_time_beside_the_socket(short_tempdir):
    private = PrivateEndpoint()
    try:
        folder = Path(private.folder)
        assert folder.name.startswith(f"cfstack-{os.getpid()}-")
        # proc(5) field 22: this process's start time, in clock ticks since boot
        assert (folder / OWNER_FILE).read_bytes() == _proc_stat_fields(os.getpid())[22]
        assert [p.name for p in folder.iterdir()] == [OWNER_FILE]  # the socket comes when the emulator listens
    finally:
        private.close()
    assert list(short_tempdir.iterdir()) == []


@unix_only
@has_proc
def test_a_folder_whose_process_id_a_later_process_got_is_removed_and_its_creators_is_kept(tmp_path):
    started = _proc_stat_fields(os.getpid())[22]
    earlier = str(int(started) - 1).encode()  # a process started a tick earlier had this id, and was killed
    reused = tmp_path / f"cfstack-{os.getpid()}-reused"
    reused.mkdir()
    (reused / UNIX_SOCKET_NAME).touch()
    (reused / f"{UNIX_SOCKET_NAME}.lock").touch()
    (reused / OWNER_FILE).write_bytes(earlier)
    ours = tmp_path / f"cfstack-{os.getpid()}-ours01"  # this process's own: in use
    ours.mkdir()
    (ours / UNIX_SOCKET_NAME).touch()
    (ours / OWNER_FILE).write_bytes(started)
    unwritten = tmp_path / f"cfstack-{os.getpid()}-unwrit"  # its creator has not written the start time yet
    unwritten.mkdir()
    (unwritten / OWNER_FILE).touch()
    assert remove_stale_folders(str(tmp_path)) == [str(reused)]
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(p.name for p in (ours, unwritten))
