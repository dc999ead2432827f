"""The pinch input node: ``facesculpt run pinch`` (beside ``facesculpt run hands``).

Turns ``hands/landmarks`` into ``input/events`` with :class:`.pinch_gesture.PinchTracker`: a
pinch (thumb and index tips together) is a press at the pinch point, moving the pinched hand
drags, bringing it closer or farther pushes the point along the view ray (depth), opening the
hand releases; two hands hold two handles. On stopping it releases what it holds.
"""

from __future__ import annotations

import time

from facesculpt.msgs import HandLandmarks, InputEvent
from facesculpt.runtime.node import Node
from facesculpt.runtime.parameters import ConfigurationError, Param
from facesculpt.runtime.qos import EVENTS

from .pinch_gesture import PinchConfig, PinchTracker


class PinchNode(Node):
    """Publishes press / drag / depth / release on input/events from hands/landmarks."""

    NAME = "pinch"
    TOPICS = ("input/events", "hands/landmarks")
    PARAMS = {
        "close_ratio": Param(0.25, "thumb-index tip distance / hand size below which a pinch closes",
                             range=(0.01, 2.0)),
        "open_ratio": Param(0.40, "tip distance / hand size above which it opens (above close_ratio)",
                            range=(0.01, 2.0)),
        "depth_mm": Param(60.0, "depth per unit of ln(hand size change), mm (+: a nearer hand pulls toward the "
                                "camera)", range=(0.0, 1000.0)),
        "min_move_px": Param(0.5, "the least pinch-point move sent as a drag, px", range=(0.0, 100.0)),
        "min_depth_mm": Param(0.5, "the least depth step sent, mm", range=(0.0, 100.0)),
        "min_cutoff_hz": Param(1.0, "One Euro filter cutoff of a still hand, Hz (lower: steadier, more lag)",
                               range=(0.01, 100.0)),
        "beta": Param(0.05, "One Euro filter speed coefficient, 1/px (higher: less lag when moving fast)",
                      range=(0.0, 10.0)),
        "max_missing": Param(3, "frames a pinching hand may be missing before it releases", range=(0, 1000)),
        "first_handle": Param(3, "handle id of the first hand (the second is +1; the mouse is 0, the joystick 1, "
                                 "scripts 2)", range=(0, None)),
    }

    def setup(self):
        p = self.params
        config = PinchConfig(close_ratio=p.close_ratio, open_ratio=p.open_ratio, depth_mm=p.depth_mm,
                             min_move_px=p.min_move_px, min_depth_mm=p.min_depth_mm,
                             min_cutoff_hz=p.min_cutoff_hz, beta=p.beta, max_missing=p.max_missing,
                             first_handle=p.first_handle)
        try:
            self.tracker = PinchTracker(config)
        except ValueError as exc:
            raise ConfigurationError(str(exc)) from None
        self.events = self.advertise("input/events", InputEvent, qos=EVENTS)
        self.subscribe("hands/landmarks", HandLandmarks, self.on_hands)

    def on_hands(self, msg: HandLandmarks) -> None:
        for event in self.tracker.update(msg.points, msg.track_ids, msg.stamp * 1e-9):
            event.stamp = msg.stamp  # exactly the frame's (seconds as a float lose the last digits of ns)
            self.events.publish(event)
            self.count(event.kind)

    def teardown(self) -> None:
        for event in self.tracker.release_all(time.time_ns() * 1e-9):
            self.events.publish(event)


if __name__ == "__main__":
    PinchNode.main()
