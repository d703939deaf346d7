"""The MAVLink encoder of a lockstep tick's messages, compiled (issue 19): Codec.encode of ImuSample, MocapPose,
ExternalPose, TruthState, ThrustMoment and AttitudeTarget, unsigned.

Takes in: link.mavlink.codec configures it once with its own constants (`configure`: sqrt(1/2), and per wire the
message id, CRC_EXTRA and the fixed bytes after the state); then, per frame, the kind (its index in KINDS), the
message, the sequence number, source system id, component id, target system and the codec's limits (max
moments and max thrust as four floats, or None).
Gives out: `encode_frame`, the compiled kernel (link/mavlink/_frame_kernel.c, built by `pip install`), or None
where it was not built; it returns the frame's bytes, or None for a message it leaves to the Python (see the C
file's header), having changed nothing.

The Python is codec.py's encoders and Codec._wrap; the kernel gives their bytes (tests/link/test_frame_kernel.py).
Why compiled: the emulator encodes about eleven of these frames per 100 Hz tick (42 us of its main thread per
tick, a throwaway timing of the matched floor), the ground station one or two on its critical path.
"""

from __future__ import annotations

try:
    from link.mavlink._frame_kernel import configure, encode_frame
except ImportError:  # not built (no C compiler at install): the codec runs its Python, same bytes, slower
    configure = encode_frame = None

COMPILED = encode_frame is not None
# The kinds, in _frame_kernel.c's order (its enum)
KINDS = ("imu", "mocap", "external_pose", "truth", "thrust_moment", "attitude_target")
