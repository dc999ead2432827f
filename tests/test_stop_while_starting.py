"""A node process told to stop (Ctrl-C, the launcher's SIGTERM) while it is still starting stops
at once and says so once, exit status 0: while it imports its libraries (before the node handles
signals itself: `facesculpt run` holds them) and while its setup runs (a stop asked for during
setup holds)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys

import pytest

SLOW_NODE = '''
import os, sys, time
from facesculpt.runtime.node import Node
print("importing", file=sys.stderr, flush=True)
time.sleep(float(os.environ.get("SLOW_IMPORT_S", "0")))


class Slow(Node):
    NAME = "slow"
    PARAMS = {"setup_s": 0.0}

    def setup(self):
        print("setting up", file=sys.stderr, flush=True)
        time.sleep(self.params.setup_s)
'''


def _stop_while(graph, tmp_path, marker: str, signum: int, *params: str, **env: str) -> tuple[int, str]:
    """Run the slow node, send ``signum`` once it wrote ``marker``; its exit status and stderr."""
    path = tmp_path / "slow_node.py"
    path.write_text(SLOW_NODE)
    proc = subprocess.Popen([sys.executable, "-m", "facesculpt.cli", "run", f"{path}:Slow", *params],
                            env={**graph.env, **env}, stderr=subprocess.PIPE, text=True)
    graph.procs.append(proc)
    lines = []
    for line in iter(proc.stderr.readline, ""):
        lines.append(line)
        if line.strip() == marker:
            os.kill(proc.pid, signum)
            break
    try:
        _, out = proc.communicate(timeout=20)
    except subprocess.TimeoutExpired:
        proc.kill()
        _, out = proc.communicate()
        pytest.fail(f"the node did not stop: {''.join(lines) + out}")
    return proc.returncode, "".join(lines) + out


@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM])
@pytest.mark.slow
def test_a_stop_while_the_node_imports_stops_it_before_setup(graph, tmp_path, signum):
    code, log = _stop_while(graph, tmp_path, "importing", signum, SLOW_IMPORT_S="2")
    assert code == 0, log
    assert log.count(f"[facesculpt.slow] stopping ({signal.Signals(signum).name})") == 1, log
    assert "setting up" not in log and "Traceback" not in log, log


@pytest.mark.slow
def test_a_stop_during_setup_holds(graph, tmp_path):
    code, log = _stop_while(graph, tmp_path, "setting up", signal.SIGINT, "setup_s=2")
    assert code == 0, log
    assert log.count("[facesculpt.slow] stopping (SIGINT)") == 1 and "Traceback" not in log, log
