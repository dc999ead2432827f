"""A node whose parameters name something that cannot be used stops at once with one sentence and
the configuration status (2), is not respawned, and a launch whose required node fails that way
stops with the node's reason as its last line."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest
import yaml
from conftest import free_port

from facesculpt.runtime.parameters import EXIT_BAD_PARAMETER


def _cli(*args: str, env: dict, cwd, timeout: float = 60) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "facesculpt.cli", *args], env=env, cwd=cwd,
                          capture_output=True, text=True, timeout=timeout)


@pytest.fixture
def env(tmp_path):
    # A master address nothing listens on: a node that starts would only retry; these must not start.
    e = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}
    e.update(FACESCULPT_MASTER=f"tcp://127.0.0.1:{free_port()}", FACESCULPT_RUN_DIR=str(tmp_path / "run"))
    return e


@pytest.mark.parametrize("args, sentence", [
    (("fitter", "model=missing.npz"), "facesculpt: fitter: cannot load model 'missing.npz'"),
    (("camera", "source=57"), "facesculpt: camera: cannot open webcam 57"),
    (("camera", "source=missing.mp4"), "facesculpt: camera: "),
    (("renderer", "window=true"), "facesculpt: renderer: window=true needs a display"),
    (("renderer", "outline_band=wide"), "facesculpt: renderer: outline_band must be auto or a share"),
])
def test_a_misconfigured_node_stops_with_its_reason(args, sentence, env, tmp_path):
    result = _cli("run", *args, env=env, cwd=tmp_path)
    assert result.returncode == EXIT_BAD_PARAMETER, result.stderr
    last = result.stderr.strip().splitlines()[-1]
    assert last.startswith(sentence), result.stderr
    assert "Traceback" not in result.stderr


@pytest.mark.slow
def test_a_launch_whose_required_node_cannot_start_stops_with_the_reason(env, tmp_path):
    launch = tmp_path / "bad.yaml"
    launch.write_text(yaml.safe_dump({"nodes": [
        {"name": "camera", "node": "camera", "required": True, "params": {"source": "57"}},
        {"name": "fitter", "node": "fitter", "respawn": True, "params": {"model": "missing.npz"}},
    ]}))
    result = _cli("launch", str(launch), env=env, cwd=tmp_path)
    assert result.returncode == 1, result.stdout + result.stderr
    lines = result.stdout.strip().splitlines()
    assert lines[-1] == "the graph stopped: required node camera failed (exit code 2): camera: cannot open webcam 57"
    assert sum("[fitter] running" in line for line in lines) == 1  # not respawned (whichever ends first)


CRASHER = '''
from facesculpt.runtime import Node


class Crasher(Node):
    NAME = "crasher"

    def setup(self):
        raise RuntimeError("crashes at every start")
'''


@pytest.mark.slow
def test_a_node_that_keeps_crashing_is_given_up(env, tmp_path):
    from facesculpt.runtime.launcher import MAX_QUICK_FAILURES

    (tmp_path / "crasher.py").write_text(CRASHER)
    launch = tmp_path / "crash.yaml"
    launch.write_text(yaml.safe_dump({"nodes": [
        {"name": "crasher", "node": f"{tmp_path / 'crasher.py'}:Crasher", "respawn": True, "respawn_delay_s": 0.05},
    ]}))
    result = _cli("launch", str(launch), env=env, cwd=tmp_path, timeout=120)
    lines = result.stdout.strip().splitlines()
    assert result.returncode == 1, result.stdout + result.stderr
    assert sum("[crasher] running" in line for line in lines) == MAX_QUICK_FAILURES
    assert any(f"{MAX_QUICK_FAILURES} times in a row" in line and "giving up" in line for line in lines), lines


@pytest.mark.parametrize("field, value, sentence", [
    ("respawn", "maybe", "respawn must be true or false, not 'maybe'"),
    ("required", 1, "required must be true or false, not 1"),
    ("respawn_delay_s", -1, "respawn_delay_s must be a number of seconds in [0, 60], not -1"),
    ("params", ["fps", 3], "params must be a mapping (name: value), not ['fps', 3]"),
])
def test_launch_file_fields_are_checked(field, value, sentence, tmp_path):
    from facesculpt.runtime.launcher import load_launch

    launch = tmp_path / "x.yaml"
    launch.write_text(yaml.safe_dump({"nodes": [{"name": "cam", "node": "camera", field: value}]}))
    with pytest.raises(ValueError) as info:
        load_launch(launch)
    assert str(info.value) == f"launch file {launch}: node #1 (cam): {sentence}"
