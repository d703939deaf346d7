"""Child processes of the ground-station side (the fly launcher's emulator, the sweep's flights).

Takes in: nothing; used as subprocess.Popen(preexec_fn=die_with_parent).
Gives out: a child that Linux stops with SIGTERM when its parent dies, however the parent dies (a
SIGKILLed ground station leaves no orphaned emulator behind).
"""

from __future__ import annotations

import signal

PR_SET_PDEATHSIG = 1  # prctl option: the signal the child gets when its parent thread exits (linux/prctl.h)


def die_with_parent() -> None:
    """In the child, between fork and exec: ask Linux for SIGTERM when the parent dies."""
    try:
        import ctypes

        ctypes.CDLL("libc.so.6", use_errno=True).prctl(PR_SET_PDEATHSIG, signal.SIGTERM)
    except (OSError, AttributeError):  # not Linux: the parent stops its children itself, as usual
        pass
