"""Where a lockstep tick's wall time goes, from both processes' clocks (issue 19).

Takes in: the flight mode (--mode), how many flights (--flights), and what a second flight of each pair leaves
out, flown interleaved with the first: --without-bookkeeping, the ground station's work after the ack (truth,
log row, flight record); --without-truth, the truth channel itself (the emulator publishes no truth state, so
the ground station neither waits for, receives nor decodes any; crash reports still go); both, both. These are
what-ifs, not flights anyone would fly (their grade is meaningless). --floor flies loop_bench's matched floor
(the emulator against the zero-work responder flying the mode's own command) twice before and twice after each
flight (or pair of flights).
Gives out: per flight, medians (and quartiles) of one lockstep cycle's parts, in us:
- P: the ground station's tick record taken -> its ack sent (its critical path, as the summary's);
- ack hop: ack sent -> the emulator handling it;
- E: the emulator handling the ack of tick k -> having published the record of tick k + n (its physics
  steps, its frames, the record), n = the ticks one emulator round covers (2 when its lookahead covers a
  whole tick, as at 500 Hz; else 1);
- record hop: that record published -> the ground station holding it, over the ticks the ground station
  blocked for (its record was not in when it asked);
- of those, the share whose record was published before the ground station started to block, and for how
  long it had been busy since; then the hop counted from when both were ready (the later of the two).
With --floor, each flight's real-time factor (its ticks at the mode's rate over the loop's wall time) as a
share of the median of its four floor runs (loop_bench's "new/matched"), and the medians (range) of those shares
over the flights. The stamps cost the flights a little (below), not the floor runs.
When the ground station waits for each record, n ticks take ack hop + E + record hop + P: the line "n x period"
checks that against the measured period. Plus the summary's wall time per tick, the flight loop thread's CPU
and the record wait per tick.

How: the flights run as `cfstack fly` processes (the emulator is its child) with a sitecustomize on PYTHONPATH
that wraps LockstepClock.release/_next_tick in the ground station and Lockstep.handle/LockstepClock.publish_tick
in the emulator, stamping CLOCK_MONOTONIC (one clock for every process on a machine), and each process writes
its stamps at exit. A stamp costs about 0.4 us (timeit, here); each process takes two or three per tick, and
the emulator unpacks each ack once more.

Usage: python benchmarks/lockstep_hops.py [--mode moments|attitude] [--flights N] [--without-bookkeeping]
                                         [--without-truth] [--floor]
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
from pathlib import Path
from tempfile import TemporaryDirectory

# this folder: `cfstack ... --json` in a child process; the floor and its target
from loop_bench import FLOOR_SHARE_TARGET, cfstack, matched_floor_run

from groundstation.clocks import DEFAULT_RATE_HZ
from groundstation.logread import read_log

STAMPS_ENV = "CFSTACK_HOPS_STAMPS"  # the prefix of the stamp files each process writes
SKIP_ENV = "CFSTACK_HOPS_LEAVE_OUT"  # what the second flight of a pair leaves out: "bookkeeping", "truth" or both
LEAVE_OUT = ("bookkeeping", "truth")
WARM_UP_TICKS = 100  # the first ticks (start-up, arming) are left out

# Installed as sitecustomize.py in both processes. It patches a module when it is first imported (a meta-path
# finder wraps the loader), so neither process imports anything it would not have imported anyway.
SITECUSTOMIZE = '''
import atexit, importlib.machinery, json, os, sys, time

_OUT = os.environ.get("@STAMPS_ENV@")
_LEFT_OUT = set(filter(None, os.environ.get("@SKIP_ENV@", "").split(",")))
if _OUT:
    _stamps = {}
    _clock = time.monotonic

    def _stamp(kind, tick, value=None):
        _stamps.setdefault(kind, {}).setdefault(tick, _clock() if value is None else value)

    def _ground_station(clocks):
        cls = clocks.LockstepClock
        release, next_tick = cls.release, cls._next_tick

        def timed_release(self, next_wakeup_s):
            release(self, next_wakeup_s)
            _stamp("ack_sent", self.tick)

        def timed_next_tick(self):
            if not self._ticks:
                self._take_ticks(0.0)
            blocked_at = None if self._ticks else _clock()
            tick = next_tick(self)
            _stamp("record_taken", tick.tick)
            if blocked_at is not None:
                _stamp("blocked_at", tick.tick, blocked_at)
            return tick
        cls.release, cls._next_tick = timed_release, timed_next_tick
        atexit.register(_dump, "groundstation")

    def _flight(flight):
        if "bookkeeping" in _LEFT_OUT:
            flight.FlightLoop.write_row = lambda self, now, step, out: None
            flight.FlightLoop.absorb_truth = lambda self: None

    def _vehicle_sim(vehicle_sim):
        if "truth" in _LEFT_OUT:  # keep the truth schedule, publish nothing on it
            assert callable(vehicle_sim.SimVehicle._emit_truth)  # renamed: fail here, not fly with truth
            vehicle_sim.SimVehicle._emit_truth = lambda self, t: self._truth.advance(t)

    def _emulator(lockstep):
        from link.clock import unpack_ack
        handle, publish = lockstep.Lockstep.handle, lockstep.LockstepClock.publish_tick

        def timed_handle(self, vehicle_id, data, *args):
            ack = unpack_ack(data)
            if ack is not None:
                _stamp("ack_handled", ack.tick)
            return handle(self, vehicle_id, data, *args)

        def timed_publish(self, n):
            publish(self, n)
            _stamp("published", self.tick)
        lockstep.Lockstep.handle, lockstep.LockstepClock.publish_tick = timed_handle, timed_publish
        atexit.register(_dump, "emulator")

    def _dump(role):
        with open(f"{_OUT}.{role}.{os.getpid()}.json", "w") as f:
            json.dump(_stamps, f)

    _PATCHES = {"groundstation.clocks": _ground_station, "groundstation.flight": _flight,
                "simulator.lockstep": _emulator, "simulator.vehicle_sim": _vehicle_sim}

    class _Patcher:
        @staticmethod
        def find_spec(name, path=None, target=None):
            if name not in _PATCHES:
                return None
            spec = importlib.machinery.PathFinder.find_spec(name, path)
            if spec is None or spec.loader is None:
                return None
            run = spec.loader.exec_module

            def exec_module(module):
                run(module)
                _PATCHES[name](module)
            spec.loader.exec_module = exec_module
            return spec
    sys.meta_path.insert(0, _Patcher)
'''.replace("@STAMPS_ENV@", STAMPS_ENV).replace("@SKIP_ENV@", SKIP_ENV)


def fly(mode: str, folder: Path, index: int, left_out: tuple[str, ...] = ()) -> dict:
    """One `cfstack fly` circle with stamps, leaving out what `left_out` names (LEAVE_OUT); returns its summary's
    timing and both processes' stamps."""
    prefix = folder / f"stamps{index}"
    env = dict(os.environ, **{STAMPS_ENV: str(prefix), SKIP_ENV: ",".join(left_out)})
    env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(folder), env.get("PYTHONPATH")]))
    log = folder / f"log{index}"
    timing = cfstack("fly", "--trajectory", "circle", "--mode", mode, "--log", str(log), env=env)["timing"]
    if "bookkeeping" not in left_out and read_log(log).has_truth == ("truth" in left_out):
        raise SystemExit(f"lockstep_hops: flight {index} {'logged' if 'truth' in left_out else 'did not log'} truth, "
                         "against what it was to leave out")
    stamps = {}
    for role in ("groundstation", "emulator"):
        files = list(folder.glob(f"stamps{index}.{role}.*.json"))
        if len(files) != 1:
            raise SystemExit(f"lockstep_hops: expected one {role} stamp file, found {len(files)}")
        stamps[role] = {kind: {int(k): v for k, v in by_tick.items()}
                        for kind, by_tick in json.loads(files[0].read_text()).items()}
    return {"timing": timing, **stamps}


def quartiles_us(values: list[float]) -> tuple[float, float, float]:
    q1, q2, q3 = statistics.quantiles(values, n=4)
    return q1 * 1e6, q2 * 1e6, q3 * 1e6


def cycle(flown: dict) -> dict:
    """The cycle's parts (module docstring) from one flight's stamps, each as (q1, median, q3) us."""
    gs, emu = flown["groundstation"], flown["emulator"]
    sent, taken, blocked_at = gs["ack_sent"], gs["record_taken"], gs.get("blocked_at", {})
    handled, published = emu["ack_handled"], emu["published"]
    ticks = sorted(k for k in sent if k >= WARM_UP_TICKS and k in taken and k in handled)
    if not ticks:
        raise SystemExit(f"lockstep_hops: no tick after the first {WARM_UP_TICKS} has stamps from both processes")
    # n: 2 when the emulator mostly published tick k + 1 before it handled the ack of tick k (lookahead)
    ahead = sum(published.get(k + 1, float("inf")) < handled[k] for k in ticks) / len(ticks)
    n = 2 if ahead > 0.5 else 1
    rounds = [k for k in ticks if k + n in published and k + n in taken]
    waited = [k for k in rounds if k + n in blocked_at]
    early = [k for k in waited if published[k + n] < blocked_at[k + n]]
    parts = {
        "P": [sent[k] - taken[k] for k in ticks],
        "ack hop": [handled[k] - sent[k] for k in ticks],
        "E": [published[k + n] - handled[k] for k in rounds],
        "record hop": [taken[k + n] - published[k + n] for k in waited],
        "busy before blocking": [blocked_at[k + n] - published[k + n] for k in early],
        "hop once both ready": [taken[k + n] - max(published[k + n], blocked_at[k + n]) for k in waited],
        "period": [(sent[k + n] - sent[k]) / n for k in rounds if k + n in sent],
    }
    return {"n": n, "lookahead share": ahead, "blocked share": len(waited) / len(rounds),
            "published before blocking": len(early) / max(1, len(waited)),
            **{name: quartiles_us(values) for name, values in parts.items() if len(values) >= 2}}


def report(label: str, flown: dict) -> None:
    parts, timing = cycle(flown), flown["timing"]
    wall_us = timing["loop_wall_s"] / timing["ticks"] * 1e6
    print(f"  {label}: wall {wall_us:.0f} us/tick, loop thread CPU {timing['loop_thread_cpu_us_per_tick']:.0f}, "
          f"record wait {timing['tick_record_wait_us_mean']:.0f}; n = {parts['n']} (tick k + 1 out before the ack "
          f"of k: {parts['lookahead share']:.0%}); ground station blocked for {parts['blocked share']:.0%} of "
          f"records, {parts['published before blocking']:.0%} of those published before it blocked")
    for name in ("P", "ack hop", "E", "record hop", "busy before blocking", "hop once both ready", "period"):
        if name in parts:
            q1, q2, q3 = parts[name]
            print(f"    {name:22} median {q2:5.0f} us  (quartiles {q1:.0f}-{q3:.0f})")
    medians = {name: parts[name][1] for name in ("P", "ack hop", "E", "record hop") if name in parts}
    if len(medians) == 4 and "period" in parts:
        print(f"    {parts['n']} x period = {parts['n'] * parts['period'][1]:.0f} us against ack hop + E + record hop"
              f" + P = {sum(medians.values()):.0f} us (medians)")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--mode", choices=("moments", "attitude"), default="moments")
    parser.add_argument("--flights", type=int, default=2)
    parser.add_argument("--without-bookkeeping", action="store_true",
                        help="also fly each flight without the work after the ack (truth, log row, record)")
    parser.add_argument("--without-truth", action="store_true",
                        help="also fly each flight without the truth channel (the emulator publishes no truth)")
    parser.add_argument("--floor", action="store_true",
                        help="also fly the matched floor around each flight and give each flight's share of it")
    args = parser.parse_args()
    sys.stdout.reconfigure(line_buffering=True)  # each flight's lines before the next one's progress
    if args.flights < 1:
        parser.error("--flights must be at least 1")
    left_out = tuple(name for name in LEAVE_OUT if getattr(args, f"without_{name}"))
    arms = [False, True] if left_out else [False]
    without = " without " + " or ".join(left_out)  # the second flight's label
    with TemporaryDirectory() as tmp:
        folder = Path(tmp)
        (folder / "sitecustomize.py").write_text(SITECUSTOMIZE)
        print(f"lockstep cycle of the {args.mode} circle (cfstack fly, this tree), {args.flights} flight(s)"
              + (f", each also{without}" if left_out else ""))
        shares = {arm: [] for arm in arms}
        for i in range(args.flights):
            floors = matched_floor(args.mode) if args.floor else []
            flown = {}
            for skip in arms if i % 2 == 0 else arms[::-1]:  # interleaved: the machine's load drifts
                index = 2 * i + skip
                print(f"  flying {i + 1}/{args.flights}{without if skip else ''}", file=sys.stderr, flush=True)
                flown[skip] = fly(args.mode, folder, index, left_out if skip else ())
                report(f"flight {i + 1}{without if skip else ''}", flown[skip])
            if args.floor:
                floors += matched_floor(args.mode)
                floor = statistics.median(floors)
                print(f"  matched floor {floor:.2f}x (runs {', '.join(f'{rtf:.1f}x' for rtf in floors)})")
                for skip in arms:
                    rtf = ticks_rtf(flown[skip]["timing"], args.mode)
                    shares[skip].append(rtf / floor)
                    print(f"  flight {i + 1}{without if skip else ''}: {rtf:.2f}x, {rtf / floor:.0%} of the matched "
                          "floor")
        if args.floor:
            for skip in arms:
                print(f"{without.strip() if skip else 'as it is'}: {statistics.median(shares[skip]):.0%} "
                      f"({min(shares[skip]):.0%}-{max(shares[skip]):.0%}) of the matched floor, median (range) "
                      f"over {args.flights} flight(s); target {FLOOR_SHARE_TARGET:.0%} (issue 19)")
    return 0


def ticks_rtf(timing: dict, mode: str) -> float:
    """Simulated s (ticks at the mode's rate) per wall s of the flight loop: the summary's real_time_factor takes
    the simulated time from the flight record, which a flight without bookkeeping does not keep."""
    return timing["ticks"] / DEFAULT_RATE_HZ[mode] / timing["loop_wall_s"]


def matched_floor(mode: str, runs: int = 2) -> list[float]:
    """Real-time factors of `runs` of loop_bench's matched floor runs."""
    print(f"  flying the matched floor ({runs} runs)", file=sys.stderr, flush=True)
    return [matched_floor_run(mode)["rtf"] for _ in range(runs)]


if __name__ == "__main__":
    sys.exit(main())
