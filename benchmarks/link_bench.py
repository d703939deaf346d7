"""Benchmark of the link: round trip, throughput and codec cost against bare zenoh and bare UDP.

Takes in: the options of `cfstack link-bench` (--count, --frames, --blocks, --quick).
Gives out: the table of cfstack.link_bench (baselines and ratios in the same run, PASS/MISS per target); exit 0.
A thin wrapper: everything lives in cfstack.link_bench. Run: python benchmarks/link_bench.py [--quick]
"""

from __future__ import annotations

import sys

from cfstack.link_bench import main

if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
