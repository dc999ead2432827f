"""Nodes used by the graph tests, run in their own processes as
`facesculpt run tests/graph_nodes.py:NAME param=value`."""

from __future__ import annotations

import json
import time

import numpy as np
import psutil

from facesculpt.msgs import Image, InputEvent
from facesculpt.runtime.node import Node
from facesculpt.runtime.qos import EVENTS


class ImagePublisher(Node):
    """Publishes 856x480x3 images at `rate_hz`, stamped with time_ns; reports its achieved rate."""

    NAME = "image_publisher"
    PARAMS = {"rate_hz": 100.0, "count": 2000, "out": "", "topic": "bench/image"}

    def setup(self):
        self.pub = self.advertise(self.params.topic, Image)
        self.frames = [np.full((480, 856, 3), i, np.uint8) for i in range(4)]
        self.sent = 0
        self.sent_at: list[float] = []
        self.rss: list[int] = []
        self.timer(1.0 / self.params.rate_hz, self.tick)

    def tick(self):
        if self.sent >= self.params.count:
            self.shutdown()
            return
        self.sent += 1
        stamp = time.time_ns()
        self.pub.publish(Image(stamp=stamp, seq=self.sent, image=self.frames[self.sent % 4]))
        self.sent_at.append(stamp)
        if self.sent % 100 == 0:
            self.rss.append(psutil.Process().memory_info().rss)

    def teardown(self):
        if self.params.out:
            with open(self.params.out, "w") as f:
                json.dump({"sent": self.sent, "sent_at": self.sent_at, "rss": self.rss}, f)


class SlowSubscriber(Node):
    """Latest-only subscriber that sleeps `sleep_s` per message and records each message's age when taken."""

    NAME = "slow_subscriber"
    PARAMS = {"sleep_s": 0.1, "out": "", "topic": "bench/image"}

    def setup(self):
        self.ages_ms: list[float] = []
        self.taken_at: list[int] = []
        self.seqs: list[int] = []
        self.rss: list[int] = []
        self.subscribe(self.params.topic, Image, self.on_image)

    def on_image(self, msg):
        now = time.time_ns()
        self.taken_at.append(now)
        self.ages_ms.append((now - msg.stamp) / 1e6)
        self.seqs.append(msg.seq)
        self.rss.append(psutil.Process().memory_info().rss)
        time.sleep(self.params.sleep_s)

    def teardown(self):
        if self.params.out:
            with open(self.params.out, "w") as f:
                json.dump({"ages_ms": self.ages_ms, "taken_at": self.taken_at, "seqs": self.seqs, "rss": self.rss}, f)


class EventCounter(Node):
    """Counts valid input events (queued) and reports them in diagnostics counters."""

    NAME = "event_counter"
    PARAMS = {"topic": "input/events"}

    def setup(self):
        self.subscribe(self.params.topic, InputEvent, self.on_event, qos=EVENTS)

    def on_event(self, msg):
        self.count("valid")
        if msg.handle == -1:
            self.count("sentinel")
