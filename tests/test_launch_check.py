"""Launch files checked before anything starts (issue 51): a bad node type, param, value or
topic refuses the whole file in one sentence and exit 1 with no process started; `launch --check`
says ok in one line, and every shipped launch file passes it. Every subcommand's `--help` opens
with a description, `launch --help` lists the shipped launch files, and `bag play --loop` reports
every pass."""

from __future__ import annotations

import argparse
import os
import signal
import subprocess
import sys
import time

import numpy as np
import pytest
import yaml
from conftest import free_port

from facesculpt.cli import build_parser, main
from facesculpt.msgs import Image
from facesculpt.nodes import BUILTIN_NODES, node_class
from facesculpt.paths import shipped_launch_files
from facesculpt.runtime.bag import BagWriter
from facesculpt.runtime.node import Node, node_parser

KNOWN = ", ".join(sorted(BUILTIN_NODES))


def _cli(*args, cwd, timeout: float = 60) -> subprocess.CompletedProcess:
    env = dict(os.environ, FACESCULPT_MASTER=f"tcp://127.0.0.1:{free_port()}", FACESCULPT_RUN_DIR=str(cwd))
    return subprocess.run([sys.executable, "-m", "facesculpt.cli", *map(str, args)], env=env, cwd=cwd,
                          capture_output=True, text=True, timeout=timeout)


def _write(tmp_path, nodes: list[dict]):
    path = tmp_path / "graph.yaml"
    path.write_text(yaml.safe_dump({"nodes": nodes}))
    return path


CAMERA = {"name": "camera", "node": "camera", "required": True, "params": {"source": "embedded", "max_frames": 2}}

# (the launch file's nodes, the overrides, the sentence after "facesculpt: launch file PATH: ")
BAD = {
    "misspelt node type": (
        [CAMERA, {"name": "landmarks", "node": "landmarkz", "respawn": True}], [],
        f"node landmarks: unknown node 'landmarkz' (did you mean landmarks?): give a built-in name ({KNOWN}), "
        f"module:Class or path/file.py:Class"),
    "module without the class": (
        [CAMERA, {"name": "mine", "node": "facesculpt.nodes.camera.node:NoSuchNode"}], [],
        "node mine: node 'facesculpt.nodes.camera.node:NoSuchNode': NoSuchNode is not a "
        "facesculpt.runtime.node.Node subclass in facesculpt.nodes.camera.node"),
    "misspelt param": (
        [dict(CAMERA, params={"source": "embedded", "fsp": 10})], [],
        "node camera: unknown param(s) fsp (known: "),
    "value of the wrong type": (
        [dict(CAMERA, params={"source": "embedded", "fps": "fast"})], [],
        "param camera.fps: expected float, got 'fast'"),
    "value out of range": (
        [CAMERA], ["camera.width=-3"],
        "camera.width=-3 is out of range [0, 16384]"),
    "value not a choice, on a node left out": (
        [CAMERA, {"name": "renderer", "node": "renderer", "enabled": False, "params": {"pairing": "sometimes"}}], [],
        "renderer.pairing='sometimes' is not one of "),
    "topic param not a topic": (
        [dict(CAMERA, params={"source": "embedded", "wait_for": "render done"})], [],
        "camera.wait_for='render done' is not a topic name (words of letters, digits, _ . - joined by /, "
        "as in camera/image)"),
    "remap of a topic the node does not use": (
        [dict(CAMERA, remap={"camera/imag": "cam0/image"})], [],
        "node camera: remap camera/imag: cam0/image: node type camera uses no topic camera/imag "
        "(it uses camera/analysis, camera/image, diagnostics, render/done)"),
    "remap onto a name that is no topic": (
        [dict(CAMERA, remap={"camera/image": "/cam0//image"})], [],
        "node camera: remap camera/image: /cam0//image: '/cam0//image' is not a topic name (words of letters, "
        "digits, _ . - joined by /, as in camera/image)"),
}


@pytest.mark.parametrize("case", list(BAD))
@pytest.mark.slow
def test_a_bad_launch_file_is_refused_before_anything_starts(case, tmp_path):
    nodes, overrides, sentence = BAD[case]
    path = _write(tmp_path, nodes)
    result = _cli("launch", path, *overrides, cwd=tmp_path)
    assert result.returncode == 1, result.stdout + result.stderr
    last = result.stderr.strip().splitlines()[-1]
    assert last.startswith(f"facesculpt: launch file {path}: {sentence}"), last
    assert "Traceback" not in result.stderr
    assert "running (pid" not in result.stdout and "master" not in result.stdout  # nothing was started
    check = _cli("launch", "--check", path, *overrides, cwd=tmp_path)
    assert check.returncode == 1 and check.stderr.strip().splitlines()[-1] == last


def test_a_users_node_file_that_fails_to_import_is_named(tmp_path):
    (tmp_path / "mine.py").write_text("import no_such_module_here\n")
    path = _write(tmp_path, [CAMERA, {"name": "mine", "node": "mine.py:Mine"}])
    result = _cli("launch", path, cwd=tmp_path)
    assert result.returncode == 1
    assert result.stderr.strip().splitlines()[-1] == (
        f"facesculpt: launch file {path}: node mine: cannot load node 'mine.py:Mine' "
        f"(ModuleNotFoundError: No module named 'no_such_module_here')")


def test_check_says_ok_in_one_line_and_starts_nothing(tmp_path):
    (tmp_path / "mine.py").write_text("from facesculpt.runtime.node import Node\n\n\nclass Mine(Node):\n"
                                      "    NAME = 'mine'\n")
    path = _write(tmp_path, [
        CAMERA,
        {"name": "landmarks", "node": "landmarks", "remap": {"camera/image": "cam0/image"}},
        {"name": "mine", "node": "mine.py:Mine", "remap": {"anything/at_all": "x"}},  # declares no TOPICS
        {"name": "foxglove", "node": "foxglove", "enabled": False},
    ])
    result = _cli("launch", "--check", path, "camera.fps=12", cwd=tmp_path)
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip().splitlines() == [
        f"launch file {path}: ok: starts 3 node(s) (camera, landmarks, mine), leaves out 1 (foxglove); 2 remap(s)"]


@pytest.mark.parametrize("launch_file", [p.stem for p in shipped_launch_files()])
def test_every_shipped_launch_file_passes_check(launch_file, capsys):
    assert main(["launch", "--check", launch_file]) == 0
    out = capsys.readouterr().out.strip().splitlines()
    assert len(out) == 1 and out[0].startswith("launch file ") and f"{launch_file}.yaml: ok: starts " in out[0]


def test_the_shipped_launch_files_are_the_ones_expected():
    names = [p.stem for p in shipped_launch_files()]
    assert {"webcam", "video", "demo", "replay", "reenact", "coding"} <= set(names)
    assert "demo_gestures" not in names  # a gesture script, not a launch file


def _subparsers(parser: argparse.ArgumentParser, path=()):
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                yield (*path, name), sub
                yield from _subparsers(sub, (*path, name))


def test_every_subcommand_help_has_a_description():
    found = list(_subparsers(build_parser()))
    assert len(found) > 20
    missing = [" ".join(path) for path, sub in found if not (sub.description or "").strip()]
    assert not missing, f"no description in --help of: {', '.join(missing)}"
    for name in BUILTIN_NODES:  # `facesculpt run NAME --help`
        assert (node_parser(node_class(name)).description or "").strip(), name


def test_launch_and_run_node_help_as_a_user_sees_it(tmp_path):
    launch = _cli("launch", "--help", cwd=tmp_path)
    assert launch.returncode == 0
    assert "Start a graph from a launch file" in launch.stdout and "--check" in launch.stdout
    listed = launch.stdout.split("shipped launch files (facesculpt launch NAME):")[1].splitlines()
    assert [line.split()[0] for line in listed if line.strip()] == [p.stem for p in shipped_launch_files()]
    assert all(len(line.split()) > 3 for line in listed if line.strip())  # each with what it does
    fox = _cli("run", "foxglove", "--help", cwd=tmp_path)
    assert fox.returncode == 0
    assert fox.stdout.split("\n\n")[1].startswith("Serves the running graph to Foxglove"), fox.stdout


def test_a_node_may_use_only_the_topics_it_declares(tmp_path, monkeypatch):
    monkeypatch.setenv("FACESCULPT_RUN_DIR", str(tmp_path))

    class Declared(Node):
        NAME = "declared"
        TOPICS = ("a/b",)

    node = Declared()
    try:
        node.advertise("a/b", Image)
        with pytest.raises(ValueError, match=r"node declared: topic c/d is not declared: add it to Declared.TOPICS"):
            node.subscribe("c/d", Image, lambda m: None)
    finally:
        node.close()
    assert all(node_class(name).TOPICS for name in BUILTIN_NODES)


def test_bag_play_loop_reports_every_pass(tmp_path):
    bag = tmp_path / "three.mcap"
    with BagWriter(bag) as writer:
        for i in range(3):
            image = Image(stamp=i, seq=i, frame_id="cam", image=np.full((8, 8, 3), i, np.uint8))
            writer.write(1_700_000_000_000_000_000 + i * 1_000_000, "camera/image", image.to_frames())
    env = dict(os.environ, FACESCULPT_MASTER=f"tcp://127.0.0.1:{free_port()}", FACESCULPT_RUN_DIR=str(tmp_path))
    player = subprocess.Popen([sys.executable, "-m", "facesculpt.cli", "bag", "play", "--loop", "--fast",
                               "--wait", "0", str(bag)], env=env, cwd=tmp_path, stderr=subprocess.PIPE, text=True)
    lines = []
    try:
        deadline = time.monotonic() + 60
        while len(lines) < 3 and time.monotonic() < deadline:
            line = player.stderr.readline()
            if line.startswith("pass "):
                lines.append(line.strip())
        player.send_signal(signal.SIGINT)
        player.wait(30)
        rest = player.stderr.read().strip().splitlines()  # what the reader's buffer holds too
    finally:
        if player.poll() is None:
            player.kill()
    assert player.returncode == 0
    assert lines == [f"pass {n}: played 3 messages from {bag}" for n in (1, 2, 3)]
    passes = [int(line.split("played ")[1].split()[0]) for line in rest if line.startswith("pass ")]
    assert all(n == 3 for n in passes[:-1]) and all(n <= 3 for n in passes[-1:])  # the last one cut by the stop
    assert rest[-1] == f"played {9 + sum(passes)} messages from {bag} in {3 + len(passes)} passes (each one's count above)"


def test_checking_leaves_the_environment_of_the_graphs_processes_as_it_was(tmp_path):
    """Loading the node classes imports OpenCV, which adds to LD_LIBRARY_PATH; the processes the
    launcher starts after the check must not inherit that (a fresh interpreter: nothing imported)."""
    script = ("import os\nfrom facesculpt.nodes import node_class\nfrom facesculpt.paths import launch_file\n"
              "from facesculpt.runtime.launcher import load_launch\nbefore = dict(os.environ)\n"
              "load_launch(launch_file('reenact'), [], node_class=node_class)\n"
              "print(before == dict(os.environ))\n")
    env = {k: v for k, v in os.environ.items() if k != "LD_LIBRARY_PATH"}
    result = subprocess.run([sys.executable, "-c", script], env=env, cwd=tmp_path, capture_output=True, text=True,
                            timeout=120)
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip() == "True"
