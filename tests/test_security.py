"""CURVE over tcp loopback: authenticated peers work; a stranger subscriber receives nothing,
a stranger publisher is never heard, a stranger cannot talk to the master."""

from __future__ import annotations

import os
import subprocess
import sys
import time

import numpy as np
import pytest
import yaml
import zmq
from conftest import REPO_ROOT, free_port

from facesculpt.msgs import Image, InputEvent
from facesculpt.runtime.master import MasterClient, master_alive
from facesculpt.runtime.node import Node
from facesculpt.runtime.qos import EVENTS
from facesculpt.runtime.security import Security, SecurityError, generate_keypair


@pytest.fixture
def keys(tmp_path):
    graph_dir, stranger_dir = tmp_path / "keys", tmp_path / "stranger"
    generate_keypair(graph_dir, "graph")
    generate_keypair(graph_dir, "laptop")          # an authorised client keypair
    generate_keypair(stranger_dir, "graph")        # same name, other keys: not the graph's
    return graph_dir, stranger_dir


def _secure_master(graph, keys_dir) -> str:
    address = f"tcp://127.0.0.1:{free_port()}"
    env = dict(graph.env, FACESCULPT_KEYS=str(keys_dir), FACESCULPT_MASTER=address)
    proc = subprocess.Popen([sys.executable, "-m", "facesculpt.cli", "master"], env=env, cwd=REPO_ROOT)
    graph.procs.append(proc)
    trusted = Security.from_dir(keys_dir)
    deadline = time.monotonic() + 10
    while not master_alive(address, 0.3, security=trusted):
        assert time.monotonic() < deadline and proc.poll() is None, "secure master did not start"
    return address


def _event(handle: int) -> InputEvent:
    return InputEvent(stamp=time.time_ns(), kind="move", vector=np.ones(3, np.float32), handle=handle)


@pytest.mark.slow
def test_curve_admits_authenticated_peers_and_shuts_out_strangers(graph, keys):
    graph_dir, stranger_dir = keys
    trusted = Security.from_dir(graph_dir)
    laptop = Security.from_dir(graph_dir, client="laptop")
    stranger = Security.from_dir(stranger_dir)
    address = _secure_master(graph, graph_dir)

    # The master answers trusted clients only.
    assert MasterClient(address, 0.5, security=laptop).request("ping") is not None
    plain = MasterClient(address, 0.5)
    plain.security = None
    assert plain.request("ping") is None, "the master answered a client without keys"
    assert MasterClient(address, 0.5, security=stranger).request("ping") is None, "the master answered a stranger"

    pub_node = graph.node(Node(name="secure_pub", master=address, transport="tcp", security=trusted))
    pub = pub_node.advertise("input/events", InputEvent)
    got: list[int] = []
    sub_node = graph.node(Node(name="secure_sub", master=address, transport="tcp", security=laptop))
    sub = sub_node.subscribe("input/events", InputEvent, lambda m: got.append(m.handle), qos=EVENTS)
    assert pub.endpoint.startswith("tcp://127.0.0.1:")   # loopback unless told otherwise

    # A stranger's publisher on the same topic, with its own (wrong) server key; its master link is
    # refused, so we hand its endpoint to the trusted subscriber directly, as an attacker could not.
    evil_node = graph.node(Node(name="evil_pub", master=address, transport="tcp", security=stranger))
    evil = evil_node.advertise("input/events", InputEvent)

    # Stranger subscribers to the trusted publisher: with no keys, and with a keypair of its own
    # that knows the graph's (public) server key.
    ctx = zmq.Context()
    spies = []
    for sec in (None, stranger):
        s = ctx.socket(zmq.SUB)
        s.setsockopt(zmq.LINGER, 0)
        if sec is not None:
            s.curve_secretkey, s.curve_publickey = sec.client_secret, sec.client_public
            s.curve_serverkey = trusted.server_public
        s.setsockopt(zmq.SUBSCRIBE, b"")
        s.connect(pub.endpoint)
        spies.append(s)

    assert graph.spin_until(sub_node, lambda: bool(sub.endpoints), 10), "the trusted subscriber found no publisher"
    sub_node.receiver.set_endpoints(sub, sub.endpoints | {evil.endpoint})
    deadline = time.monotonic() + 4.0
    sent = 0
    while time.monotonic() < deadline:
        pub.publish(_event(1))
        evil.publish(_event(-666))
        sent += 1
        sub_node.spin_once(0.05)
    sub_node.spin_once(0.2)

    assert got.count(1) >= sent // 2, f"the authenticated subscriber got {got.count(1)} of {sent}"
    assert -666 not in got, "a stranger's publisher was heard"
    for spy in spies:
        assert not spy.poll(200), "a subscriber without the graph's trust received a message"
        spy.close()
    ctx.term()
    nodes = {n["node"] for n in MasterClient(address, 1.0, security=trusted).call("nodes")["nodes"]}
    assert {"secure_pub", "secure_sub"} <= nodes and "evil_pub" not in nodes


@pytest.mark.slow
def test_keys_command_and_a_secure_launch_file(graph, data_dir, tmp_path):
    keys_dir = tmp_path / "k"
    out = graph.run("keys", "generate", str(keys_dir))
    assert out.returncode == 0, out.stderr
    assert (keys_dir / "graph.key").is_file() and os.stat(keys_dir / "graph.key_secret").st_mode & 0o077 == 0
    again = graph.run("keys", "generate", str(keys_dir))
    assert again.returncode != 0 and "already exists" in again.stderr

    launch = tmp_path / "secure.yaml"
    launch.write_text(yaml.safe_dump({
        "transport": "tcp", "security": {"keys": "./k"},
        "nodes": [{"name": "camera", "node": "camera",
                   "params": {"source": str(data_dir / "video" / "d3.mp4"), "loop": True, "fps": 15.0,
                              "width": 160}}]}))
    address = f"tcp://127.0.0.1:{free_port()}"
    env = dict(graph.env, FACESCULPT_MASTER=address)
    proc = subprocess.Popen([sys.executable, "-m", "facesculpt.cli", "launch", str(launch)], env=env, cwd=REPO_ROOT)
    graph.procs.append(proc)
    got: list = []
    watcher = graph.node(Node(name="watcher", master=address, security=Security.from_dir(keys_dir)))
    watcher.subscribe("camera/image", Image, got.append)
    assert graph.spin_until(watcher, lambda: len(got) >= 3, 30), "no images through the secure graph"
    assert got[-1].image.shape[1] == 160
    endpoints = {ep for s in watcher.subscriptions for ep in s.endpoints}
    assert endpoints and all(ep.startswith("tcp://127.0.0.1:") for ep in endpoints), endpoints
    # Without keys the same graph is silent: the master does not answer a plain client.
    assert not master_alive(address, 0.5)

    bad = tmp_path / "bad.yaml"
    bad.write_text(yaml.safe_dump({"security": {"keys": "./nowhere"}, "nodes": [{"node": "camera"}]}))
    from facesculpt.runtime.launcher import load_launch

    with pytest.raises(ValueError, match="nowhere"):
        load_launch(bad)
    with pytest.raises(SecurityError, match="not found"):
        Security.from_dir(keys_dir, client="nobody")
