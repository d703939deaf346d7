"""Endpoint.deliver's per-frame work, compiled (issue 19): count the frame into the endpoint's LinkStats (frames,
bytes, one-way age, sequence verdict), append it to the tlog, and make its Received.

Takes in: link.endpoint configures it once with Received and the constants of link.stats and link.mavlink.tlog;
then `deliver_fields` takes the parser's fields of each frame, the stats, the tlog (or None), the receive time and
the list to append the Received records to.
Gives out: the compiled kernel (link/_deliver_kernel.c, built by `pip install`), or None where it was not built;
link.endpoint.deliver_fields is its Python twin, with the same records, counts and tlog records
(tests/link/test_deliver_kernel.py).

Why compiled: the ground station delivers about six frames per 100 Hz tick on its critical path, and per frame the
Python of this work took longer than the compiled parser (1.5 us against 1.0 per frame of a six-frame chunk, warm:
a throwaway timing), and more after the wake-up that starts each tick, when the caches are cold.
"""

from __future__ import annotations

try:
    from link._deliver_kernel import configure, deliver_fields
except ImportError:  # not built (no C compiler at install): the endpoint runs its Python, same results, slower
    configure = deliver_fields = None

COMPILED = deliver_fields is not None
