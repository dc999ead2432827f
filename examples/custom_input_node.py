"""Your own input node in a few lines: wiggle the nose tip left and right.

Start a graph (`facesculpt launch ...` with a deformer), then, in another terminal:

    python examples/custom_input_node.py amplitude_mm=8 period_s=2

It finds the running graph through the master (FACESCULPT_MASTER) and publishes InputEvents on
`input/events`; the deformer moves the landmark, the renderer shows it. Any device or program
can drive the face the same way: subclass Node, advertise input/events, publish InputEvents
(docs/graph/input-events.md lists the kinds).
"""

import math
import time

import numpy as np

from facesculpt.msgs import InputEvent
from facesculpt.runtime import Node, Param


class Wiggle(Node):
    NAME = "wiggle"
    PARAMS = {
        "landmark": Param("nose_tip", "the landmark to move"),
        "amplitude_mm": Param(6.0, "how far to either side, mm along model x", range=(0.0, 50.0)),
        "period_s": Param(2.0, "one left-right cycle, s", range=(0.1, 60.0)),
    }

    def setup(self):
        self.events = self.advertise("input/events", InputEvent)
        self.offset = 0.0  # where we have moved the landmark so far, mm along model x
        self.timer(1 / 30, self.tick)
        self.t0 = time.monotonic()

    def tick(self):
        if self.events.subscriber_count() == 0:  # nobody listens yet: a move now would be lost
            self.t0 = time.monotonic()
            return
        phase = 2 * math.pi * (time.monotonic() - self.t0) / self.params.period_s
        target = self.params.amplitude_mm * math.sin(phase)
        step, self.offset = target - self.offset, target
        self.events.publish(InputEvent(stamp=time.time_ns(), kind="move", landmark=self.params.landmark,
                                       handle=3, vector=np.array([step, 0.0, 0.0], np.float32), source=self.name))


if __name__ == "__main__":
    Wiggle.main()
