"""Launch files: start a master and one process per node, respawn, stop cleanly.

A launch file is YAML::

    nodes:
      - name: camera                 # unique node name
        node: camera                 # built-in name, or module:Class, or path/file.py:Class
        params: {source: face.mp4, fps: 30}
        remap: {camera/image: cam0/image}
        respawn: true                # restart when it dies (with backoff)
        required: false              # when it exits, stop the whole graph
        key: hostb                   # (with security) this node's client keypair name
        enabled: false               # listed but not started unless `name.enabled=true` is given

Optional top-level keys: ``transport: tcp`` (default ipc) with ``host: ADDRESS``
(what tcp publishers bind to; default 127.0.0.1, loopback), and ``security:``
(ZeroMQ CURVE, see facesculpt.runtime.security and docs/security.md)::

    security:
      keys: ./keys                   # from `facesculpt keys generate keys`
      server: graph                  # the graph's server keypair name (default graph)
      client: graph                  # the nodes' client keypair name (default: the server's)

Before anything starts, every node's type, params and remaps are checked against its class
(:mod:`facesculpt.runtime.launch_check`; ``facesculpt launch --check FILE`` checks only).
``facesculpt launch FILE name.param=value ...`` overrides params (``name.enabled=true|false``
starts or leaves out an optional node; it is no param). A string param
starting with ``./`` is a path relative to the launch file. Children are
killed with the launcher even if it is killed itself (PR_SET_PDEATHSIG), and on
SIGINT/SIGTERM every node gets SIGTERM; one still running after ``STOP_GRACE_S`` is named (it may be
finishing a file: a video's encoder flushes its last frames, which takes seconds on a busy machine)
and killed after ``STOP_KILL_S``, or at once on a second SIGINT/SIGTERM (``launch`` then exits
non-zero: a file it was writing may be incomplete); the master stops
last (in a session of its own, a Ctrl-C in the terminal does not end it before the nodes).

A node that exits with ``EXIT_BAD_PARAMETER`` (2: a parameter out of its range or choices, or a
resource it names that cannot be used, see facesculpt.runtime.parameters) is not respawned: the
same values would stop it again. Nor is one that exits with ``EXIT_NODE_CLOSED`` (4: the user
closed it, e.g. the renderer's window with ``close: node``); the rest of the graph runs on. A
node marked ``respawn`` that exits 0 comes back like one that died. A node that keeps crashing
quickly is respawned with a growing delay and given up after ``MAX_QUICK_FAILURES`` quick deaths
in a row. When a required node ends, the graph stops; if it failed, ``launch`` exits non-zero
and its last line names the node and the last line the node wrote to stderr (its reason).
"""

from __future__ import annotations

import ctypes
import json
import logging
import os
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import yaml

from facesculpt.runtime.launch_check import check_nodes
from facesculpt.runtime.master import master_address, master_alive
from facesculpt.runtime.parameters import EXIT_BAD_PARAMETER, EXIT_NODE_CLOSED, EXIT_STOP_GRAPH, parse_assignments

# After STOP_GRACE_S the launcher says which nodes it still waits for; after STOP_KILL_S it kills
# them. The long limit is for nodes finishing a file (a killed video writer leaves no playable video).
STOP_GRACE_S = 2.5
STOP_KILL_S = 30.0
# A node that ran this long before dying was healthy: its next respawn starts without backoff
# (otherwise occasional crashes over hours would end at the 5 s cap).
HEALTHY_RUN_S = 5.0
MAX_RESPAWN_DELAY_S = 5.0
# Quick deaths in a row (each within HEALTHY_RUN_S of its start) after which a node is given up.
MAX_QUICK_FAILURES = 8
log = logging.getLogger("facesculpt.launch")


@dataclass
class NodeSpec:
    name: str
    node: str
    params: dict = field(default_factory=dict)
    remap: dict = field(default_factory=dict)
    respawn: bool = False
    required: bool = False
    respawn_delay_s: float = 0.2
    transport: str = "ipc"
    host: str = "127.0.0.1"
    graph_env: dict = field(default_factory=dict)   # security for the whole graph (master included)
    env: dict = field(default_factory=dict)         # this node's own additions (its client key)
    enabled: bool = True                            # false: listed but not started (NAME.enabled=true starts it)


def load_launch(path: str | os.PathLike, overrides: list[str] | None = None,
                node_class: Callable[[str], type] | None = None, left_out: bool = False) -> list[NodeSpec]:
    """Parse and validate a launch file; ``overrides`` are ``name.param=value`` strings. With
    ``node_class`` (a node type -> its Node subclass, from the application), every node is also
    checked against its class, its type, params and remaps (:mod:`.launch_check`), before anything
    starts. Returns the nodes to start, and with ``left_out`` those listed but not enabled too."""
    path = Path(path)
    try:
        doc = yaml.safe_load(path.read_text())
    except FileNotFoundError:
        raise FileNotFoundError(f"launch file {path} not found") from None
    except yaml.YAMLError as exc:
        raise ValueError(f"launch file {path} is not valid YAML: {exc}") from None
    if not isinstance(doc, dict) or not isinstance(doc.get("nodes"), list):
        raise ValueError(f"launch file {path}: expected a mapping with a 'nodes' list")
    extra = set(doc) - {"nodes", "security", "transport", "host", "insecure"}
    if extra:
        raise ValueError(f"launch file {path}: unknown top-level keys {sorted(extra)}")
    transport, host = str(doc.get("transport", "ipc")), str(doc.get("host", "127.0.0.1"))
    if transport not in ("ipc", "tcp"):
        raise ValueError(f"launch file {path}: transport must be ipc or tcp, not {transport!r}")
    graph_env = _security_env(path, doc.get("security"))
    graph_env.update(_exposure_env(path, doc, transport, host))
    specs: list[NodeSpec] = []
    allowed = {"name", "node", "params", "remap", "respawn", "required", "respawn_delay_s", "key", "enabled"}
    for i, entry in enumerate(doc["nodes"]):
        if not isinstance(entry, dict) or "node" not in entry:
            raise ValueError(f"launch file {path}: node #{i + 1} needs at least 'node'")
        extra = set(entry) - allowed
        if extra:
            raise ValueError(f"launch file {path}: node #{i + 1} has unknown keys {sorted(extra)}")
        _check_node_fields(path, i, entry)
        spec = NodeSpec(name=str(entry.get("name", entry["node"])), node=str(entry["node"]),
                        params=dict(entry.get("params") or {}), remap=dict(entry.get("remap") or {}),
                        respawn=bool(entry.get("respawn", False)), required=bool(entry.get("required", False)),
                        respawn_delay_s=float(entry.get("respawn_delay_s", 0.2)),
                        transport=transport, host=host, graph_env=graph_env, enabled=entry.get("enabled", True))
        if "key" in entry:
            if "FACESCULPT_KEYS" not in graph_env:
                raise ValueError(f"launch file {path}: node {spec.name} names a key but there is no security block")
            from facesculpt.runtime.security import ENV_CLIENT, Security

            Security.from_dir(graph_env["FACESCULPT_KEYS"], graph_env.get("FACESCULPT_SERVER_KEY", "graph"),
                              str(entry["key"]))  # fail now, with the file's name, not in the child
            spec.env = {ENV_CLIENT: str(entry["key"])}
        if any(s.name == spec.name for s in specs):
            raise ValueError(f"launch file {path}: two nodes are named {spec.name!r}")
        specs.append(spec)
    # "./x" in a param is relative to the launch file, so shipped files travel with it.
    for spec in specs:
        for key, value in spec.params.items():
            if isinstance(value, str) and value.startswith("./"):
                spec.params[key] = str((path.parent / value).resolve())
    by_name = {s.name: s for s in specs}
    for key, value in parse_assignments(overrides or []).items():
        node_name, dot, param = key.partition(".")
        if not dot or node_name not in by_name:
            raise ValueError(f"override {key}={value}: expected NODE.param=value with NODE one of "
                             f"{', '.join(by_name)}")
        if param == "enabled":  # not a parameter: whether the launcher starts the node at all
            if value.strip().lower() not in ("true", "false"):
                raise ValueError(f"override {key}={value}: enabled must be true or false")
            by_name[node_name].enabled = value.strip().lower() == "true"
            continue
        by_name[node_name].params[param] = value
    if node_class is not None:
        check_nodes(path, specs, node_class)
    return [spec for spec in specs if spec.enabled or left_out]


def _check_node_fields(path: Path, i: int, entry: dict) -> None:
    """One sentence naming the field, the value and what is allowed, for a node entry's fields."""
    where = f"launch file {path}: node #{i + 1} ({entry.get('name', entry['node'])})"
    for key in ("respawn", "required", "enabled"):
        if key in entry and not isinstance(entry[key], bool):
            raise ValueError(f"{where}: {key} must be true or false, not {entry[key]!r}")
    delay = entry.get("respawn_delay_s", 0.2)
    if isinstance(delay, bool) or not isinstance(delay, (int, float)) or not 0 <= delay <= 60:
        raise ValueError(f"{where}: respawn_delay_s must be a number of seconds in [0, 60], not {delay!r}")
    for key in ("params", "remap"):
        if entry.get(key) is not None and not isinstance(entry[key], dict):
            raise ValueError(f"{where}: {key} must be a mapping (name: value), not {entry[key]!r}")


def _exposure_env(path: Path, doc: dict, transport: str, host: str) -> dict:
    """Secure by default: publishers on a network address need a ``security:`` block, or
    ``insecure: true`` said explicitly (then every process may bind in the open, and one warning
    line says what is exposed). Returns the environment the processes need for it."""
    from facesculpt.runtime.security import ENV_INSECURE, check_exposure

    insecure = doc.get("insecure", False)
    if not isinstance(insecure, bool):
        raise ValueError(f"launch file {path}: insecure must be true or false, not {insecure!r}")
    if transport != "tcp" or doc.get("security"):
        return {}
    try:
        warning = check_exposure("the graph's publishers", f"tcp://{host}:*", None, insecure)
    except ValueError as exc:
        raise ValueError(f"launch file {path}: {exc}") from None
    if warning:
        log.warning("%s", warning)
        return {ENV_INSECURE: "1"}
    return {}


def _security_env(path: Path, block) -> dict:
    """The launch file's ``security:`` block as environment variables for every process."""
    if block is None:
        return {}
    from facesculpt.runtime.security import Security, SecurityError, env_for

    if not isinstance(block, dict) or "keys" not in block or set(block) - {"keys", "server", "client"}:
        raise ValueError(f"launch file {path}: security needs 'keys' (a directory) and optionally "
                         f"'server' and 'client' key names")
    keys = Path(str(block["keys"]))
    keys = keys if keys.is_absolute() else (path.parent / keys).resolve()
    server, client = block.get("server"), block.get("client")
    try:
        Security.from_dir(keys, str(server or "graph"), str(client) if client else None)
    except SecurityError as exc:
        raise ValueError(f"launch file {path}: {exc}") from None
    return env_for(keys, str(server) if server else None, str(client) if client else None)


def _die_with_parent() -> None:
    # Linux: the child gets SIGTERM when the launcher dies, even by SIGKILL: no orphans.
    try:
        libc = ctypes.CDLL("libc.so.6", use_errno=True)
        libc.prctl(1, signal.SIGTERM)  # PR_SET_PDEATHSIG
    except OSError:
        pass


def _spawn(argv: list[str], env: dict, stderr=None, own_session: bool = False) -> subprocess.Popen:
    """Start a child that dies with the launcher; ``own_session``: in a session of its own, out of
    reach of the terminal's Ctrl-C (SIGINT goes to the whole foreground process group)."""
    return subprocess.Popen(argv, env=env, stderr=stderr, preexec_fn=_die_with_parent,
                            start_new_session=own_session)


def _forward_stderr(child: Child) -> None:
    """Pass the child's stderr through to ours, line by line, remembering its last line."""
    def forward(stream, out=sys.stderr):
        for raw in iter(stream.readline, b""):
            line = raw.decode(errors="replace")
            if line.strip():
                child.last_line = line.strip()
            out.write(line)
            out.flush()
        stream.close()

    threading.Thread(target=forward, args=(child.proc.stderr,), daemon=True,
                     name=f"stderr-{child.spec.name}").start()


def node_argv(spec: NodeSpec) -> list[str]:
    config = {"name": spec.name, "params": spec.params, "remap": spec.remap}
    if spec.transport != "ipc" or spec.host != "127.0.0.1":
        config.update(transport=spec.transport, host=spec.host)
    return [sys.executable, "-m", "facesculpt.cli", "run", spec.node, "--config-json", json.dumps(config)]


@dataclass
class Child:
    spec: NodeSpec
    proc: subprocess.Popen | None = None
    restarts: int = 0
    failures: int = 0        # consecutive quick deaths: the respawn backoff exponent
    started_at: float = 0.0
    state: str = "starting"
    next_start: float = 0.0
    exit_code: int | None = None
    last_line: str = ""      # the last line the process wrote to stderr (a failure's reason)


class Launcher:
    """Supervises the processes of one launch file."""

    def __init__(self, specs: list[NodeSpec], master: str | None = None, status=print):
        self.specs = specs
        self.master = master or master_address()
        self.status = status
        self.children = [Child(s) for s in specs]
        self.master_proc: subprocess.Popen | None = None
        self.stopping = False
        self.in_stop = False    # stop() is waiting for the nodes
        self.kill_now = False   # a second SIGINT/SIGTERM came while it waited
        self.killed: list[str] = []  # nodes that had to be killed while stopping
        self.stop_reason = ""
        self.env = dict(os.environ, FACESCULPT_MASTER=self.master, PYTHONUNBUFFERED="1")
        if specs:
            self.env.update(specs[0].graph_env)
        from facesculpt.runtime.security import Security

        self.security = Security.from_env(self.env)

    def start_master(self) -> None:
        if master_alive(self.master, security=self.security):
            self.status(f"using the master already running at {self.master}")
            return
        # The master stops last (stop()): a Ctrl-C in the terminal reaches the nodes and the
        # launcher, but not the master, which the nodes still talk to while they stop.
        self.master_proc = _spawn([sys.executable, "-m", "facesculpt.cli", "master"], self.env, own_session=True)
        deadline = time.monotonic() + 10
        while not master_alive(self.master, 0.2, security=self.security):
            if self.master_proc.poll() is not None or time.monotonic() > deadline:
                raise RuntimeError(f"the master did not start at {self.master}")
            time.sleep(0.05)

    def _start(self, child: Child) -> None:
        child.proc = _spawn(node_argv(child.spec), dict(self.env, **child.spec.env), stderr=subprocess.PIPE)
        _forward_stderr(child)
        child.started_at = time.monotonic()
        child.state = "running"
        self.status(f"[{child.spec.name}] running (pid {child.proc.pid}"
                    + (f", restart {child.restarts}" if child.restarts else "") + ")")

    def poll(self) -> bool:
        """Check children once; returns False when the graph should stop."""
        now = time.monotonic()
        alive = False
        for child in self.children:
            if child.state == "waiting" and now >= child.next_start:
                child.restarts += 1
                self._start(child)
            if child.proc is not None and child.state == "running":
                code = child.proc.poll()
                if code is None:
                    alive = True
                    continue
                child.exit_code = code
                how = f"exit code {code}" if code >= 0 else f"killed by {signal.Signals(-code).name}"
                if code == EXIT_STOP_GRAPH:
                    self.status(f"[{child.spec.name}] asked the graph to stop (its window was closed)")
                    child.state = "done"
                    return False
                if child.spec.required:
                    self.status(f"[{child.spec.name}] ended ({how}); it is required, so the graph stops")
                    child.state = "done"
                    if code not in (0, EXIT_NODE_CLOSED):
                        self._reason(child, how)
                    return False
                if code == EXIT_NODE_CLOSED:
                    child.state = "done"
                    self.status(f"[{child.spec.name}] closed by the user (its window); not respawning")
                elif child.spec.respawn and code == EXIT_BAD_PARAMETER:
                    child.state = "done"
                    self.status(f"[{child.spec.name}] ended ({how}): a parameter, or what it names, cannot be used "
                                f"(its message above); not respawning")
                elif child.spec.respawn and not self.stopping:
                    # A node that ran healthily comes back at once (the graph waits on it); back off
                    # only while it keeps dying quickly (a crash loop): delay, 2 x delay, ... capped.
                    child.failures = 0 if now - child.started_at >= HEALTHY_RUN_S else child.failures + 1
                    if child.failures >= MAX_QUICK_FAILURES:
                        child.state = "done"
                        self.status(f"[{child.spec.name}] died ({how}) {child.failures} times in a row within "
                                    f"{HEALTHY_RUN_S:.0f} s of starting; giving up on it")
                        continue
                    delay = 0.0 if child.failures == 0 else min(
                        MAX_RESPAWN_DELAY_S, child.spec.respawn_delay_s * 2 ** min(child.failures - 1, 5))
                    child.state, child.next_start = "waiting", now + delay
                    self.status(f"[{child.spec.name}] died ({how}); respawning in {delay:.1f} s")
                    alive = True
                else:
                    child.state = "done"
                    self.status(f"[{child.spec.name}] ended ({how})")
            elif child.state == "waiting":
                alive = True
        if self.master_proc is not None and self.master_proc.poll() is not None and not self.stopping:
            self.status("[master] died; restarting it")
            self.start_master()
        return alive

    def _reason(self, child: Child, how: str) -> None:
        """Remember why the graph stopped: printed as ``launch``'s last line."""
        self.stop_reason = f"the graph stopped: required node {child.spec.name} failed ({how})" + (
            f": {child.last_line.removeprefix('facesculpt: ')}" if child.last_line else "")

    def run(self) -> int:
        """Start everything and supervise until SIGINT/SIGTERM or until every node ended."""
        def _on_signal(signum, frame):
            # A signal while the nodes are being stopped means: do not wait for them.
            self.kill_now = self.in_stop
            self.stopping = True
        old = {s: signal.signal(s, _on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
        try:
            self.start_master()
            for child in self.children:
                self._start(child)
            while not self.stopping and self.poll():
                time.sleep(0.05)
        finally:
            self.stop()
            for s, handler in old.items():
                signal.signal(s, handler)
        if self.stop_reason:
            time.sleep(0.05)  # let the forwarders write the nodes' last lines first
            self.status(self.stop_reason)
        failed = [c for c in self.children if c.exit_code not in (None, 0, EXIT_STOP_GRAPH, EXIT_NODE_CLOSED)
                  and (not c.spec.respawn or c.exit_code == EXIT_BAD_PARAMETER
                       or c.failures >= MAX_QUICK_FAILURES)]
        return 1 if failed or self.killed else 0

    def stop(self) -> None:
        """SIGTERM every child; after STOP_GRACE_S name those still running; SIGKILL what is left
        after STOP_KILL_S or on a second SIGINT/SIGTERM."""
        self.stopping = True
        self.in_stop = True
        procs = {c.spec.name: c.proc for c in self.children if c.proc is not None and c.proc.poll() is None}
        for proc in procs.values():
            proc.send_signal(signal.SIGTERM)
        start = time.monotonic()
        named = False
        while any(p.poll() is None for p in procs.values()) and not self.kill_now:
            waited = time.monotonic() - start
            if waited >= STOP_KILL_S:
                break
            if waited >= STOP_GRACE_S and not named:
                named = True
                left = ", ".join(n for n, p in procs.items() if p.poll() is None)
                self.status(f"waiting for {left} to stop (a file may be being finished); killed in "
                            f"{STOP_KILL_S - waited:.0f} s, or now on a second Ctrl-C")
            time.sleep(0.05)
        for name, proc in procs.items():
            if proc.poll() is None:
                proc.kill()
                proc.wait()
                self.killed.append(name)
                self.status(f"[{name}] did not stop: killed (a file it was writing may be incomplete)")
        if self.master_proc is not None and self.master_proc.poll() is None:
            self.master_proc.terminate()
            try:
                self.master_proc.wait(1.0)
            except subprocess.TimeoutExpired:
                self.master_proc.kill()
                self.master_proc.wait()
        self.status("all nodes stopped")
