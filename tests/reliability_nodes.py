"""Nodes for the reliability tests, run as `facesculpt run tests/reliability_nodes.py:NAME`."""

from __future__ import annotations

import time

import psutil

from facesculpt.msgs import REGISTRY
from facesculpt.runtime.node import Node
from facesculpt.runtime.qos import EVERY_MESSAGE


class AllTypesCounter(Node):
    """Subscribes (queued, so that every valid message is counted) to `fuzz/<Type>` for every type and
    counts the valid messages it is given; reports its RSS (MiB) as counter `rss_mib`."""

    NAME = "all_types_counter"
    PARAMS = {}

    def setup(self):
        for name, cls in REGISTRY.items():
            self.subscribe(f"fuzz/{name}", cls, lambda m, n=name: self.count(f"valid:{n}"), qos=EVERY_MESSAGE)
        self.timer(0.5, self.on_tick)

    def on_tick(self):
        self.counters["rss_mib"] = int(psutil.Process().memory_info().rss / 2**20)


class SlowImageConsumer(Node):
    """Takes camera/image and spends `sleep_s` on each (a consumer far slower than the camera)."""

    NAME = "slow_consumer"
    PARAMS = {"sleep_s": 0.5, "topic": "camera/image"}

    def setup(self):
        self.subscribe(self.params.topic, None, self.on_image)

    def on_image(self, msg):
        self.count("taken")
        time.sleep(self.params.sleep_s)
