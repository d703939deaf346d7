"""CRTP round trip (issue 16): the emulator's link echo over UDP against a bare UDP echo, in the same run.

Prints, from one run:
1. the round trip of a CRTP link echo (port 15, channel 0: what cflib's latency ping sends) to a
   `cfstack emulator` serving CRTP (realtime clock: the echo is answered between physics steps), p50/p99,
   with the ideal radio (the service's own cost) and with the crazyradio profile (its air time and latency,
   both ways);
2. the round trip of the same datagram through a bare UDP echo process (the floor of any UDP service here);
3. cflib's own connect time (scan excluded): SyncCrazyflie open with the TOCs downloaded, then all
   parameter values read, cold (no TOC cache) and warm (cache filled by the first connect);
4. lockstep speed of the ground station's cflib path (`--link crtp`, over zenoh) against its MAVLink path:
   `cfstack fly --trajectory circle --mode M --link L --json`, the flight loop's real-time factor (the
   summary's timing.real_time_factor), attitude and moments mode, the two links alternating flight by
   flight in the same run; median per path and the ratio cflib / MAVLink.

Usage: python benchmarks/crtp_bench.py [--count N] [--flights N]
"""

from __future__ import annotations

import argparse
import json
import signal
import socket
import subprocess
import sys
import tempfile
import time
import uuid

import numpy as np
from loop_bench import bare_udp_rtt_ms  # this folder (python puts it on sys.path)

from link.transports.base import free_loopback_port

ECHO = bytes((0xFC,)) + b"cfstack-crtp-echo"  # 15:0 with the legacy bits, as cflib sends it


def start_emulator(port: int, radio: str) -> subprocess.Popen:
    proc = subprocess.Popen([sys.executable, "-m", "cfstack", "emulator", "--crtp-port", str(port), "--radio", radio,
                             "--listen",
                             f"tcp/127.0.0.1:{free_loopback_port()}", "--id", f"b{uuid.uuid4().hex[:8]}", "--quiet"],
                            stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        sock.settimeout(0.2)
        for _ in range(300):
            sock.sendto(b"\xff", ("127.0.0.1", port))
            try:
                sock.recvfrom(64)
                return proc
            except OSError:
                continue
    proc.kill()
    raise SystemExit("the emulator did not answer CRTP within 60 s")


def crtp_echo_rtt_ms(port: int, count: int) -> np.ndarray:
    out = []
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        sock.connect(("127.0.0.1", port))
        sock.settimeout(2.0)
        for _ in range(count):
            t0 = time.perf_counter()
            sock.send(ECHO)
            while sock.recv(64)[1:] != ECHO[1:]:  # a log block could come between (none are running here)
                pass
            out.append((time.perf_counter() - t0) * 1e3)
    return np.array(out)


def cflib_connect_s(uri: str, cache: str | None) -> tuple[float, float]:
    from cflib.crazyflie import Crazyflie
    from cflib.crazyflie.syncCrazyflie import SyncCrazyflie

    t0 = time.perf_counter()
    scf = SyncCrazyflie(uri, cf=Crazyflie(rw_cache=cache))
    scf.open_link()
    connected = time.perf_counter() - t0
    scf.wait_for_params()
    fully = time.perf_counter() - t0
    scf.close_link()
    return connected, fully


def lockstep_rtf(mode: str, link: str) -> float:
    """The flight loop's real-time factor of one lockstep circle (a private zenoh endpoint: fly's own child)."""
    run = subprocess.run([sys.executable, "-m", "cfstack", "fly", "--trajectory", "circle", "--mode", mode,
                          "--link", link, "--id", f"b{uuid.uuid4().hex[:8]}", "--json"],
                         capture_output=True, text=True, timeout=600)
    if run.returncode != 0:
        raise SystemExit(f"fly --link {link} --mode {mode} failed: {run.stderr.strip().splitlines()[-1]}")
    return float(json.loads(run.stdout)["timing"]["real_time_factor"])


def lockstep_paths(flights: int) -> None:
    for mode in ("attitude", "moments"):
        rtf: dict[str, list[float]] = {"crtp": [], "mavlink": []}
        for i in range(flights):
            for link in ("crtp", "mavlink") if i % 2 == 0 else ("mavlink", "crtp"):
                rtf[link].append(lockstep_rtf(mode, link))
        cflib, mavlink = (float(np.median(rtf[k])) for k in ("crtp", "mavlink"))
        print(f"lockstep circle, {mode} mode, {flights} flights each: cflib path {cflib:.2f}x real time "
              f"({', '.join(f'{v:.2f}' for v in rtf['crtp'])}), MAVLink path {mavlink:.2f}x "
              f"({', '.join(f'{v:.2f}' for v in rtf['mavlink'])}); ratio cflib / MAVLink {cflib / mavlink:.2f}")


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--count", type=int, default=2000, help="round trips per measurement")
    p.add_argument("--flights", type=int, default=3, help="lockstep flights per path and mode (0: skip)")
    args = p.parse_args()
    bare = bare_udp_rtt_ms(len(ECHO), args.count)
    for radio in ("ideal", "crazyradio"):  # the cflib connect below runs on the last: the default radio
        port = free_loopback_port(socket.SOCK_DGRAM)
        emulator = start_emulator(port, radio)
        crtp = crtp_echo_rtt_ms(port, args.count)
        print(f"CRTP link echo to the emulator, {radio} radio ({len(ECHO)} B, {args.count} round trips): "
              f"p50 {np.percentile(crtp, 50):.3f} ms, p99 {np.percentile(crtp, 99):.3f} ms; ratio to a bare UDP "
              f"echo p50 {np.percentile(crtp, 50) / np.percentile(bare, 50):.2f}x, "
              f"p99 {np.percentile(crtp, 99) / np.percentile(bare, 99):.2f}x")
        if radio != "crazyradio":
            emulator.send_signal(signal.SIGINT)
            emulator.wait(timeout=30)
    print(f"bare UDP echo, same size, same run: p50 {np.percentile(bare, 50):.3f} ms, "
          f"p99 {np.percentile(bare, 99):.3f} ms")
    try:
        try:
            import cflib.crtp
        except ImportError:
            print("cflib not installed (pip install 'cfstack[cflib]'): connect times skipped")
            return 0
        cflib.crtp.init_drivers()
        with tempfile.TemporaryDirectory() as cache:
            for label in ("cold (no TOC cache)", "warm (TOC cache)"):
                connected, fully = cflib_connect_s(f"udp://127.0.0.1:{port}", cache)
                print(f"cflib connect, {label}: TOCs {connected * 1e3:.1f} ms, all parameter values "
                      f"{fully * 1e3:.1f} ms")
    finally:
        emulator.send_signal(signal.SIGINT)
        emulator.wait(timeout=30)
    if args.flights > 0:
        lockstep_paths(args.flights)
    return 0


if __name__ == "__main__":
    sys.exit(main())
