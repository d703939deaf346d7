"""cfstack link: what crosses between processes, and nothing else.

Holds: the message schema both codecs speak (link.messages: plain dataclasses, ENU/FLU, SI units), the
codecs (link.mavlink: MAVLink 2 with signing and the .tlog format), the transports chosen by
connection string (link.transports: zenoh, UDP, serial, in-memory), the zenoh keys and system ids
(link.keys), the lockstep clock messages (link.clock), endpoints and link statistics (link.endpoint,
link.stats).
Takes in: typed messages and raw frames from transports.
Gives out: frames on a transport, decoded messages, link statistics, logs.
May import: model (frames, errors). pymavlink and zenoh are imported here and nowhere else.
"""
