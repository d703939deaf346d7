"""Fixtures every test folder can use.

Takes in: nothing.
Gives out: `shared_worlds`, the folder of the course's world files (../shared/worlds beside the
checkout), skipping the test with the reason when it is absent.
"""

from __future__ import annotations

from pathlib import Path

import pytest
from testsupport import ABSENT_REASON, SHARED_WORLDS, shared_worlds_present


@pytest.fixture
def shared_worlds() -> Path:
    if not shared_worlds_present():
        pytest.skip(ABSENT_REASON)
    return SHARED_WORLDS
