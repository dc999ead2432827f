"""The command line as a user types it: help where help is asked for, an answer instead of a
wait when no graph runs, JSON that parses, one sentence for a malformed preset, and the same
logs from a node's own script as from `facesculpt run`."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time

import pytest
from conftest import free_port

from facesculpt.msgs import InputEvent
from facesculpt.runtime.node import Node


def _cli(*args: str, env=None, cwd=None, timeout: float = 60) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "facesculpt.cli", *args], env=env, cwd=cwd,
                          capture_output=True, text=True, timeout=timeout)


@pytest.mark.slow
def test_run_help_lists_the_built_in_nodes(tmp_path):
    for flag in ("--help", "-h"):
        result = _cli("run", flag, cwd=tmp_path)
        assert result.returncode == 0, result.stderr
        assert result.stdout.startswith("usage: facesculpt run NODE") and "fitter" in result.stdout
    bare = _cli("run", cwd=tmp_path)
    assert bare.returncode == 2 and "built-in nodes:" in bare.stdout


@pytest.mark.slow
def test_topic_echo_without_a_master_says_so(tmp_path):
    env = dict(os.environ, FACESCULPT_MASTER=f"tcp://127.0.0.1:{free_port()}", FACESCULPT_RUN_DIR=str(tmp_path))
    started = time.monotonic()
    result = _cli("topic", "echo", "camera/image", env=env, cwd=tmp_path, timeout=30)
    assert result.returncode == 1 and time.monotonic() - started < 20
    assert result.stderr.strip().splitlines()[-1].startswith("facesculpt: no master answers at")


def test_topic_echo_json_is_json(graph, tmp_path):
    proc = subprocess.Popen([sys.executable, "-m", "facesculpt.cli", "topic", "echo", "input/events", "--json",
                             "--count", "1", "--timeout", "30"], env=graph.env, cwd=tmp_path,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    pub_node = graph.node(Node(name="nan_pub"))
    pub = pub_node.advertise("input/events", InputEvent)
    deadline = time.monotonic() + 30
    while proc.poll() is None and time.monotonic() < deadline:
        pub.publish(InputEvent(stamp=time.time_ns(), kind="command", command="reset"))  # x, y are NaN
        pub_node.spin_once(0.2)
    out, err = proc.communicate(timeout=10)
    assert proc.returncode == 0, err
    doc = json.loads(out.strip().splitlines()[0])  # strict JSON: NaN would not parse as the standard says
    assert doc["x"] is None and doc["kind"] == "command"
    assert "NaN" not in out


@pytest.mark.slow
def test_a_preset_that_is_not_an_object_is_one_sentence(tmp_path):
    preset = tmp_path / "list.json"
    preset.write_text("[1, 2]")
    video = tmp_path / "in.avi"
    import cv2
    import numpy as np

    writer = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"MJPG"), 25.0, (64, 48))
    writer.write(np.zeros((48, 64, 3), np.uint8))
    writer.release()
    result = _cli("process", str(video), "-o", str(tmp_path / "out.mp4"), "--edits", str(preset), cwd=tmp_path)
    assert result.returncode == 1 and "Traceback" not in result.stderr
    assert result.stderr.strip().splitlines()[-1] == (
        f"facesculpt: preset {preset} is a JSON list, not a deformer preset (a JSON object with 'format', "
        f"'version' and a list of 'edits', as the window's S key saves)")


@pytest.mark.slow
def test_a_node_script_logs_like_facesculpt_run(tmp_path):
    script = tmp_path / "my_node.py"
    script.write_text("from facesculpt.runtime import Node\n\n\nclass Mine(Node):\n    NAME = 'mine'\n\n"
                      "    def setup(self):\n        self.log.info('hello from setup')\n        self.timer(0.2, self.shutdown)\n\n\n"
                      "if __name__ == '__main__':\n    Mine.main()\n")
    env = dict(os.environ, FACESCULPT_MASTER=f"tcp://127.0.0.1:{free_port()}", FACESCULPT_RUN_DIR=str(tmp_path))
    own = subprocess.run([sys.executable, str(script)], env=env, cwd=tmp_path, capture_output=True, text=True,
                         timeout=60)
    run = _cli("run", f"{script}:Mine", env=env, cwd=tmp_path)
    for result in (own, run):
        assert result.returncode == 0, result.stderr
        assert " I [facesculpt.mine] hello from setup" in result.stderr, result.stderr


@pytest.mark.slow
def test_a_json_object_that_is_not_a_preset_names_its_file(tmp_path):
    video = tmp_path / "in.avi"
    import cv2
    import numpy as np

    writer = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"MJPG"), 25.0, (64, 48))
    writer.write(np.zeros((48, 64, 3), np.uint8))
    writer.release()
    other = tmp_path / "settings.json"
    other.write_text('{"theme": "dark", "edits": []}')
    newer = tmp_path / "newer.json"
    newer.write_text('{"format": "facesculpt-deformer-preset", "version": 7, "edits": []}')
    for preset, sentence in (
            (other, f"preset {other} is a JSON object without \"format\": \"facesculpt-deformer-preset\", not a "
                    f"deformer preset (a JSON object with 'format', 'version' and a list of 'edits', as the window's "
                    f"S key saves)"),
            (newer, f"preset {newer}: preset version 7 is not 1")):
        result = _cli("process", str(video), "-o", str(tmp_path / "out.mp4"), "--edits", str(preset), cwd=tmp_path)
        assert result.returncode == 1 and "Traceback" not in result.stderr
        assert result.stderr.strip().splitlines()[-1] == f"facesculpt: {sentence}"
        assert not (tmp_path / "out.mp4").exists()


def test_each_command_module_adds_the_commands_the_cli_names_for_it():
    import argparse
    import importlib

    from facesculpt.cli import COMMAND_MODULES, build_parser

    for module, commands in COMMAND_MODULES.items():
        sub = argparse.ArgumentParser().add_subparsers()
        importlib.import_module(module).register(sub)
        assert tuple(sub.choices) == commands, module
    assert build_parser(["-v", "run", "fitter"]).parse_args(["-v", "run", "fitter"]).command == "run"


def test_a_dense_fitter_process_starts_without_the_other_commands_or_scipy(tmp_path):
    """What a respawned `facesculpt run fitter` imports, loads and fits before its first state:
    not the other commands' modules, not scipy (only the sparse fitter and the appearance
    refinement use it), not OpenCV (the appearance refinement's) and not PyYAML (a string
    parameter's parsing)."""
    code = ("import sys, numpy as np\n"
            "from facesculpt import cli\n"
            "cli.build_parser(['run', 'fitter'])\n"
            "from facesculpt.nodes import node_class\n"
            "node_class('fitter')\n"
            "from facesculpt.nodes.fitter import FitterConfig, fit_landmarks, load_model, make_fitter\n"
            "model = load_model('facemesh')\n"
            "fitter = make_fitter(model, FitterConfig(), image_size=(640, 480))\n"
            "p = np.asarray(model.mean, np.float64)[:468]\n"
            "p = np.column_stack([320 + 2 * p[:, 0], 240 - 2 * p[:, 1], -2 * p[:, 2]])[None]\n"
            "assert fit_landmarks(fitter, p, np.ones(1), 0.0).fit is not None\n"
            "print(sorted(m for m in sys.modules if m.split('.')[0] in ('scipy', 'cv2', 'yaml')\n"
            "             or m.startswith('facesculpt.app.')))\n")
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip() == "['facesculpt.app.graph_commands']"   # `run`'s own module only
