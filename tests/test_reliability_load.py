"""Load: a second consumer of camera/image that is 10x too slow does not lower the renderer's
output rate (by more than 5 %): the camera never waits for its slowest subscriber."""

from __future__ import annotations

import time

import pytest

from facesculpt.msgs import Diagnostics, Image
from facesculpt.runtime.node import Node

NODES = "tests/reliability_nodes.py"
FPS = 15.0
PHASE_S = 8.0


def _rate(graph, watcher, arrivals, seconds) -> float:
    graph.spin_until(watcher, lambda: False, 1.0)  # settle
    arrivals.clear()
    graph.spin_until(watcher, lambda: False, seconds)
    return (len(arrivals) - 1) / (arrivals[-1] - arrivals[0]) if len(arrivals) > 1 else 0.0


@pytest.mark.timing
@pytest.mark.slow
def test_a_ten_times_too_slow_consumer_does_not_slow_the_renderer(graph, data_dir):
    video = data_dir / "video" / "d3.mp4"
    graph.spawn("run", "camera", f"source={video}", "loop=true", f"fps={FPS}")
    graph.spawn("run", "renderer", "pairing=latest", "output=")
    arrivals: list[float] = []
    diags: dict = {}
    watcher = graph.node(Node(name="load_watcher"))
    watcher.subscribe("render/image", Image, lambda m: arrivals.append(time.monotonic()))
    watcher.subscribe("diagnostics", Diagnostics, lambda m: diags.__setitem__(m.node, m.values))
    assert graph.spin_until(watcher, lambda: len(arrivals) > 10, 30), "the renderer published nothing"

    alone = _rate(graph, watcher, arrivals, PHASE_S)
    slow = graph.spawn("run", f"{NODES}:SlowImageConsumer", f"sleep_s={10.0 / FPS}")
    assert graph.spin_until(watcher, lambda: diags.get("slow_consumer", {}).get("counters", {}).get("taken", 0) >= 2,
                            20), "the slow consumer took nothing"
    loaded = _rate(graph, watcher, arrivals, PHASE_S)
    taken = diags["slow_consumer"]["counters"]["taken"]
    print(f"\nload: renderer {alone:.2f} Hz alone, {loaded:.2f} Hz with a consumer taking "
          f"{FPS / 10:.1f} Hz ({taken} frames, dropped {diags['slow_consumer']['dropped']})")
    assert slow.poll() is None
    assert alone >= 0.8 * FPS, f"the renderer ran at {alone:.1f} Hz alone"
    assert loaded >= 0.95 * alone, f"renderer rate fell from {alone:.2f} to {loaded:.2f} Hz"
    # The slow consumer really was too slow: it skipped most frames rather than queueing them.
    assert diags["slow_consumer"]["dropped"]["camera/image"] > taken
