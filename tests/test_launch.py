"""Launch files with real processes: respawn after kill -9, clean stop, and a user's
own node joining a launched graph; the introspection commands on that graph."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time

import psutil
import pytest
import yaml
from conftest import REPO_ROOT, load_scale

from facesculpt.msgs import Image
from facesculpt.runtime.launcher import load_launch
from facesculpt.runtime.node import Node


def _launch_file(tmp_path, video) -> str:
    path = tmp_path / "graph.yaml"
    path.write_text(yaml.safe_dump({"nodes": [
        {"name": "camera", "node": "camera", "respawn": True,
         "params": {"source": str(video), "loop": True, "fps": 30.0, "width": 320}},
    ]}))
    return str(path)


def _node_pid(graph, name: str) -> int | None:
    out = graph.run("node", "list", "--json")
    for entry in json.loads(out.stdout or "[]"):
        if entry["node"] == name:
            return entry["pid"]
    return None


@pytest.mark.timing
@pytest.mark.slow
def test_respawn_after_kill_and_clean_stop(graph, data_dir, tmp_path):
    launch = graph.spawn("launch", _launch_file(tmp_path, data_dir / "video" / "d0.mp4"))
    arrivals: list[tuple[float, int]] = []
    watcher = graph.node(Node(name="watcher"))
    watcher.subscribe("camera/image", Image, lambda m: arrivals.append((time.monotonic(), m.image.shape[1])))
    assert graph.spin_until(watcher, lambda: len(arrivals) > 10, 20), "no camera images"
    assert arrivals[-1][1] == 320  # the launch file's params reached the node

    recoveries = []
    for _ in range(2):
        pid = _node_pid(graph, "camera")
        assert pid and psutil.pid_exists(pid)
        os.kill(pid, signal.SIGKILL)
        killed_at = time.monotonic()
        arrivals.clear()
        assert graph.spin_until(watcher, lambda: any(t > killed_at + 0.05 for t, _ in arrivals), 10)
        recoveries.append(min(t for t, _ in arrivals if t > killed_at + 0.05) - killed_at)
        assert _node_pid(graph, "camera") != pid
    assert max(recoveries) <= 2.0 * load_scale(), f"camera images resumed after {recoveries} s"

    children = psutil.Process(launch.pid).children(recursive=True)
    assert children
    launch.send_signal(signal.SIGINT)
    started, scale = time.monotonic(), load_scale()
    assert launch.wait(5 * scale) == 0
    gone, alive = psutil.wait_procs(children, timeout=max(0.1, 3.0 * scale - (time.monotonic() - started)))
    assert not alive, f"left behind: {alive}"
    assert time.monotonic() - started <= 3.0 * scale


@pytest.mark.timing
@pytest.mark.slow
def test_user_node_joins_a_launched_graph(graph, data_dir, tmp_path):
    graph.spawn("launch", _launch_file(tmp_path, data_dir / "video" / "d3.mp4"))
    user = subprocess.Popen([sys.executable, str(REPO_ROOT / "examples" / "brightness_node.py"), "gain=2.0"],
                            env=graph.env)
    graph.procs.append(user)
    got: dict[str, Image] = {}
    watcher = graph.node(Node(name="watcher"))
    watcher.subscribe("camera/image", Image, lambda m: got.__setitem__("raw", m))
    watcher.subscribe("camera/bright", Image, lambda m: got.__setitem__("bright", m))
    assert graph.spin_until(watcher, lambda: "bright" in got and "raw" in got, 20), "the user's node published nothing"
    bright, raw = got["bright"], got["raw"]
    assert bright.image.shape == raw.image.shape
    assert bright.image.mean() > 1.3 * raw.image.mean()  # it really processed camera images

    topics = {t["topic"]: t for t in json.loads(graph.run("topic", "list", "--json").stdout)}
    assert topics["camera/bright"]["publishers"] == ["brightness"]
    assert "brightness" in topics["camera/image"]["subscribers"]
    nodes = {n["node"]: n for n in json.loads(graph.run("node", "list", "--json").stdout)}
    assert nodes["brightness"]["pid"] == user.pid

    echo = graph.run("topic", "echo", "camera/bright", "--count", "2", "--json", "--timeout", "10")
    lines = [json.loads(line) for line in echo.stdout.splitlines()]
    assert len(lines) == 2 and lines[0]["image"]["shape"] == [320, 320, 3] and lines[0]["image"]["dtype"] == "uint8"
    hz = json.loads(graph.run("topic", "hz", "camera/image", "--duration", "2", "--json").stdout)
    assert 20 <= hz["rate_hz"] <= 40  # the camera is paced at 30 fps


def test_launch_file_errors_are_clear(tmp_path):
    bad = tmp_path / "bad.yaml"
    bad.write_text("nodes:\n  - name: a\n    node: camera\n    colour: red\n")
    with pytest.raises(ValueError, match="unknown keys"):
        load_launch(bad)
    good = tmp_path / "good.yaml"
    good.write_text("nodes:\n  - name: cam\n    node: camera\n")
    with pytest.raises(ValueError, match="NODE.param=value"):
        load_launch(good, ["nope.fps=3"])
    assert load_launch(good, ["cam.fps=3"])[0].params == {"fps": "3"}
    with pytest.raises(FileNotFoundError, match="missing.yaml"):
        load_launch(tmp_path / "missing.yaml")


def test_run_rejects_unknown_params_with_the_known_ones(graph):
    out = graph.run("run", "camera", "colour=red")
    assert out.returncode != 0
    assert "unknown param(s) colour" in out.stderr and "fov_deg" in out.stderr
    out = graph.run("run", "camera", "source=/no/such/video.mp4")
    assert out.returncode != 0 and "/no/such/video.mp4 not found" in out.stderr


SLOW_NODE = '''
import pathlib
import time

from facesculpt.runtime.node import Node


class Slow(Node):
    """Takes {finish_s} s to finish its file after a stop signal, as a video writer's flush can."""

    def setup(self):
        pathlib.Path({started!r}).write_text("started")

    def teardown(self):
        time.sleep({finish_s})
        pathlib.Path({finished!r}).write_text("finished")
'''


@pytest.mark.slow
@pytest.mark.parametrize("second_signal", [False, True])
def test_a_node_finishing_a_file_is_waited_for_unless_a_second_signal_comes(graph, tmp_path, second_signal):
    started, finished = tmp_path / "started", tmp_path / "finished"
    (tmp_path / "slow.py").write_text(SLOW_NODE.format(finish_s=4.0, started=str(started), finished=str(finished)))
    path = tmp_path / "graph.yaml"
    path.write_text(yaml.safe_dump({"nodes": [{"name": "slow", "node": f"{tmp_path / 'slow.py'}:Slow"}]}))
    launch = graph.spawn("launch", str(path), stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
    deadline = time.monotonic() + 30 * load_scale()
    while not started.exists():
        assert time.monotonic() < deadline and launch.poll() is None, "the node did not start"
        time.sleep(0.05)
    launch.send_signal(signal.SIGINT)
    if second_signal:
        time.sleep(0.5)
        launch.send_signal(signal.SIGINT)
    out = launch.communicate(timeout=40)[0].decode()
    if second_signal:   # killed at once: its file is not finished, and the launcher says so
        assert not finished.exists() and "[slow] did not stop: killed" in out, out
        assert launch.returncode == 1   # a node had to be killed: launch does not say all went well
    else:               # waited for past STOP_GRACE_S, named while it is waited for, not killed
        assert finished.exists(), out
        assert "waiting for slow to stop" in out and "did not stop" not in out, out
        assert launch.returncode == 0
