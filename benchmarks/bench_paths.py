"""Where the benchmarks find the course's world files (../shared/worlds beside the checkout), and where they
run `python -m cfstack` from.

Takes in: nothing.
Gives out: SHARED_WORLDS (a benchmark that needs it says so and measures what it can without it);
NEUTRAL_CWD.
"""

import tempfile
from pathlib import Path

SHARED_WORLDS = Path(__file__).resolve().parents[1].parent / "shared" / "worlds"
# `python -m cfstack` puts its working directory first on sys.path: run outside any tree, so a baseline's
# PYTHONPATH decides which cfstack runs (its emulator child included), never the directory it was started in
NEUTRAL_CWD = tempfile.gettempdir()
