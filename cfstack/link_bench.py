"""`cfstack link-bench`: how fast the link is, against bare zenoh and bare UDP, measured in one run.

Takes in: `--count N` round trips per path, `--frames N` frames per throughput run, `--blocks N`
(interleaved blocks of round trips), `--quick` (a smoke-sized run); internally `--echo ENDPOINT PREFIX`
runs the far end in a child process.
Gives out: a table on stdout and progress lines on stderr; exit code 0 whatever the numbers (it is a
benchmark, not a test: a missed target prints MISS, it does not fail). Three paths per medium (zenoh,
UDP), all on loopback between this process and an echo child process:
- bare: no cfstack code. zenoh: a raw publisher (RELIABLE, BLOCK, as the transport declares it) and a
  FIFO subscriber read with a blocking recv(), on the same session the transports use. UDP: a socket.
- transport: our transport (link.transports) moving the same bytes, no codec.
- link: the full link, Endpoint on both ends: Codec.encode -> transport -> FrameParser decode (+ LinkStats).
Measured:
- round trip (p50, p99, microseconds) of a ThrustMoment frame out and an ImuSample frame back: the child
  decodes the command and answers with an encoded IMU sample stamped with the command's time (bare and
  transport paths move as many bytes without the codec); ratios of each p50 to its medium's bare p50.
- one-way throughput (frames/s): the sender encodes and sends `--frames` ImuSample frames back to back,
  the child decodes and counts them; rate = frames received / (last arrival - first send). Both times
  are CLOCK_MONOTONIC (time.monotonic), which Linux shares between processes.
- median encode and decode cost per message type, signing off and on (link.mavlink.codec.measure_codec_costs).
Targets (issue "The link", section Numbers): the full zenoh link adds at most 50 % to the bare zenoh
round trip (p50 ratio <= 1.5); full zenoh link throughput >= 20 000 frames/s.

Reading the ratios (measured on the shared 2-vCPU VM this project runs on, load 4-8): a round trip's
p50 depends steeply on the turnaround, the time a process takes from a frame's arrival to its next send.
Bare zenoh with a busy spin of D us inserted after every receive on both ends, p50 in one run each:
D = 0: 136-158 us, 1: 167-185, 3: 163-185, 5: 167-196, 12: 182-217, 20: 207-230, 45: 265-288 (3 runs):
a step of 25-30 us as soon as the turnaround exceeds 1-2 us, then ~1.2 us per us. The bare rows turn
around in ~2 us and sit below the step (their p50 itself swings between ~90 and ~230 us from run to run);
every layer that does anything per frame is past it. And right after a wake-up the per-frame Python runs
3-7x slower than in a hot loop (cold caches; spinning before it does not help): FrameParser.feed of one
ThrustMoment frame takes 10-12 us in the echo process right after the frame arrives (2.5-3 us hot),
Codec.encode of an ImuSample 4-6 us (1.1 us hot). The full link turns around in ~20-25 us on each end,
so it sits 75-100 us above bare whatever bare is: ratio 1.4-1.65 in runs where bare took 150-230 us,
1.7-2.2 where it took 90-130 us.

Method: the round-trip paths run in interleaved blocks (every path once per block), each block after a
warm-up, so that load from other processes on a shared machine hits every path alike and the ratios
stay meaningful; the p50 and p99 are over all blocks' samples. The child is driven through its
stdin/stdout, one phase at a time ("echo PATH ..." / "sink PATH ..."); a phase ends in-band with a stop
token carrying the phase number (bytes b"stop N" on byte paths, VehicleCommand(DISARM, time_s=N) on the
link), so a stop repeated over lossy UDP cannot end a later phase.
"""

from __future__ import annotations

import argparse
import collections
import contextlib
import math
import os
import platform
import select
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field, replace

import numpy as np

from link.endpoint import Endpoint
from link.keys import DEFAULT_PREFIX, GROUND_STATION_SYSTEM_ID
from link.mavlink import frame_kernel
from link.mavlink.codec import KERNEL_KINDS, ActuatorLimits, Codec, measure_codec_costs, sample_messages
from link.messages import CommandKind, ImuSample, Message, ThrustMoment, VehicleCommand
from link.transports import open_transport
from link.transports.base import free_loopback_port
from link.transports.udp import DEFAULT_SOCKET_BUFFER_BYTES, MAX_DATAGRAM_BYTES
from link.transports.zenoh_bare import ZENOH_ERRORS, BareZenoh
from link.transports.zenoh_session import ZenohSettings, acquire_session, release_session
from model.errors import UserError
from model.vehicle import load_vehicle

# Targets of issue "The link", section Numbers.
ROUND_TRIP_RATIO_TARGET = 1.5  # full zenoh link p50 / bare zenoh p50
THROUGHPUT_TARGET_FPS = 20_000.0  # full zenoh link, one way

DEFAULT_COUNT = 2000  # round trips per path
DEFAULT_FRAMES = 50_000  # frames per throughput run
DEFAULT_BLOCKS = 8
DEFAULT_CODEC_CALLS = 2000  # calls per message type and direction in measure_codec_costs
KERNEL_MESSAGES = frozenset(kind.__name__ for kind in KERNEL_KINDS)  # what the compiled encoder takes (the parser: all)
QUICK = {"count": 100, "frames": 3000, "blocks": 2, "codec_calls": 200}
WARMUP_ROUND_TRIPS = 30  # per block, not recorded: first samples after a phase switch are slow

BENCH_VEHICLE_ID = 1  # MAVLink system id of the echo side (the ground station is GROUND_STATION_SYSTEM_ID)
# Per medium: bare (no cfstack code), transport (our transport moving the same bytes, no codec), link
# (Endpoint: codec + transport + statistics). The middle row tells the transport's cost from the codec's.
MEDIA = ("zenoh", "udp")
LAYERS = ("bare", "transport", "link")
PATHS = tuple(f"{medium}-{layer}" for medium in MEDIA for layer in LAYERS)
STOP_PREFIX = b"stop "

READY_TIMEOUT_S = 30.0  # child start: imports, zenoh session, subscriber matching
MATCHING_TIMEOUT_S = 10.0
REPLY_TIMEOUT_S = 2.0  # one round trip; longer counts as lost
PHASE_IDLE_LIMIT_S = 10.0  # the child gives a phase up after this long without any frame
RESULT_TIMEOUT_S = 30.0  # waiting for a phase's result line (a sink may still decode a backlog)
STOP_RETRY_S = 0.3  # resend the stop token this often until the result line comes (UDP may drop it)
POLL_S = 0.2  # receive timeout of the child's loops, so it notices idleness
PARENT_CHECK_S = 0.5  # how often the child checks that its parent is still alive


def _progress(text: str) -> None:
    print(f"link-bench: {text}", file=sys.stderr, flush=True)


def _stop_token(phase: int) -> bytes:
    return STOP_PREFIX + str(phase).encode()


def _stop_message(phase: int) -> VehicleCommand:
    return VehicleCommand(float(phase), CommandKind.DISARM)


def _is_stop(message: Message, phase: int) -> bool:
    return type(message) is VehicleCommand and message.time_s == float(phase)


def _limits() -> ActuatorLimits:
    return ActuatorLimits.from_vehicle(load_vehicle("crazyflie"))


def _template(kind: type) -> Message:
    """The typical message of that kind (link.mavlink.codec.sample_messages: a hovering Crazyflie)."""
    return next(message for message in sample_messages() if type(message) is kind)


# ---------------------------------------------------------------------------------------------------
# Pipes: what each path is, at either end. Bare pipes move bytes; link paths are Endpoints.


class BareUdp:
    """A plain UDP socket: sends to `peer` (or to whoever spoke last, like udpin), blocking recv()."""

    def __init__(self, peer: tuple[str, int] | None = None):
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        for option in (socket.SO_RCVBUF, socket.SO_SNDBUF):
            self.sock.setsockopt(socket.SOL_SOCKET, option, DEFAULT_SOCKET_BUFFER_BYTES)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.settimeout(REPLY_TIMEOUT_S if peer else PHASE_IDLE_LIMIT_S)
        self.peer = peer
        self._learn_peer = peer is None

    @property
    def port(self) -> int:
        return self.sock.getsockname()[1]

    def send(self, payload: bytes) -> None:
        if self.peer is not None:
            with contextlib.suppress(BlockingIOError, TimeoutError):  # a full send buffer drops the datagram
                self.sock.sendto(payload, self.peer)

    def recv(self) -> bytes:
        """The next datagram; raises TimeoutError after the socket's timeout."""
        data, sender = self.sock.recvfrom(MAX_DATAGRAM_BYTES)
        if self._learn_peer:
            self.peer = sender
        return data

    @contextlib.contextmanager
    def guard(self, limit_s: float) -> Iterator[None]:
        yield  # the socket's own timeout bounds every recv

    def close(self) -> None:
        self.sock.close()


class TransportPipe:
    """Bytes over one of our transports, no codec; recv() raises TimeoutError after `timeout_s`."""

    def __init__(self, transport, timeout_s: float):
        self.transport = transport
        self.timeout_s = timeout_s
        self._pending: collections.deque[bytes] = collections.deque()

    def send(self, payload: bytes) -> None:
        self.transport.send(payload)

    def recv(self) -> bytes:
        while not self._pending:
            frames = self.transport.receive(self.timeout_s)
            if not frames:
                raise TimeoutError(f"nothing on {self.transport.describe()} within {self.timeout_s} s")
            self._pending.extend(frames)
        return self._pending.popleft()

    def guard(self, limit_s: float):
        return contextlib.nullcontext()  # every recv has its own timeout

    def close(self) -> None:
        self.transport.close()


@dataclass
class Side:
    """One end's pipe of every path (BareZenoh, BareUdp, TransportPipe or Endpoint) on its session."""

    pipes: dict[str, object]
    session_settings: ZenohSettings

    def udp_ports(self) -> list[int]:
        """The local UDP ports of the udp paths, in PATHS order (the echo side tells the parent)."""
        ports = []
        for path in PATHS:
            pipe = self.pipes[path]
            if isinstance(pipe, BareUdp):
                ports.append(pipe.port)
            elif path.startswith("udp"):
                transport = pipe.transport
                ports.append(transport.local_address[1])
        return ports

    def close(self) -> None:
        for pipe in self.pipes.values():
            pipe.close()
        release_session(self.session_settings)


def _open_side(settings: ZenohSettings, prefix: str, ground: bool, udp_ports: list[int] | None) -> Side:
    """The ground (parent) side sends on PREFIX/PATH/up and receives on .../down; the vehicle (echo)
    side the other way round. The vehicle side binds its UDP ports (udp_ports None); the ground side
    sends to them, one port per udp path in PATHS order."""
    tx, rx = ("up", "down") if ground else ("down", "up")
    timeout_s = REPLY_TIMEOUT_S if ground else PHASE_IDLE_LIMIT_S
    system_id = GROUND_STATION_SYSTEM_ID if ground else BENCH_VEHICLE_ID
    limits = _limits()
    session = acquire_session(settings)
    zenoh_address = "zenoh:" + ",".join(settings.connect)
    ports = iter(udp_ports or ())
    pipes: dict[str, object] = {}
    for path in PATHS:
        medium, layer = path.split("-")
        if medium == "zenoh" and layer == "bare":
            pipes[path] = BareZenoh(session, f"{prefix}/{path}/{tx}", f"{prefix}/{path}/{rx}")
            continue
        if medium == "udp" and layer == "bare":
            pipes[path] = BareUdp(("127.0.0.1", next(ports)) if ground else None)
            continue
        if medium == "zenoh":
            transport = open_transport(zenoh_address, tx=f"{prefix}/{path}/{tx}", rx=f"{prefix}/{path}/{rx}",
                                       listen=list(settings.listen or ()))
        else:
            transport = open_transport(f"udpout:127.0.0.1:{next(ports)}" if ground else "udpin:127.0.0.1:0")
        if layer == "transport":
            pipes[path] = TransportPipe(transport, timeout_s)
        else:
            pipes[path] = Endpoint(transport, Codec(system_id, limits=limits), clock=time.monotonic)
    return Side(pipes, settings)


def _wait_for_matching(side: Side) -> None:
    for path in PATHS:
        pipe = side.pipes[path]
        if not path.startswith("zenoh"):
            continue
        subscribed = pipe if isinstance(pipe, BareZenoh) else pipe.transport
        if not subscribed.wait_for_subscribers(MATCHING_TIMEOUT_S):
            raise UserError(f"the other process did not subscribe to {path} "
                            f"within {MATCHING_TIMEOUT_S:.0f} s")


# ---------------------------------------------------------------------------------------------------
# The echo side (child process): `python -m cfstack.link_bench --echo ENDPOINT PREFIX`.


def _exit_with_parent() -> None:
    """A daemon thread ending this process when its parent dies (a blocked zenoh recv would not)."""
    parent = os.getppid()

    def watch() -> None:
        while os.getppid() == parent:
            time.sleep(PARENT_CHECK_S)
        os._exit(1)

    threading.Thread(target=watch, name="parent watch", daemon=True).start()


def _echo_bare(pipe, phase: int, request_bytes: int, reply_bytes: int) -> str:
    reply, stop, handled = bytes(reply_bytes), _stop_token(phase), 0
    while True:
        data = pipe.recv()
        if len(data) == request_bytes:
            pipe.send(reply)
            handled += 1
        elif data == stop:
            return f"done {handled}"


def _sink_bare(pipe, phase: int, expected: int) -> str:
    stop, count, first, last = _stop_token(phase), 0, math.nan, math.nan
    while count < expected:
        try:
            data = pipe.recv()
        except TimeoutError:
            break  # UDP lost the rest, stop included
        if data.startswith(STOP_PREFIX):
            if data == stop:
                break
            continue  # a stop repeated for an earlier phase
        last = time.monotonic()
        if count == 0:
            first = last
        count += 1
    return f"sunk {count} {first!r} {last!r}"


def _echo_link(endpoint: Endpoint, phase: int) -> str:
    """Answer each ThrustMoment with an ImuSample. Like _echo_bare, nothing but the link runs between a
    frame's arrival and the reply, nor between the reply and the next wait: the clock is read only
    when a wait ends empty (to give up after PHASE_IDLE_LIMIT_S without frames)."""
    reply, handled, idle_since = _template(ImuSample), 0, None
    while True:
        received = endpoint.receive(POLL_S)
        if not received:
            now = time.monotonic()
            if idle_since is None:
                idle_since = now - POLL_S
            elif now - idle_since >= PHASE_IDLE_LIMIT_S:
                return f"done {handled}"
            continue
        idle_since = None
        for item in received:
            message = item.message
            if type(message) is ThrustMoment:
                endpoint.send(ImuSample(message.time_s, reply.specific_force_flu_mps2, reply.rate_flu_radps))
                handled += 1
            elif _is_stop(message, phase):
                return f"done {handled}"


def _sink_link(endpoint: Endpoint, phase: int, expected: int) -> str:
    count, first, last, idle_since = 0, math.nan, math.nan, time.monotonic()
    while count < expected and time.monotonic() - idle_since < PHASE_IDLE_LIMIT_S:
        received = endpoint.receive(POLL_S)
        if not received:
            continue
        now = idle_since = time.monotonic()
        frames = sum(1 for item in received if type(item.message) is ImuSample)
        if frames:
            first = now if count == 0 else first
            last = now
            count += frames
        if any(_is_stop(item.message, phase) for item in received):
            break
    return f"sunk {count} {first!r} {last!r}"


def _run_phase(side: Side, words: list[str]) -> str:
    mode, path, phase, *numbers = words
    pipe, phase, numbers = side.pipes[path], int(phase), [int(number) for number in numbers]
    print("go", flush=True)
    bare = not path.endswith("link")  # bytes, not messages
    if mode == "echo":
        return _echo_bare(pipe, phase, *numbers) if bare else _echo_link(pipe, phase)
    return _sink_bare(pipe, phase, *numbers) if bare else _sink_link(pipe, phase, *numbers)


def serve_echo(zenoh_endpoint: str, prefix: str) -> int:
    """The far end: connects to the parent's zenoh endpoint, binds its UDP ports, then runs the phases
    its stdin names until "quit" (or its parent dies)."""
    _exit_with_parent()
    side = _open_side(ZenohSettings.from_options(zenoh_endpoint, listen=[]), prefix, ground=False, udp_ports=None)
    try:
        print("ready " + " ".join(map(str, side.udp_ports())), flush=True)
        _wait_for_matching(side)  # the parent opens its side once it has read our UDP ports
        while True:
            words = sys.stdin.readline().split()
            if not words or words[0] == "quit":
                return 0
            try:
                result = _run_phase(side, words)
            except (TimeoutError, *ZENOH_ERRORS) as err:
                result = f"failed {type(err).__name__}"
            print(result, flush=True)
    finally:
        side.close()


# ---------------------------------------------------------------------------------------------------
# The measuring side.


class _Child:
    """The echo process and its line protocol (unbuffered reads, so select() sees every line)."""

    def __init__(self, endpoint: str, prefix: str):
        command = [sys.executable, "-m", "cfstack.link_bench", "--echo", endpoint, prefix]
        self.process = subprocess.Popen(command, stdin=subprocess.PIPE, stdout=subprocess.PIPE)
        self._buffer = b""
        self.phase = 0

    def read_line(self, timeout_s: float) -> str | None:
        deadline = time.monotonic() + timeout_s
        while b"\n" not in self._buffer:
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                return None
            readable, _, _ = select.select([self.process.stdout], [], [], remaining)
            if readable:
                chunk = os.read(self.process.stdout.fileno(), 4096)
                if not chunk:
                    raise UserError(f"the echo process ended (exit code {self.process.wait()})")
                self._buffer += chunk
        line, _, self._buffer = self._buffer.partition(b"\n")
        return line.decode()

    def expect(self, prefix: str, timeout_s: float) -> list[str]:
        line = self.read_line(timeout_s)
        if line is None or not line.startswith(prefix):
            raise UserError(f"the echo process said {line!r}, expected '{prefix} ...'")
        return line.split()[1:]

    def start_phase(self, mode: str, path: str, *numbers: int) -> int:
        self.phase += 1
        words = [mode, path, str(self.phase), *map(str, numbers)]
        self.process.stdin.write((" ".join(words) + "\n").encode())
        self.process.stdin.flush()
        self.expect("go", RESULT_TIMEOUT_S)
        return self.phase

    def finish_phase(self, send_stop: Callable[[], None], prefix: str) -> list[str]:
        """Send the stop token until the phase's result line comes (UDP may lose a stop)."""
        deadline = time.monotonic() + RESULT_TIMEOUT_S
        while time.monotonic() < deadline:
            send_stop()
            line = self.read_line(STOP_RETRY_S)
            if line is not None:
                if not line.startswith(prefix):
                    raise UserError(f"the echo process said {line!r}, expected '{prefix} ...'")
                return line.split()[1:]
        raise UserError(f"the echo process gave no result within {RESULT_TIMEOUT_S:.0f} s")

    def quit(self) -> None:
        with contextlib.suppress(OSError):
            self.process.stdin.write(b"quit\n")
            self.process.stdin.close()
        try:
            self.process.wait(5.0)
        except subprocess.TimeoutExpired:
            self.process.kill()
            self.process.wait()


@dataclass
class RoundTrips:
    path: str
    samples_s: list[float] = field(default_factory=list)
    lost: int = 0

    @property
    def p50_us(self) -> float:
        return float(np.percentile(self.samples_s, 50)) * 1e6 if self.samples_s else math.nan

    @property
    def p99_us(self) -> float:
        return float(np.percentile(self.samples_s, 99)) * 1e6 if self.samples_s else math.nan


@dataclass(frozen=True)
class Throughput:
    path: str
    frames_sent: int
    frames_received: int
    send_s: float  # first send -> last send (sender side)
    delivery_s: float  # first send -> last arrival (CLOCK_MONOTONIC across the two processes)

    @property
    def received_fps(self) -> float:
        return self.frames_received / self.delivery_s if self.delivery_s > 0 else math.nan

    @property
    def sent_fps(self) -> float:
        return self.frames_sent / self.send_s if self.send_s > 0 else math.nan


@dataclass
class BenchReport:
    request_bytes: int  # the ThrustMoment frame (bare paths send as many bytes)
    reply_bytes: int  # the ImuSample frame
    count: int
    frames: int
    blocks: int
    round_trips: dict[str, RoundTrips]
    throughput: dict[str, Throughput]
    codec_us: dict[bool, dict[str, tuple[float, float]]]  # signing -> type -> (encode, decode)
    setup: str = ""
    # unsigned, compiled and Python twins timed in turns: type -> (encode, decode, Python encode, Python decode)
    codec_twin_us: dict[str, tuple[float, float, float, float]] = field(default_factory=dict)

    def ratio(self, medium: str, layer: str = "link") -> float:
        """p50 round trip of `medium`'s `layer` over its bare p50."""
        return self.round_trips[f"{medium}-{layer}"].p50_us / self.round_trips[f"{medium}-bare"].p50_us


class _LinkDriver:
    """The measuring end of a link path: one round trip = ThrustMoment out, the matching ImuSample back."""

    def __init__(self, endpoint: Endpoint):
        self.endpoint = endpoint
        self.command = _template(ThrustMoment)
        self.stamp_us = 0  # a fresh stamp per round trip: a late reply cannot be taken for the current one

    def round_trip(self) -> bool:
        self.stamp_us += 1
        stamp_s = self.stamp_us / 1e6  # what the reply's time decodes to (whole microseconds on the wire)
        command = self.command
        self.endpoint.send(ThrustMoment(stamp_s, command.thrust_n, command.moment_flu_nm))
        deadline = time.monotonic() + REPLY_TIMEOUT_S  # after the send: off the way from reply to command
        remaining = REPLY_TIMEOUT_S
        while remaining > 0:
            for received in self.endpoint.receive(remaining):
                message = received.message
                if type(message) is ImuSample and message.time_s == stamp_s:
                    return True
            remaining = deadline - time.monotonic()
        return False

    def stream(self, messages: list[Message]) -> None:
        send = self.endpoint.send
        for message in messages:
            send(message)

    def stop(self, phase: int) -> None:
        self.endpoint.send(_stop_message(phase))

    def guard(self, limit_s: float):
        return contextlib.nullcontext()  # every round trip has its own timeout


class _BareDriver:
    def __init__(self, pipe, request_bytes: int, reply_bytes: int):
        self.pipe = pipe
        self.request = bytes(request_bytes)
        self.reply_bytes = reply_bytes

    def round_trip(self) -> bool:
        self.pipe.send(self.request)
        try:
            return len(self.pipe.recv()) == self.reply_bytes
        except TimeoutError:
            return False

    def stream(self, payloads: list[bytes]) -> None:
        send = self.pipe.send
        for payload in payloads:
            send(payload)

    def stop(self, phase: int) -> None:
        self.pipe.send(_stop_token(phase))

    def guard(self, limit_s: float):
        return self.pipe.guard(limit_s)


def _round_trip_block(child: _Child, driver, path: str, count: int, result: RoundTrips,
                      request_bytes: int, reply_bytes: int) -> None:
    child.start_phase("echo", path, request_bytes, reply_bytes)
    timer = time.perf_counter
    samples, lost = result.samples_s, 0
    block_limit_s = (count + WARMUP_ROUND_TRIPS) * REPLY_TIMEOUT_S
    with driver.guard(block_limit_s):
        for index in range(WARMUP_ROUND_TRIPS + count):
            started = timer()
            answered = driver.round_trip()
            elapsed = timer() - started
            if index < WARMUP_ROUND_TRIPS:
                continue
            if answered:
                samples.append(elapsed)
            else:
                lost += 1
    result.lost += lost
    child.finish_phase(lambda: driver.stop(child.phase), "done")


def _throughput(child: _Child, driver, path: str, items: list) -> Throughput:
    child.start_phase("sink", path, len(items))
    started = time.monotonic()
    driver.stream(items)
    sent = time.monotonic()
    count, first, last = child.finish_phase(lambda: driver.stop(child.phase), "sunk")
    delivered = float(last) - started if int(count) else math.nan
    return Throughput(path, len(items), int(count), sent - started, delivered)


def _drivers(side: Side, request_bytes: int, reply_bytes: int) -> dict[str, object]:
    return {path: _LinkDriver(pipe) if path.endswith("link") else _BareDriver(pipe, request_bytes, reply_bytes)
            for path, pipe in side.pipes.items()}


def _frame_sizes() -> tuple[int, int]:
    codec = Codec(GROUND_STATION_SYSTEM_ID, limits=_limits())
    return len(codec.encode(_template(ThrustMoment))), len(codec.encode(_template(ImuSample)))


def _imu_stream(frames: int) -> list[ImuSample]:
    imu = _template(ImuSample)
    return [replace(imu, time_s=(index + 1) * 1e-6) for index in range(frames)]


def run_bench(count: int = DEFAULT_COUNT, frames: int = DEFAULT_FRAMES, blocks: int = DEFAULT_BLOCKS,
              codec_calls: int = DEFAULT_CODEC_CALLS, progress: Callable[[str], None] = _progress) -> BenchReport:
    """Measure everything (see the module docstring) with an echo child process; returns the numbers.
    Each of the `blocks` runs ceil(count / blocks) round trips per path."""
    blocks = min(blocks, count)
    count = math.ceil(count / blocks) * blocks
    request_bytes, reply_bytes = _frame_sizes()
    endpoint = f"tcp/127.0.0.1:{free_loopback_port()}"
    prefix = f"{DEFAULT_PREFIX}/bench/{os.getpid()}"
    settings = ZenohSettings.from_options("", listen=[endpoint])
    progress(f"starting the echo process (zenoh peer on {endpoint})")
    child = _Child(endpoint, prefix)
    side = None
    try:
        udp_ports = [int(port) for port in child.expect("ready", READY_TIMEOUT_S)]
        side = _open_side(settings, prefix, ground=True, udp_ports=udp_ports)
        _wait_for_matching(side)
        report = BenchReport(request_bytes, reply_bytes, count, frames, blocks,
                             {path: RoundTrips(path) for path in PATHS}, {}, {},
                             setup=f"loopback, 2 processes, zenoh peer {endpoint}")
        _measure_round_trips(child, side, report, progress)
        _measure_throughput(child, side, report, progress)
    finally:
        child.quit()
        if side is not None:
            side.close()
    for signing in (False, True):
        progress(f"codec costs, signing {'on' if signing else 'off'} ({codec_calls} calls per message type)")
        report.codec_us[signing] = measure_codec_costs(codec_calls, signing=signing)
    if frame_kernel.COMPILED:  # the compiled encoder's and parser's baseline: their Python twins, timed in turns
        progress(f"codec costs, compiled and Python twins in turns ({codec_calls} calls per message type)")
        report.codec_twin_us = measure_codec_costs(codec_calls, python_twin=True)
    return report


def _measure_round_trips(child: _Child, side: Side, report: BenchReport, progress) -> None:
    drivers = _drivers(side, report.request_bytes, report.reply_bytes)
    per_block = report.count // report.blocks
    for block in range(report.blocks):
        for path in PATHS:
            result = report.round_trips[path]
            _round_trip_block(child, drivers[path], path, per_block, result,
                              report.request_bytes, report.reply_bytes)
            progress(f"round trips, block {block + 1}/{report.blocks}, {_label(path)}: "
                     f"p50 so far {result.p50_us:.0f} us")


def _measure_throughput(child: _Child, side: Side, report: BenchReport, progress) -> None:
    drivers = _drivers(side, report.request_bytes, report.reply_bytes)
    imu_frames = _imu_stream(report.frames)
    payloads = [bytes(report.reply_bytes)] * report.frames
    for path in PATHS:
        items = imu_frames if path.endswith("link") else payloads
        result = _throughput(child, drivers[path], path, items)
        report.throughput[path] = result
        progress(f"throughput, {_label(path)}: {result.received_fps:,.0f} frames/s "
                 f"({result.frames_received}/{result.frames_sent} received)")


# ---------------------------------------------------------------------------------------------------
# The table.


def verdict(passed: bool) -> str:
    return "PASS" if passed else "MISS"


def _label(path: str) -> str:
    return path.replace("-", " ")


def format_report(report: BenchReport) -> str:
    header = (f"cfstack link-bench: {report.setup}; python {platform.python_version()}, "
              f"zenoh {_zenoh_version()}")
    sections = [header, _round_trip_table(report), _throughput_table(report), _codec_table(report)]
    return "\n\n".join(sections)


def _round_trip_table(report: BenchReport) -> str:
    lines = [
        f"Round trip: ThrustMoment frame out ({report.request_bytes} B), ImuSample frame back "
        f"({report.reply_bytes} B); bare and transport rows move the same bytes without the codec. "
        f"{report.count} per path, {report.blocks} interleaved blocks.",
        f"  {'path':<16}{'p50 us':>9}{'p99 us':>9}{'p50/bare':>10}{'samples':>9}{'lost':>6}",
    ]
    for path in PATHS:
        trips = report.round_trips[path]
        medium, layer = path.split("-")
        lines.append(f"  {_label(path):<16}{trips.p50_us:>9.0f}{trips.p99_us:>9.0f}"
                     f"{report.ratio(medium, layer):>10.2f}{len(trips.samples_s):>9}{trips.lost:>6}")
    zenoh_ratio = report.ratio("zenoh")
    lines += [
        f"  zenoh link p50 / zenoh bare p50 = {zenoh_ratio:.2f}   target <= {ROUND_TRIP_RATIO_TARGET:.2f}   "
        f"{verdict(zenoh_ratio <= ROUND_TRIP_RATIO_TARGET)}",
        f"  udp link p50 / udp bare p50 = {report.ratio('udp'):.2f}   (no target)",
    ]
    return "\n".join(lines)


def _throughput_table(report: BenchReport) -> str:
    lines = [
        f"Throughput one way: {report.frames} ImuSample frames sent back to back (bare and transport rows: "
        f"as many {report.reply_bytes} B payloads); frames/s = received / (last arrival - first send).",
        f"  {'path':<16}{'frames/s':>11}{'sent/s':>11}{'received':>10}{'lost':>7}",
    ]
    for path in PATHS:
        result = report.throughput[path]
        lines.append(f"  {_label(path):<16}{result.received_fps:>11,.0f}{result.sent_fps:>11,.0f}"
                     f"{result.frames_received:>10}{result.frames_sent - result.frames_received:>7}")
    zenoh_fps = report.throughput["zenoh-link"].received_fps
    lines.append(f"  zenoh link: {zenoh_fps:,.0f} frames/s   target >= {THROUGHPUT_TARGET_FPS:,.0f}   "
                 f"{verdict(zenoh_fps >= THROUGHPUT_TARGET_FPS)}")
    return "\n".join(lines)


def _codec_table(report: BenchReport) -> str:
    twin = report.codec_twin_us
    lines = [
        "Codec cost per message, median us (encode = Codec.encode; decode = FrameParser.feed of one datagram)",
        ("  py enc, py dec = the Python twins of the compiled encoder (the messages it takes) and parser "
         "(link.mavlink.frame_kernel),\n  py/enc, py/dec = their cost over the compiled one's, the two timed in turns "
         "in a run of their own" if twin else "  the compiled encoder and parser were not built"),
        f"  {'message':<16}{'encode':>8}{'decode':>8}{'signed enc':>12}{'signed dec':>12}"
        + (f"{'py enc':>8}{'py dec':>8}{'py/enc':>8}{'py/dec':>8}" if twin else ""),
    ]
    plain, signed = report.codec_us[False], report.codec_us[True]
    for name, (encode_us, decode_us) in plain.items():
        signed_encode_us, signed_decode_us = signed[name]
        line = (f"  {name:<16}{encode_us:>8.1f}{decode_us:>8.1f}{signed_encode_us:>12.1f}"
                f"{signed_decode_us:>12.1f}")
        if twin:
            compiled_encode_us, compiled_decode_us, python_encode_us, python_decode_us = twin[name]
            taken = name in KERNEL_MESSAGES
            line += (f"{python_encode_us:>8.1f}" if taken else f"{'-':>8}") + f"{python_decode_us:>8.1f}"
            line += f"{python_encode_us / compiled_encode_us:>8.2f}" if taken else f"{'-':>8}"
            line += f"{python_decode_us / compiled_decode_us:>8.2f}"
        lines.append(line)
    return "\n".join(lines)


def _zenoh_version() -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("eclipse-zenoh")
    except PackageNotFoundError:
        return "?"


# ---------------------------------------------------------------------------------------------------
# Command line.


def _positive_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"'{text}' is not a whole number") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"{value} must be at least 1")
    return value


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="cfstack link-bench",
        description="Round trip, throughput and codec cost of the link against bare zenoh and bare UDP "
                    "(loopback, two processes). Prints PASS/MISS against the targets; always exits 0.")
    parser.add_argument("--count", type=_positive_int, default=None,
                        help=f"round trips per path (default {DEFAULT_COUNT}, --quick {QUICK['count']})")
    parser.add_argument("--frames", type=_positive_int, default=None,
                        help=f"frames per throughput run (default {DEFAULT_FRAMES}, --quick {QUICK['frames']})")
    parser.add_argument("--blocks", type=_positive_int, default=None,
                        help=f"interleaved blocks of round trips (default {DEFAULT_BLOCKS}, "
                             f"--quick {QUICK['blocks']})")
    parser.add_argument("--quick", action="store_true", help="a short run (smoke test sizes)")
    parser.add_argument("--echo", nargs=2, metavar=("ENDPOINT", "PREFIX"), help=argparse.SUPPRESS)
    return parser


def command(argv: list[str]) -> int:
    args = _parser().parse_args(argv)
    if args.echo:
        return serve_echo(*args.echo)
    sizes = dict(QUICK) if args.quick else {"count": DEFAULT_COUNT, "frames": DEFAULT_FRAMES,
                                             "blocks": DEFAULT_BLOCKS, "codec_calls": DEFAULT_CODEC_CALLS}
    for name in ("count", "frames", "blocks"):
        if getattr(args, name) is not None:
            sizes[name] = getattr(args, name)
    started = time.monotonic()
    report = run_bench(**sizes)
    print(format_report(report), flush=True)
    _progress(f"done in {time.monotonic() - started:.1f} s")
    return 0


def main(argv: list[str] | None = None) -> int:
    """`python -m cfstack.link_bench` / `python benchmarks/link_bench.py`: command() with cfstack's error handling
    (a UserError is one line on stderr, never a traceback)."""
    try:
        return command(list(sys.argv[1:] if argv is None else argv))
    except UserError as err:
        print(f"link-bench: {err}", file=sys.stderr)
        return err.exit_code
    except KeyboardInterrupt:
        print("link-bench: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
