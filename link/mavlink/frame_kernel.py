"""MAVLink frames, compiled (issue 19): the encoder of a lockstep tick's messages (Codec.encode of ImuSample,
MocapPose, ExternalPose, TruthState, ThrustMoment and AttitudeTarget, unsigned) and the parser of frames that
need no signature check (FrameParser._scan).

Takes in: link.mavlink.codec configures both once with its own constants (`configure`: sqrt(1/2), and per wire the
message id, CRC_EXTRA and the fixed bytes after the state; `configure_parser`: the decoders the parser runs natively,
the messages they make, the ground station's system id and MAV_FRAME_LOCAL_NED, and per message its
codec.direct_fields: made as its __init__ would make it, without running it). Then `encode_frame` takes the kind
(its index in KINDS), the message, the sequence number, source system id, component id, target system and the
codec's limits (max moments and max thrust as four floats, or None); `parse_frames` takes the parser, the bytes
to scan (its pending bytes first) and whether they end a datagram.
Gives out: the compiled kernels (link/mavlink/_frame_kernel.c, built by `pip install`), or None where they were not
built. encode_frame returns the frame's bytes, or None for a message it leaves to the Python (see the C file's
header), having changed nothing; parse_frames returns the fields of each frame, as FrameParser._scan's tuples, and
the position it scanned to, counting into the parser's counters and calling its `_undelivered` as the Python does.

The Python is codec.py's encoders with Codec._wrap, and FrameParser._scan with codec.py's decoders; the kernels
give their bytes, messages and counts (tests/link/test_frame_kernel.py). Why compiled: the emulator encodes about
eleven frames per 100 Hz tick (42 us of its main thread per tick, a throwaway timing of the matched floor), and
the ground station decodes six per 100 Hz tick on its critical path (the parser was 13.3 of the 28.9 us that
Endpoint.deliver took per six-frame chunk, warm: a throwaway timing).
"""

from __future__ import annotations

try:
    from link.mavlink._frame_kernel import configure, configure_parser, encode_frame, parse_frames
except ImportError:  # not built (no C compiler at install): the codec runs its Python, same bytes, slower
    configure = configure_parser = encode_frame = parse_frames = None

COMPILED = encode_frame is not None
# The kinds, in _frame_kernel.c's order (its enum)
KINDS = ("imu", "mocap", "external_pose", "truth", "thrust_moment", "attitude_target")
