"""What one send costs the sender on cfstack's zenoh transport, back to back and after an idle gap.

Takes in: --count sends per case (default 400).
Gives out: a table on stdout, one run: per gap between sends (0, 2 ms, 10 ms), the wall time of
ZenohTransport.send (p50 and mean, microseconds), with a subscriber in another process on loopback
TCP, as a flight has; beside it, the baseline: a bare UDP sendto of the same size on loopback after the
same gaps (what any first system call after a wait costs on this machine). The lockstep's critical
path (loop_bench) holds one such send per tick after the ground station's wait for the tick: the
command's (the ack right after it is a back-to-back send).
At 500 Hz that wait is short; at 100 Hz it is most of a millisecond.

Run: python benchmarks/put_after_idle_bench.py [--count N]
"""

from __future__ import annotations

import argparse
import socket
import statistics
import subprocess
import sys
import time

from link.transports import open_transport
from link.transports.base import free_loopback_port

KEY = "bench/put_after_idle"
GAPS_S = (0.0, 0.002, 0.01)
PAYLOAD = b"x" * 34  # a SET_ACTUATOR_CONTROL_TARGET frame's size
STOP = b"stop"


def subscriber(endpoint: str) -> None:
    """Take every sample until STOP (so the sender's samples have a remote subscriber to go to)."""
    rx = open_transport("zenoh", rx=KEY, listen=[endpoint], connect=[])
    print("ready", flush=True)
    while STOP not in rx.receive(1.0):
        pass
    rx.close()


def timed_sends(send, count: int, gap_s: float) -> list[float]:
    """Wall microseconds of `count` calls of send(), each after sleeping gap_s."""
    spent = []
    for _ in range(count):
        if gap_s:
            time.sleep(gap_s)
        start = time.perf_counter()
        send()
        spent.append((time.perf_counter() - start) * 1e6)
    return spent


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--count", type=int, default=400, help="sends per case")
    args = p.parse_args()
    endpoint = f"tcp/127.0.0.1:{free_loopback_port()}"
    child = subprocess.Popen([sys.executable, __file__, "--subscriber", endpoint], stdout=subprocess.PIPE, text=True)
    try:
        if child.stdout.readline().strip() != "ready":
            raise SystemExit("the subscriber did not start")
        tx = open_transport("zenoh", tx=KEY, connect=[endpoint], listen=[])
        if not tx.wait_for_subscribers(30.0):
            raise SystemExit(f"no subscriber on {KEY} within 30 s")
        sink = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        sink.bind(("127.0.0.1", 0))
        udp = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        address = sink.getsockname()
        print(f"{len(PAYLOAD)} B sends, {args.count} per case, wall microseconds p50 / mean: ZenohTransport.send "
              "to a subscriber in another process (loopback TCP), against a bare UDP sendto (loopback):")
        for gap_s in GAPS_S:
            zenoh_us = timed_sends(lambda: tx.send(PAYLOAD), args.count, gap_s)
            udp_us = timed_sends(lambda: udp.sendto(PAYLOAD, address), args.count, gap_s)
            print(f"  idle {gap_s * 1e3:4.0f} ms before each send: zenoh {statistics.median(zenoh_us):6.1f} / "
                  f"{statistics.mean(zenoh_us):6.1f}, UDP {statistics.median(udp_us):6.1f} / "
                  f"{statistics.mean(udp_us):6.1f}, zenoh / UDP (p50) "
                  f"{statistics.median(zenoh_us) / statistics.median(udp_us):4.1f}")
        udp.close()
        sink.close()
        tx.send(STOP)
        tx.close()
        child.wait(timeout=30)
    finally:
        if child.poll() is None:
            child.kill()
    return 0


if __name__ == "__main__":
    if sys.argv[1:2] == ["--subscriber"]:
        subscriber(sys.argv[2])
        sys.exit(0)
    sys.exit(main())
