"""Zenoh sessions of this process: settings, one shared session per settings, the common CLI flags.

Takes in: session options (`mode`, `connect`, `listen`, `scouting`, `config_file`), from code or from
the flags `add_zenoh_arguments` adds to a command (`--mode`, `--connect`, `--listen`, `--config`,
`--scouting`).
Gives out: an opened zenoh.Session shared (reference-counted) by every user asking for the same
settings, closed when the last user releases it (or at interpreter exit); ZenohSettings; PrivateEndpoint (where
`cfstack fly` meets its emulator child); a
`python -m link.transports.zenoh_session --mode router --listen tcp/127.0.0.1:7447` router for tests and labs.

Defaults (our choice, not zenoh's): peer mode, multicast scouting OFF, so a process only talks to the
endpoints it is given; a connect that found nobody listening is retried after 20 ms, doubling
(CONNECT_RETRY). A config file (JSON5, zenoh's own format) is loaded first; any option given
explicitly overrides the file's value. The unicast transport offered, zenoh's universal one or its
low-latency one (LOW_LATENCY_CONFIG), is link.transports.zenoh_process's choice (the low-latency one in a
lockstep process; why, with the measurements, there); a config file decides it alone. The low-latency transport
has no fragmentation: a sample longer than the link's batch is lost with the link (on
loopback TCP, 48000 B arrived and 50000 B broke the link, silently: a throwaway script, zenoh 1.10.2), so a
low-latency session's transports refuse samples over LOW_LATENCY_MAX_SAMPLE_BYTES (ours are at most 8192 B).
zenoh's own threads run as link.transports.zenoh_process says (in the background in a lockstep process).
"""

from __future__ import annotations

import argparse
import atexit
import json
import os
import re
import shutil
import signal
import socket
import sys
import tempfile
import threading
from collections.abc import Iterable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import zenoh

from link.transports import zenoh_process
from link.transports.base import free_loopback_port
from model.errors import UserError

DEFAULT_MODE = "peer"
MODES = ("peer", "client", "router")
SESSION_OPTIONS = ("mode", "connect", "listen", "scouting", "config_file")
# A zenoh endpoint is PROTOCOL/ADDRESS[?metadata][#config], e.g. tcp/127.0.0.1:7447, udp/[::1]:7447.
ENDPOINT_PATTERN = re.compile(r"^[a-z][a-z0-9-]*/\S+$")
ENDPOINT_EXAMPLE = "tcp/127.0.0.1:7447"
# Where `cfstack emulator` listens and `cfstack groundstation` connects when given neither --connect nor
# --listen, so the two commands meet on one machine as written (zenoh's own default port, 7447).
DEFAULT_ENDPOINT = "tcp/127.0.0.1:7447"
# Connect retries (our default unless a config file is given): zenoh retries a connect that found nobody
# listening 1 s later, then 2 and 4 s; `cfstack fly` starts its emulator child and its ground station at
# once, and a user may start the ground station first, so try again after 20 ms, doubling up to zenoh's 4 s.
CONNECT_RETRY = {"period_init_ms": 20, "period_max_ms": 4000, "period_increase_factor": 2}
# zenoh's low-latency transport, offered where link.transports.zenoh_process says (a lockstep process)
LOW_LATENCY_CONFIG = {"transport/unicast/lowlatency": True, "transport/unicast/qos/enabled": False}
# The longest sample a low-latency session's transports send: below the 48000 B measured to arrive whole on
# loopback TCP (module docstring), with room for other links' smaller batches; ours are at most 8192 B.
LOW_LATENCY_MAX_SAMPLE_BYTES = 32768


HAS_UNIX_SOCKETS = hasattr(socket, "AF_UNIX") and sys.platform != "win32"  # zenoh's unixsock-stream is Unix-only
# A private endpoint's Unix socket path must fit the kernel's sun_path (108 bytes on Linux, 104 on macOS, NUL included)
UNIX_SOCKET_PATH_MAX_BYTES = 103
UNIX_SOCKET_NAME = "zenoh.sock"
PRIVATE_FOLDER_PREFIX = "cfstack-"  # then the creating process's id, "-", and mkdtemp's random part
# The creating process's start time (/proc/PID/stat field 22, clock ticks since boot), in a file inside the folder
# rather than in its name, which would lengthen the socket's path (UNIX_SOCKET_PATH_MAX_BYTES); Linux only.
OWNER_FILE = "owner"
_ENDPOINT_FILES = {UNIX_SOCKET_NAME, UNIX_SOCKET_NAME + ".lock"}  # what zenoh's listener puts in the folder
_STAT_STATE, _STAT_START_TIME = 0, 19  # /proc/PID/stat fields 3 and 22, counted from the one after "(name)"
_PRIVATE_FOLDER_NAME = re.compile(re.escape(PRIVATE_FOLDER_PREFIX) + r"(\d+)-[^/]+")


class PrivateEndpoint:
    """An endpoint on this machine for two processes of ours that nobody else joins (`cfstack fly`'s emulator
    child and its ground station, a benchmark's pair): zenoh's Unix socket (`unixsock-stream/PATH`) in a fresh
    folder of its own where the system has Unix sockets and the path fits, else a free loopback TCP port.
    Why a Unix socket: a sample over it skips TCP's loopback path; a 60 B ping-pong between two lockstep
    processes (README "Lockstep speed") measured shorter round trips and cheaper puts. `close()` removes the
    folder (the listener is gone by then). The folder's name carries the creating process's id and its OWNER_FILE
    that process's start time, so a process that could not close it (killed with SIGKILL) leaves it for the next one
    to remove (remove_stale_folders), even once a later process has the same id."""

    def __init__(self) -> None:
        self.folder: str | None = None
        if HAS_UNIX_SOCKETS:
            remove_stale_folders(tempfile.gettempdir())
            folder = tempfile.mkdtemp(prefix=f"{PRIVATE_FOLDER_PREFIX}{os.getpid()}-")
            _write_owner(folder)
            path = os.path.join(folder, UNIX_SOCKET_NAME)
            if len(os.fsencode(path)) <= UNIX_SOCKET_PATH_MAX_BYTES:
                self.folder = folder
                self.endpoint = f"unixsock-stream/{path}"
                return
            shutil.rmtree(folder, ignore_errors=True)
        self.endpoint = f"tcp/127.0.0.1:{free_loopback_port()}"

    def close(self) -> None:
        if self.folder is not None:
            shutil.rmtree(self.folder, ignore_errors=True)
            self.folder = None


def remove_stale_folders(parent: str) -> list[str]:
    """Remove the private endpoints' folders in `parent` that a process no longer running left behind: ours (same
    owner), named PRIVATE_FOLDER_PREFIX + a process id that no running process has (an unreaped zombie's counts as
    gone), or that a process started at another time than the one OWNER_FILE records has now (the id was reused),
    holding nothing but zenoh's socket, its lock file and OWNER_FILE (a listener killed too leaves the first two;
    one that closed, neither).
    Anything else is left alone: another user's, a live process's (its flight may be on), a folder with other
    files in it. Gives the folders removed."""
    removed = []
    try:
        entries = list(os.scandir(parent))
    except OSError:
        return removed
    for entry in entries:
        match = _PRIVATE_FOLDER_NAME.fullmatch(entry.name)
        try:
            if match is None or not entry.is_dir(follow_symlinks=False) or entry.stat().st_uid != os.getuid():
                continue
            files = set(os.listdir(entry.path))
            if files - _ENDPOINT_FILES - {OWNER_FILE} or _process_exists(int(match.group(1)), _owner(entry.path)):
                continue
            shutil.rmtree(entry.path)
        except OSError:  # gone meanwhile (another flight removed it first), or not ours to remove
            continue
        removed.append(entry.path)
    return removed


def _process_stat(pid: int) -> list[bytes] | None:
    """/proc/PID/stat's fields from the state on (the name before them may hold spaces); None without /proc (macOS),
    or if the process ended meanwhile."""
    try:
        with open(f"/proc/{pid}/stat", "rb") as stat:
            return stat.read().rpartition(b")")[2].split()
    except OSError:
        return None


def _write_owner(folder: str) -> None:
    """Record this process's start time in the folder (nothing where there is no /proc to read it from)."""
    fields = _process_stat(os.getpid())
    if fields is not None and len(fields) > _STAT_START_TIME:
        with open(os.path.join(folder, OWNER_FILE), "xb") as owner:
            owner.write(fields[_STAT_START_TIME])


def _owner(folder: str) -> bytes | None:
    """The start time a folder's OWNER_FILE records; None if it has none (an older cfstack's, no /proc, or a
    creator killed between making the folder and writing the file)."""
    try:
        with open(os.path.join(folder, OWNER_FILE), "rb") as owner:
            started = owner.read()
    except FileNotFoundError:
        return None
    return started if started.isdigit() else None


def _process_exists(pid: int, started: bytes | None = None) -> bool:
    """Whether a process with this id runs (and, given `started`, is the one started then): one that ended but is not
    reaped yet (a zombie, as a `fly` killed with SIGKILL is until its parent waits for it) does not, nor a later
    process that got the id, where /proc says so (Linux)."""
    try:
        os.kill(pid, 0)  # signal 0: no signal, only the check
    except ProcessLookupError:
        return False
    except PermissionError:  # it exists, under another user
        return True
    fields = _process_stat(pid)
    if fields is None or len(fields) <= _STAT_START_TIME:  # no /proc: os.kill's answer stands
        return True
    if started is not None and fields[_STAT_START_TIME] != started:
        return False
    return fields[_STAT_STATE] != b"Z"


def check_endpoint(endpoint: str) -> str:
    """The endpoint itself, or a one-line UserError if it is not PROTOCOL/ADDRESS."""
    if not ENDPOINT_PATTERN.match(endpoint):
        raise UserError(f"zenoh endpoint '{endpoint}' is not PROTOCOL/ADDRESS (e.g. {ENDPOINT_EXAMPLE})")
    return endpoint


def split_endpoints(text: str) -> tuple[str, ...]:
    """'tcp/a:1,tcp/b:2' -> checked endpoints; '' -> ()."""
    return tuple(check_endpoint(part.strip()) for part in text.split(",") if part.strip())


def _endpoint_list(value: str | Iterable[str] | None, what: str) -> tuple[str, ...] | None:
    if value is None:
        return None
    if isinstance(value, str):
        return split_endpoints(value)
    try:
        return tuple(check_endpoint(str(item)) for item in value)
    except TypeError:
        raise UserError(f"zenoh option '{what}' must be a list of endpoints, got {value!r}") from None


@dataclass(frozen=True)
class ZenohSettings:
    """What identifies a session. None means "not given": the config file's value, else our default."""

    mode: str | None = None
    connect: tuple[str, ...] = ()
    listen: tuple[str, ...] | None = None
    scouting: bool | None = None
    config_file: str | None = None

    @classmethod
    def from_options(cls, endpoints: str = "", **options) -> ZenohSettings:
        """Settings from a `zenoh:ENDPOINT[,ENDPOINT]` address (endpoints to connect to) plus options."""
        unknown = set(options) - set(SESSION_OPTIONS)
        if unknown:
            raise UserError(f"unknown zenoh session option(s) {', '.join(sorted(unknown))} "
                            f"(known: {', '.join(SESSION_OPTIONS)})")
        mode = options.get("mode")
        if mode is not None and mode not in MODES:
            raise UserError(f"zenoh mode '{mode}' is not one of {', '.join(MODES)}")
        connect = split_endpoints(endpoints) + (_endpoint_list(options.get("connect"), "connect") or ())
        config_file = options.get("config_file")
        if config_file is not None:
            path = Path(config_file)
            if not path.is_file():
                raise UserError(f"{config_file}: zenoh config file not found")
            config_file = str(path.resolve())
        scouting = options.get("scouting")
        settings = cls(mode=mode, connect=tuple(dict.fromkeys(connect)),
                       listen=_endpoint_list(options.get("listen"), "listen"),
                       scouting=None if scouting is None else bool(scouting), config_file=config_file)
        settings._check_reachable()
        return settings

    def _check_reachable(self) -> None:
        can_find_router = bool(self.connect or self.scouting or self.config_file)
        if self.effective_mode == "client" and not can_find_router:
            raise UserError("zenoh client mode needs a router to connect to "
                            f"(give --connect ENDPOINT, e.g. {ENDPOINT_EXAMPLE}, or --scouting)")

    @property
    def effective_mode(self) -> str:
        return self.mode or DEFAULT_MODE

    def to_config(self) -> zenoh.Config:
        """The zenoh.Config: the file (if any), then every explicitly given option on top."""
        from_file = self.config_file is not None
        try:
            config = zenoh.Config.from_file(self.config_file) if from_file else zenoh.Config()
        except zenoh.ZError as err:
            reason = zenoh_error_text(err)
            raise UserError(f"{self.config_file}: not a valid zenoh config ({reason})") from None
        if self.mode is not None or not from_file:
            _insert(config, "mode", self.effective_mode)
        if self.scouting is not None or not from_file:
            _insert(config, "scouting/multicast/enabled", bool(self.scouting))
            if not self.scouting:
                # zenoh.open otherwise spends scouting/delay (500 ms) waiting for peers that, with
                # scouting off, can only come from the explicit endpoints it connects to anyway.
                _insert(config, "scouting/delay", 0)
        if self.connect:
            _insert(config, "connect/endpoints", list(self.connect))
            if not from_file:
                _insert(config, "connect/retry", CONNECT_RETRY)
        if self.listen is not None:
            _insert(config, "listen/endpoints", list(self.listen))
        if not from_file and zenoh_process.offers_low_latency():
            for key, value in LOW_LATENCY_CONFIG.items():
                _insert(config, key, value)
        return config

    def describe(self) -> str:
        parts = [f"mode={self.effective_mode}"]
        if self.connect:
            parts.append(f"connect={','.join(self.connect)}")
        if self.listen is not None:
            parts.append(f"listen={','.join(self.listen) or 'none'}")
        if self.scouting:
            parts.append("scouting")
        if self.config_file:
            parts.append(f"config={self.config_file}")
        return " ".join(parts)


def _insert(config: zenoh.Config, key: str, value) -> None:
    try:
        config.insert_json5(key, json.dumps(value))
    except zenoh.ZError as err:
        raise UserError(f"zenoh setting {key}={value!r} rejected: {zenoh_error_text(err)}") from None


def zenoh_error_text(err: Exception) -> str:
    """zenoh's message without its Rust source locations, on one line."""
    text = str(err)
    message = re.search(r'msg: "(.*?)"', text)  # Json5Err(Message { msg: "...", ... })
    if message:
        text = message.group(1)
    text = re.sub(r"\s+at /\S+\.rs:\d+\.?", "", text)
    return " ".join(text.split()).rstrip(".") or type(err).__name__


# ----------------------------------------------------------------------------------------------------
# One session per settings, shared and reference-counted.


@dataclass
class _SharedSession:
    session: zenoh.Session
    users: int
    low_latency: bool  # opened offering zenoh's low-latency transport


_SESSIONS: dict[ZenohSettings, _SharedSession] = {}
_SESSIONS_LOCK = threading.Lock()


def acquire_session(settings: ZenohSettings) -> zenoh.Session:
    """The session for these settings, opened on first use; pair every call with release_session."""
    with _SESSIONS_LOCK:
        shared = _SESSIONS.get(settings)
        if shared is None:
            config = settings.to_config()
            try:
                session = _open(config)
            except zenoh.ZError as err:
                raise UserError(f"cannot open zenoh session ({settings.describe()}): "
                                f"{zenoh_error_text(err)}") from None
            low_latency = json.loads(config.get_json("transport/unicast/lowlatency")) is True
            shared = _SESSIONS[settings] = _SharedSession(session, 0, low_latency)
        shared.users += 1
        return shared.session


def max_sample_bytes(settings: ZenohSettings) -> int | None:
    """The longest sample the open session for these settings sends whole: LOW_LATENCY_MAX_SAMPLE_BYTES
    where it offers the low-latency transport, else None (zenoh fragments)."""
    with _SESSIONS_LOCK:
        shared = _SESSIONS.get(settings)
        return LOW_LATENCY_MAX_SAMPLE_BYTES if shared is not None and shared.low_latency else None


def _open(config: zenoh.Config) -> zenoh.Session:
    """zenoh.open; where zenoh's threads go in the background (link.transports.zenoh_process), called from a
    short-lived thread of ours put there first: a thread inherits its creator's policy and niceness, zenoh
    starts its runtimes' threads at the first open, and the threads it starts later are started by those.
    (The caller's own thread could not take its niceness back after: only a privileged process may lower it.)"""
    if not zenoh_process.in_background():
        return zenoh.open(config)
    result: list = []

    def open_in_background() -> None:
        try:
            zenoh_process.to_background(threading.get_native_id())
            result.append(zenoh.open(config))
        except BaseException as err:  # noqa: BLE001 - handed to the caller's thread, which raises it
            result.append(err)

    opener = threading.Thread(target=open_in_background, name="zenoh-open", daemon=True)
    opener.start()
    opener.join()
    if isinstance(result[0], BaseException):
        raise result[0]
    return result[0]


def release_session(settings: ZenohSettings) -> None:
    """Drop one use; the last one closes the session."""
    with _SESSIONS_LOCK:
        shared = _SESSIONS.get(settings)
        if shared is None:
            return
        shared.users -= 1
        if shared.users > 0:
            return
        del _SESSIONS[settings]
    shared.session.close()


@contextmanager
def shared_session(settings: ZenohSettings) -> Iterator[zenoh.Session]:
    """`with shared_session(settings) as session:` - acquire and release around a block."""
    session = acquire_session(settings)
    try:
        yield session
    finally:
        release_session(settings)


def session_users(settings: ZenohSettings) -> int:
    """How many users hold the session of these settings (0: not open)."""
    with _SESSIONS_LOCK:
        shared = _SESSIONS.get(settings)
        return shared.users if shared else 0


def close_all_sessions() -> None:
    """Close every session still open (at interpreter exit: zenoh threads must stop before Python)."""
    with _SESSIONS_LOCK:
        leftovers = list(_SESSIONS.values())
        _SESSIONS.clear()
    for shared in leftovers:
        shared.session.close()


atexit.register(close_all_sessions)


# ----------------------------------------------------------------------------------------------------
# The flags every zenoh-speaking command takes.


def _endpoint_argument(text: str) -> str:
    try:
        return check_endpoint(text)
    except UserError as err:
        raise argparse.ArgumentTypeError(str(err)) from None


def add_zenoh_arguments(parser: argparse.ArgumentParser, mode_flag: str = "--mode") -> argparse._ArgumentGroup:
    """Add --mode, --connect, --listen, --config, --scouting/--no-scouting (dests prefixed zenoh_).

    Commands whose own --mode means something else (the ground station's command mode) pass
    mode_flag="--zenoh-mode"."""
    group = parser.add_argument_group("zenoh", "how this process joins the zenoh network "
                                      "(default: peer mode, no multicast scouting)")
    group.add_argument(mode_flag, dest="zenoh_mode", choices=MODES, default=None,
                       help=f"zenoh mode (default: {DEFAULT_MODE}, or the config file's)")
    group.add_argument("--connect", dest="zenoh_connect", action="append", metavar="ENDPOINT",
                       type=_endpoint_argument, default=None,
                       help=f"endpoint to connect to, e.g. {ENDPOINT_EXAMPLE} (repeatable)")
    group.add_argument("--listen", dest="zenoh_listen", action="append", metavar="ENDPOINT",
                       type=_endpoint_argument, default=None,
                       help="endpoint to listen on, e.g. tcp/0.0.0.0:7447 (repeatable)")
    group.add_argument("--config", dest="zenoh_config", metavar="FILE", default=None,
                       help="zenoh JSON5 config file; the flags above override it")
    group.add_argument("--scouting", dest="zenoh_scouting", action=argparse.BooleanOptionalAction,
                       default=None, help="multicast scouting to find peers on the LAN (default: off)")
    return group


def zenoh_options_from_args(args: argparse.Namespace) -> dict:
    """Options for open_transport("zenoh...", **options) / ZenohSettings.from_options: only those given."""
    given = {
        "mode": getattr(args, "zenoh_mode", None),
        "connect": getattr(args, "zenoh_connect", None),
        "listen": getattr(args, "zenoh_listen", None),
        "config_file": getattr(args, "zenoh_config", None),
        "scouting": getattr(args, "zenoh_scouting", None),
    }
    return {name: value for name, value in given.items() if value is not None}


# ----------------------------------------------------------------------------------------------------
# A stand-alone session, e.g. a router: `python -m link.transports.zenoh_session --mode router --listen ...`.


def serve(settings: ZenohSettings, stop: threading.Event) -> None:
    """Hold a session open until `stop` is set; prints one 'ready' line once it listens."""
    with shared_session(settings) as session:
        print(f"zenoh {settings.effective_mode} ready: zid {session.zid()} ({settings.describe()})",
              flush=True)
        while not stop.wait(0.2):  # a timed wait, so the signal handlers run promptly
            pass


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m link.transports.zenoh_session",
        description="Run a zenoh session (e.g. a router) until SIGTERM or Ctrl-C.")
    add_zenoh_arguments(parser)
    args = parser.parse_args(argv)
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    signal.signal(signal.SIGINT, lambda *_: stop.set())
    try:
        serve(ZenohSettings.from_options(**zenoh_options_from_args(args)), stop)
    except UserError as err:
        print(f"link.transports.zenoh_session: {err}", file=sys.stderr)
        return err.exit_code
    return 0


if __name__ == "__main__":
    sys.exit(main())
