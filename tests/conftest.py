"""Shared fixtures: the shared data folder (skip when absent), the model directory, a running
graph; and a session check that the suite wrote nothing into the checkout (tests write only
into temporary folders)."""

from __future__ import annotations

import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pytest

from facesculpt.paths import model_home, shared_data_dir


@pytest.fixture(scope="session")
def data_dir() -> Path:
    """`../shared/data` (or $FACESCULPT_DATA); tests that need it skip with a reason when absent."""
    path = shared_data_dir()
    if path is None:
        pytest.skip("shared test data not found: set FACESCULPT_DATA or place it at ../shared/data")
    return path


@pytest.fixture(scope="session")
def models_dir() -> Path:
    """The directory `facesculpt setup` filled; tests that need the networks skip when it is empty."""
    path = model_home()
    if not (path / "manifest.json").is_file():
        pytest.skip(f"no converted networks in {path}: run `facesculpt setup` first")
    return path


REPO_ROOT = Path(__file__).resolve().parent.parent


# -- the suite writes only into temporary folders ------------------------------------------------
# Files a test run may leave in the checkout: Python's and tools' caches, the install.
_CACHES = ("__pycache__", ".egg-info", ".ruff_cache", ".pytest_cache", ".venv/")
_BEFORE = pytest.StashKey[set]()


def untracked_files() -> set[str] | None:
    """Untracked and ignored files of the checkout (caches aside), or None outside a git checkout."""
    try:
        out = subprocess.run(["git", "status", "--porcelain", "--untracked-files=all", "--ignored"],
                             cwd=REPO_ROOT, capture_output=True, text=True, timeout=30)
    except (OSError, subprocess.TimeoutExpired):
        return None
    if out.returncode != 0:
        return None
    return {line[3:] for line in out.stdout.splitlines()
            if line[:2] in ("??", "!!") and not any(c in line for c in _CACHES)}


def pytest_sessionstart(session):
    session.config.stash[_BEFORE] = untracked_files()


def pytest_sessionfinish(session, exitstatus):
    before, after = session.config.stash.get(_BEFORE, None), untracked_files()
    if before is None or after is None:
        return
    left = sorted(after - before)
    if left:
        print(f"\nthe test run left files in the checkout (tests must write only into temporary folders): "
              f"{', '.join(left[:10])}", file=sys.stderr)
        session.exitstatus = pytest.ExitCode.TESTS_FAILED



def published_into(pub, messages: list) -> list:
    """Append every message ``pub`` publishes to ``messages`` (and still publish it); returns ``messages``."""
    publish = pub.publish
    pub.publish = lambda msg: (messages.append(msg), publish(msg))[1]
    return messages


def load_scale(cap: float = 4.0) -> float:
    """How many times slower than an idle machine this one is now: the 1-minute load average per
    CPU this process may use, at least 1 and at most ``cap``. Tests that bound a time (a respawn, a
    recovery) or a rate multiply by it, so that a machine busy with something else does not fail
    them; on an idle machine the bounds are as written."""
    return min(cap, max(1.0, os.getloadavg()[0] / len(os.sched_getaffinity(0))))


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


# -- a running graph for tests: a master on a free port, processes cleaned up -----------------------
class Graph:
    """Processes of one test's graph; every one is stopped at teardown."""

    def __init__(self, env: dict):
        self.env = env
        self.procs: list[subprocess.Popen] = []
        self.nodes = []

    def spawn(self, *args: str, stdout=None, stderr=None) -> subprocess.Popen:
        """Start `facesculpt ARGS...` as a process of this graph."""
        proc = subprocess.Popen([sys.executable, "-m", "facesculpt.cli", *args], env=self.env, cwd=REPO_ROOT,
                                stdout=stdout, stderr=stderr)
        self.procs.append(proc)
        return proc

    def run(self, *args: str, timeout: float = 60) -> subprocess.CompletedProcess:
        """Run `facesculpt ARGS...` to completion, capturing output."""
        return subprocess.run([sys.executable, "-m", "facesculpt.cli", *args], env=self.env, cwd=REPO_ROOT,
                              capture_output=True, text=True, timeout=timeout)

    def node(self, node):
        """Start an in-process node (its threads) and close it at teardown."""
        node.start()
        self.nodes.append(node)
        return node

    def spin_until(self, node, predicate, timeout: float) -> bool:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            node.spin_once(0.02)
            if predicate():
                return True
        return False

    def close(self) -> None:
        for node in self.nodes:
            node.close()
        for proc in self.procs:
            if proc.poll() is None:
                proc.send_signal(signal.SIGTERM)
        for proc in self.procs:
            try:
                proc.wait(3)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()


@pytest.fixture
def graph(monkeypatch):
    """A master on a free loopback port and a private socket directory for one test."""
    run_dir = tempfile.mkdtemp(prefix="fs-")
    address = f"tcp://127.0.0.1:{free_port()}"
    monkeypatch.setenv("FACESCULPT_MASTER", address)
    monkeypatch.setenv("FACESCULPT_RUN_DIR", run_dir)
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    g = Graph(env)
    g.address = address
    g.master = g.spawn("master")
    from facesculpt.runtime.master import master_alive

    deadline = time.monotonic() + 10
    while not master_alive(address, 0.2):
        assert time.monotonic() < deadline, "master did not start"
    yield g
    g.close()
    shutil.rmtree(run_dir, ignore_errors=True)
