"""Delivery options of a topic as one profile object (as rclpy's ``QoSProfile``).

A :class:`QoSProfile` is given to ``Node.advertise(topic, type, qos=...)`` and
``Node.subscribe(topic, type, callback, qos=...)``. Each policy acts where ZeroMQ lets it act:

* ``history`` and ``depth``, at the subscription: ``KEEP_LAST`` keeps only the newest message
  (a slow callback always gets the freshest one and nothing piles up; depth 1),
  ``KEEP_ALL`` queues every message in order, dropping the oldest beyond ``depth``.
* ``reliability``, at the publisher: ``BEST_EFFORT`` drops a message for a subscriber whose
  queue is full (a slow peer never slows the publisher); ``RELIABLE`` blocks the publish
  instead (up to its timeout) and flushes what is queued before the publisher closes.
* ``durability``, at the publisher: ``TRANSIENT_LOCAL`` has the master keep the last message
  for subscribers that join later (ROS 1's latch); ``VOLATILE`` keeps nothing.
* ``hwm``: the ZeroMQ high-water mark (messages) of the socket the profile is used on (the
  publisher's send queue per subscriber, or the subscription's receive queue); ``None``: the
  default for the type and policies (see :mod:`facesculpt.runtime.pubsub`).

The presets are the profiles the graph uses (docs/architecture.md, "Parameters and QoS").
"""

from __future__ import annotations

import enum
from dataclasses import dataclass

# Queue bound of a KEEP_ALL subscription unless a depth is given (messages).
DEFAULT_QUEUE_DEPTH = 10000


class History(enum.Enum):
    KEEP_LAST = "keep_last"   # newest message only
    KEEP_ALL = "keep_all"     # every message, in order, up to the depth


class Reliability(enum.Enum):
    BEST_EFFORT = "best_effort"   # drop when the peer is slow
    RELIABLE = "reliable"         # block the publisher when the peer is slow


class Durability(enum.Enum):
    VOLATILE = "volatile"                 # late joiners get the next message
    TRANSIENT_LOCAL = "transient_local"   # late joiners get the last one (kept by the master)


@dataclass(frozen=True)
class QoSProfile:
    """The delivery options of one publisher or subscription (see the module docstring).

    ``depth``: the queue bound of ``KEEP_ALL`` (messages, >= 1; default
    :data:`DEFAULT_QUEUE_DEPTH`); ``KEEP_LAST`` keeps the newest message only, so its depth
    is 1. ``hwm``: ZeroMQ high-water mark in messages (>= 1) or ``None`` for the default.
    """

    history: History = History.KEEP_LAST
    depth: int | None = None
    reliability: Reliability = Reliability.BEST_EFFORT
    durability: Durability = Durability.VOLATILE
    hwm: int | None = None

    def __post_init__(self):
        for name, kind in (("history", History), ("reliability", Reliability), ("durability", Durability)):
            if not isinstance(getattr(self, name), kind):
                raise TypeError(f"QoSProfile.{name} must be a {kind.__name__}, got {getattr(self, name)!r}")
        keep_all = self.history is History.KEEP_ALL
        depth = self.depth if self.depth is not None else (DEFAULT_QUEUE_DEPTH if keep_all else 1)
        if not _positive_int(depth):
            raise ValueError(f"QoSProfile.depth must be an integer >= 1, got {self.depth!r}")
        if not keep_all and depth != 1:
            raise ValueError(f"QoSProfile.depth {depth}: KEEP_LAST keeps the newest message only (depth 1); "
                             f"use KEEP_ALL to queue")
        if self.hwm is not None and not _positive_int(self.hwm):
            raise ValueError(f"QoSProfile.hwm must be an integer >= 1 or None, got {self.hwm!r}")
        object.__setattr__(self, "depth", depth)

    @property
    def keep_all(self) -> bool:
        return self.history is History.KEEP_ALL

    @property
    def reliable(self) -> bool:
        return self.reliability is Reliability.RELIABLE

    @property
    def latched(self) -> bool:
        return self.durability is Durability.TRANSIENT_LOCAL


def _positive_int(value) -> bool:
    return isinstance(value, int) and not isinstance(value, bool) and value >= 1


# Streams where only the newest message matters (images, landmarks, states): the default.
SENSOR_DATA = QoSProfile()
# Every message in order, none dropped by the publisher (input events, bag playback).
EVENTS = QoSProfile(history=History.KEEP_ALL, reliability=Reliability.RELIABLE)
# State a late joiner needs at once (face/model, face/deformation).
LATCHED = QoSProfile(durability=Durability.TRANSIENT_LOCAL)
# Every message in order on a best-effort stream (recording, echo, tests that count messages).
EVERY_MESSAGE = QoSProfile(history=History.KEEP_ALL)
