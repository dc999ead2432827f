"""Secure by default: nothing binds a network address, or talks to a master on another host,
without CURVE keys unless the user says insecure explicitly (then one warning line)."""

from __future__ import annotations

import os
import subprocess
import sys
import time

import pytest
from conftest import free_port

from facesculpt.runtime.master import master_alive
from facesculpt.runtime.security import SecurityError, check_exposure, generate_keypair, is_loopback


def _cli(*args: str, env: dict, timeout: float = 30) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "facesculpt.cli", *args], env=env, capture_output=True,
                          text=True, timeout=timeout)


@pytest.mark.parametrize("address, loopback", [
    ("tcp://127.0.0.1:11411", True), ("tcp://localhost:5", True), ("tcp://[::1]:5", True), ("ipc:///tmp/x", True),
    ("127.0.0.2", True), ("tcp://0.0.0.0:11411", False), ("tcp://*:5", False), ("tcp://192.168.1.7:5", False),
    ("tcp://example.org:5", False), ("0.0.0.0", False),
])
def test_loopback_addresses(address, loopback):
    assert is_loopback(address) is loopback


def test_exposure_needs_keys_or_an_explicit_insecure(tmp_path):
    with pytest.raises(SecurityError, match="refusing to expose the master on tcp://0.0.0.0:1 without CURVE keys"):
        check_exposure("the master", "tcp://0.0.0.0:1", None, insecure=False)
    assert "open to anyone" in check_exposure("the master", "tcp://0.0.0.0:1", None, insecure=True)
    assert check_exposure("the master", "tcp://127.0.0.1:1", None, insecure=False) is None
    from facesculpt.runtime.security import Security

    generate_keypair(tmp_path, "graph")
    assert check_exposure("the master", "tcp://0.0.0.0:1", Security.from_dir(tmp_path), insecure=False) is None


def test_a_master_on_every_interface_without_keys_is_refused_and_starts_when_told(tmp_path):
    address = f"tcp://0.0.0.0:{free_port()}"
    env = {k: v for k, v in os.environ.items() if k not in ("FACESCULPT_KEYS", "FACESCULPT_INSECURE")}
    env.update(FACESCULPT_MASTER=address, FACESCULPT_RUN_DIR=str(tmp_path))
    refused = _cli("master", env=env)
    assert refused.returncode != 0
    last = refused.stderr.strip().splitlines()[-1]
    assert last.startswith("facesculpt: refusing to expose the master on " + address), refused.stderr
    proc = subprocess.Popen([sys.executable, "-m", "facesculpt.cli", "master"], env=dict(env, FACESCULPT_INSECURE="1"),
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 15
        local = address.replace("0.0.0.0", "127.0.0.1")
        while not master_alive(local, 0.2):
            assert proc.poll() is None and time.monotonic() < deadline, "the insecure master did not start"
    finally:
        proc.terminate()
        _, err = proc.communicate(timeout=10)
    assert "insecure: the master on " + address in err and "no CURVE keys" in err


def test_a_node_that_would_talk_to_a_remote_master_without_keys_stops_with_the_reason(tmp_path):
    env = {k: v for k, v in os.environ.items() if k not in ("FACESCULPT_KEYS", "FACESCULPT_INSECURE")}
    # A master address that is not loopback (0.0.0.0 reaches this machine if the check ever let it through).
    address = f"tcp://0.0.0.0:{free_port()}"
    env.update(FACESCULPT_MASTER=address, FACESCULPT_RUN_DIR=str(tmp_path))
    result = _cli("run", "deformer", env=env)
    assert result.returncode == 2, result.stderr
    assert f"refusing to expose node deformer's link to the master on {address}" in result.stderr


def test_a_launch_file_binding_every_interface_needs_keys_or_insecure_true(tmp_path):
    import yaml

    from facesculpt.runtime.launcher import load_launch

    doc = {"transport": "tcp", "host": "0.0.0.0", "nodes": [{"name": "camera", "node": "camera"}]}
    open_file = tmp_path / "open.yaml"
    open_file.write_text(yaml.safe_dump(doc))
    with pytest.raises(ValueError, match=r"open.yaml: refusing to expose the graph's publishers on tcp://0.0.0.0:\*"):
        load_launch(open_file)
    env = {k: v for k, v in os.environ.items() if k not in ("FACESCULPT_KEYS", "FACESCULPT_INSECURE")}
    env.update(FACESCULPT_MASTER=f"tcp://127.0.0.1:{free_port()}", FACESCULPT_RUN_DIR=str(tmp_path))
    refused = _cli("launch", str(open_file), env=env)
    assert refused.returncode == 1 and "refusing to expose the graph's publishers" in refused.stderr.strip().splitlines()[-1]
    said = tmp_path / "said.yaml"
    said.write_text(yaml.safe_dump(dict(doc, insecure=True)))
    specs = load_launch(said)
    assert specs[0].graph_env.get("FACESCULPT_INSECURE") == "1"
    bad = tmp_path / "bad.yaml"
    bad.write_text(yaml.safe_dump(dict(doc, insecure="maybe")))
    with pytest.raises(ValueError, match="insecure must be true or false, not 'maybe'"):
        load_launch(bad)
