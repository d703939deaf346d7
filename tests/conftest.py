"""Fixtures every test folder can use.

Takes in: nothing.
Gives out: `shared_worlds`, the folder of the course's world files (../shared/worlds beside the
checkout), skipping the test with the reason when it is absent; `short_tempdir`, a fresh folder right under the
system's temporary folder, made tempfile's folder for the test.
"""

from __future__ import annotations

import shutil
import tempfile
from collections.abc import Iterator
from pathlib import Path

import pytest
from testsupport import ABSENT_REASON, SHARED_WORLDS, shared_worlds_present


@pytest.fixture
def shared_worlds() -> Path:
    if not shared_worlds_present():
        pytest.skip(ABSENT_REASON)
    return SHARED_WORLDS


@pytest.fixture
def short_tempdir(monkeypatch) -> Iterator[Path]:
    """A fresh folder right under the system's temporary folder, tempfile's folder while the test runs, removed
    after it. For tests of the private endpoint's Unix socket, whose path must fit in 103 bytes
    (link.transports.zenoh_session.UNIX_SOCKET_PATH_MAX_BYTES): under pytest's tmp_path
    (/tmp/pytest-of-USER/pytest-N/<test name>0/) only a few bytes were left, and a path that grew by 8 went over."""
    folder = Path(tempfile.mkdtemp(prefix="cfst-", dir=tempfile.gettempdir()))
    monkeypatch.setattr(tempfile, "tempdir", str(folder))
    yield folder
    shutil.rmtree(folder, ignore_errors=True)
