"""MAVLink 2, one of the link's codecs: framing, messages <-> link.messages, signing, .tlog logs.

Takes in: link.messages dataclasses (ENU/FLU, SI) and bytes from a transport.
Gives out: MAVLink 2 frames (NED/FRD on the wire: the conversion lives in codec.py and nowhere else),
decoded messages, signed frames (signing.py) and .tlog files readable by pymavlink's tools (tlog.py).
"""
