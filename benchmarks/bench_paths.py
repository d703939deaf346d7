"""Where the benchmarks find the course's world files: ../shared/worlds beside the checkout.

Takes in: nothing.
Gives out: SHARED_WORLDS (a benchmark that needs it says so and measures what it can without it).
"""

from pathlib import Path

SHARED_WORLDS = Path(__file__).resolve().parents[1].parent / "shared" / "worlds"
