"""The graph half of `facesculpt bench`: the pipeline as separate processes (``facesculpt
launch`` of a generated launch file), measured by an in-process subscriber: frames out per second,
end-to-end latency, the longest stall, the camera frames dropped, and each node's stage times, rate
and CPU use (module docstring of :mod:`facesculpt.app.bench`).
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

#: The frame size the bench measures at by default, px (the paper's Table 2).
SIZE = (856, 480)
#: The bench's timeline: the window cut into slices of this many seconds, each node's CPU sampled this often.
TIMELINE_SLICE_S = 2.0
CPU_SAMPLE_S = 0.5
#: A scenario's preset load not yet in the deformer's counters this long after (s) is sent again (its
#: diagnostics come every second, so two of them have passed; a load applied twice is the same edit).
RESEND_LOAD_S = 2.5


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def launch_spec(source: str, model: str, camera_fps: float, size: tuple[int, int] = SIZE,
                resize: str = "stretch", pace: int = 2, refine: str | None = None,
                memory: str = "off", depth: str = "off") -> dict:
    """The launch file of the measured graph; the camera delivers ``size`` (px: :func:`bench_size`,
    stretched, or ``--size``, filled), with ``pace`` frames in flight (0: every frame it reads);
    ``refine``: the fitter's (None: off); ``memory`` "on": the renderer's background plate and
    texture atlas on (issue 16); ``depth`` "on": the fitter refines each fit on the frame's depth image
    (an RGB-D source, issue 49)."""
    return {"nodes": [
        {"name": "camera", "node": "camera", "required": True,
         "params": {"source": source, "width": size[0], "height": size[1], "resize": resize,
                    "fps": camera_fps, "loop": True, "pace_by": "render/done" if pace else "",
                    "pace_in_flight": max(1, pace)}},
        {"name": "landmarks", "node": "landmarks"},
        {"name": "fitter", "node": "fitter", "params": {"model": model, "refine": refine or "off", "depth": depth}},
        {"name": "deformer", "node": "deformer"},
        {"name": "renderer", "node": "renderer",
         "params": {"pairing": "sync", "publish": True, "plate": memory, "atlas": memory}},
    ]}


def node_processes(launch_pid: int) -> dict:
    """Node name -> psutil.Process of the graph started by the launcher ``launch_pid``."""
    import psutil

    out = {}
    try:
        children = psutil.Process(launch_pid).children(recursive=True)
    except psutil.Error:
        return out
    for child in children:
        try:
            cmd = child.cmdline()
        except psutil.Error:
            continue
        if "--config-json" in cmd:
            out[json.loads(cmd[cmd.index("--config-json") + 1]).get("name", "?")] = child
        elif "master" in cmd:
            out["master"] = child
    return out


class _CpuSamples:
    """Each node's CPU seconds (``samples``: (ns, node -> s)), taken by :meth:`tick` at most every
    CPU_SAMPLE_S."""

    def __init__(self, procs: dict, t0_ns: int, first: dict):
        self.procs, self.samples = procs, [(t0_ns, first)]

    def tick(self) -> None:
        if time.time_ns() - self.samples[-1][0] >= CPU_SAMPLE_S * 1e9:
            self.samples.append((time.time_ns(), _cpu_seconds(self.procs)))


def _cpu_seconds(procs: dict) -> dict:
    import psutil

    out = {}
    for name, proc in procs.items():
        try:
            t = proc.cpu_times()
            out[name] = t.user + t.system
        except psutil.Error:
            pass
    return out


def node_figures(diagnostics: dict[str, list[dict]]) -> dict[str, dict]:
    """Per node (tools' own listeners, named ``_...``, aside): mean stage times (ms) over the
    window's diagnostics, and the last rates, drops, counters and error count."""
    nodes = {}
    for name, values in diagnostics.items():
        if name.startswith("_"):
            continue
        stages: dict[str, list[float]] = {}
        for v in values:
            for k, ms in (v.get("stages_ms") or {}).items():
                stages.setdefault(k, []).append(float(ms))
        last = values[-1]
        nodes[name] = {
            "stages_ms": {k: round(float(np.mean(v)), 3) for k, v in stages.items()},
            "rate_hz": last.get("rate_hz", {}),
            "dropped": last.get("dropped", {}),
            "errors": last.get("errors", 0),
            "counters": last.get("counters", {}),
        }
    return nodes


def _stop(proc: subprocess.Popen) -> None:
    """SIGTERM the launcher (it stops its nodes), SIGKILL it after 15 s."""
    if proc.poll() is None:
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(15)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


def _launch(workdir: Path, address: str, spec: dict) -> tuple[subprocess.Popen, object]:
    """`facesculpt launch` of ``spec`` with its own master at ``address``, sockets and
    ``launch.log`` in ``workdir``; returns (process, open log) once the master answers
    (RuntimeError after 20 s)."""
    import yaml

    from facesculpt.runtime.master import master_alive

    spec_file = workdir / "bench.yaml"
    spec_file.write_text(yaml.safe_dump(spec))
    log = open(workdir / "launch.log", "w")
    env = dict(os.environ, FACESCULPT_MASTER=address, FACESCULPT_RUN_DIR=str(workdir), PYTHONUNBUFFERED="1")
    proc = subprocess.Popen([sys.executable, "-m", "facesculpt.cli", "launch", str(spec_file)], env=env,
                            stdout=log, stderr=subprocess.STDOUT)
    deadline = time.monotonic() + 20
    while not master_alive(address, 0.2):
        if proc.poll() is not None or time.monotonic() > deadline:
            _stop(proc)
            log.close()
            raise RuntimeError(f"the graph did not start (see {log.name})")
    return proc, log


def _keep_diagnostics(msg, diagnostics: dict, camera_sent: list) -> None:
    """Keep a node's diagnostics; the camera's frames sent so far, with the arrival time (ns)."""
    diagnostics.setdefault(msg.node, []).append(msg.values)
    if msg.node != "camera":
        return
    # Frames the camera read: a paced camera (pace_by) skips some before they are published.
    sent = (msg.values.get("counters") or {}).get("frames_read", (msg.values.get("published") or {}).get("camera/image"))
    if sent is not None:
        camera_sent.append((time.time_ns(), int(sent)))


def measure_graph(source: str, model: str, preset_file: Path, camera_fps: float, window_s: float,
                  warmup_s: float, size: tuple[int, int] = SIZE, start_timeout_s: float = 90.0,
                  resize: str = "stretch", scenario: bool = False, pace: int = 2, refine: str | None = None,
                  memory: str = "off", depth: str = "off") -> dict:
    """Frames out per second, end-to-end latency (p50/p95/p99), the longest stall (the longest gap
    between two output frames) and the camera frames that never came out, of the graph as
    separate processes. ``scenario``: the window starts with the first frames out and holds the
    user's actions of :class:`~facesculpt.app.bench_scenario.BenchScenario` (else it starts
    ``warmup_s`` after the edit is in place and nothing is sent during it); ``refine``: the
    fitter's (None: off); ``memory``: the renderer's plate and atlas; ``depth``: the fitter's (:func:`launch_spec`)."""
    from facesculpt.msgs import Deformation, Diagnostics, Image, InputEvent
    from facesculpt.runtime.node import Node
    from facesculpt.runtime.qos import EVENTS, EVERY_MESSAGE

    workdir = Path(tempfile.mkdtemp(prefix="fs-bench-"))
    address = f"tcp://127.0.0.1:{free_port()}"
    log_path = workdir / "launch.log"
    spec = launch_spec(source, model, camera_fps, size, resize, pace, refine, memory, depth)
    proc, log = _launch(workdir, address, spec)
    listener = None
    try:
        arrivals: list[tuple[int, int]] = []  # (arrival ns, stamp ns)
        diagnostics: dict[str, list[dict]] = {}
        deformed = []
        listener = Node(name=f"_bench_{os.getpid()}", master=address)
        listener.subscribe("render/image", Image, lambda m: arrivals.append((time.time_ns(), m.stamp)),
                           qos=EVERY_MESSAGE)
        camera_sent: list[tuple[int, int]] = []  # (arrival ns, camera/image published so far)
        listener.subscribe("diagnostics", Diagnostics, lambda m: _keep_diagnostics(m, diagnostics, camera_sent),
                           qos=EVERY_MESSAGE)
        listener.subscribe("face/deformation", Deformation,
                           lambda m: deformed.append(float(np.abs(m.displacement).max()) if m.displacement.size else 0.0))
        events = listener.advertise("input/events", InputEvent, qos=EVENTS)
        listener.start()

        ticks: list = []  # called on every spin (the window's CPU sampler)

        def spin_for(seconds: float, until=lambda: False):
            end = time.monotonic() + seconds
            while time.monotonic() < end and not until():
                listener.spin_once(0.02)
                for tick in ticks:
                    tick()
                if proc.poll() is not None:
                    raise RuntimeError(f"the graph stopped (exit code {proc.returncode}; see {log_path})")

        def load_preset():
            events.publish(InputEvent(stamp=time.time_ns(), kind="command", command="load_preset",
                                      argument=str(preset_file), source="bench"))

        _bring_up(spin_for, arrivals, None if scenario else deformed, load_preset, start_timeout_s, diagnostics,
                  log_path)
        if not scenario:
            spin_for(warmup_s)
        procs = node_processes(proc.pid)
        cpu0 = _cpu_seconds(procs)
        t0, t0_ns = time.monotonic(), time.time_ns()  # before the clear: every frame kept arrives after t0_ns
        for kept in (arrivals, diagnostics, camera_sent):
            kept.clear()
        cpu = _CpuSamples(procs, t0_ns, cpu0)
        ticks.append(cpu.tick)
        _window(spin_for, events, window_s, preset_file if scenario else None, diagnostics)
        elapsed = time.monotonic() - t0
        cpu1 = _cpu_seconds(procs)
        cpu.samples.append((time.time_ns(), cpu1))
        window = list(arrivals)
    finally:
        if listener is not None:
            listener.close()
        _stop(proc)
        log.close()
    if len(window) < 2:
        raise RuntimeError(f"the graph gave {len(window)} frames in {window_s} s (see {log_path})")
    shutil.rmtree(workdir, ignore_errors=True)  # kept when something failed: its launch.log says why
    nodes = node_figures(diagnostics)
    for name in cpu1:
        if name in cpu0:
            nodes.setdefault(name, {})["cpu_percent"] = round(100.0 * (cpu1[name] - cpu0[name]) / elapsed, 1)
    return {**output_figures(window, camera_sent), "window_s": round(elapsed, 2), "nodes": nodes,
            "timeline": timeline_figures(window, cpu.samples, t0_ns)}


def _bring_up(spin_for, arrivals: list, deformed: list | None, load_preset, timeout_s: float, diagnostics: dict,
              log_path: Path) -> None:
    """Wait until frames come out and (``deformed`` given) the edit is in place, loading the preset
    until it lands; RuntimeError naming what was heard after ``timeout_s``."""
    def edited() -> bool:
        return deformed is None or (bool(deformed) and max(deformed) > 0)

    deadline = time.monotonic() + timeout_s
    while not (arrivals and edited()):
        if time.monotonic() > deadline:
            heard = ", ".join(sorted(n for n in diagnostics if not n.startswith("_"))) or "no node"
            raise RuntimeError(f"the graph gave {len(arrivals)} frames and no edit within {timeout_s:.0f} s; "
                               f"diagnostics heard from {heard} (see {log_path})")
        if not edited():
            load_preset()
        spin_for(1.0, lambda: bool(arrivals) and edited())


def _window(spin_for, events, window_s: float, scenario_preset: Path | None, diagnostics: dict) -> None:
    """Spin through the measured window; with ``scenario_preset``, send the scenario's events as their
    time comes. A preset load the deformer has not counted (its diagnostics) RESEND_LOAD_S later is sent
    again: the first goes out as the window opens, and a deformer that has not yet connected to this
    publisher (a loaded machine) would miss it."""
    if scenario_preset is None:
        spin_for(window_s)
        return
    from facesculpt.app.bench_scenario import BenchScenario

    def loads_counted() -> int:
        last = (diagnostics.get("deformer") or [{}])[-1]
        return int((last.get("counters") or {}).get("preset_loaded", 0))

    scenario, t0 = BenchScenario(str(scenario_preset)), time.monotonic()
    loads_sent, unacknowledged = loads_counted(), None   # (the load event, when it was sent)
    while (elapsed := time.monotonic() - t0) < window_s:
        for event in scenario.due(elapsed):
            events.publish(event)
            if event.kind == "command" and event.command == "load_preset":
                loads_sent, unacknowledged = loads_sent + 1, (event, elapsed)
        if unacknowledged is not None and elapsed - unacknowledged[1] > RESEND_LOAD_S:
            if loads_counted() >= loads_sent:
                unacknowledged = None
            else:
                events.publish(unacknowledged[0])
                unacknowledged = (unacknowledged[0], elapsed)
        spin_for(min(0.01, window_s - elapsed))


def output_figures(window: list[tuple[int, int]], camera_sent: list[tuple[int, int]]) -> dict:
    """The rate, latency, longest stall and dropped frames of the output frames ``window``
    ((arrival ns, capture stamp ns)), with the camera's reports (arrival ns, frames sent so far)."""
    latency = np.array([(a - s) / 1e6 for a, s in window])
    gaps_ms = np.diff([a for a, _ in window]) / 1e6
    dropped = None
    if len(camera_sent) >= 2:  # camera frames sent between two of its reports, against frames out then
        (t_first, n_first), (t_last, n_last) = camera_sent[0], camera_sent[-1]
        came_out = sum(1 for a, s in window if t_first <= s <= t_last)
        dropped = max(0, (n_last - n_first) - came_out)
    return {
        "pipelined_fps": round((len(window) - 1) / max(1e-9, (window[-1][0] - window[0][0]) / 1e9), 2),
        "frames_out": len(window),
        "latency_ms": {"p50": round(float(np.percentile(latency, 50)), 2),
                       "p95": round(float(np.percentile(latency, 95)), 2),
                       "p99": round(float(np.percentile(latency, 99)), 2),
                       "mean": round(float(latency.mean()), 2)},
        "longest_stall_ms": round(float(gaps_ms.max()), 2),
        "frames_dropped": dropped,
    }


def timeline_figures(window: list[tuple[int, int]], cpu_samples: list[tuple[int, dict]], t0_ns: int,
                     slice_s: float = TIMELINE_SLICE_S) -> list[dict]:
    """The window in slices of ``slice_s`` seconds from ``t0_ns``: per slice the output frames that
    arrived in it (``window``: (arrival ns, capture stamp ns)), their latency p50 / p99 / max (ms)
    and each node's CPU use (% of one core) between the CPU samples (ns, node -> CPU seconds)
    nearest its ends: where in the window a latency tail comes from, and which node was busy then."""
    arrival = np.array([a for a, _ in window], np.float64)
    latency = np.array([(a - s) / 1e6 for a, s in window])
    times = np.array([t for t, _ in cpu_samples], np.float64)
    out = []
    for start in slice_s * np.arange(int((arrival.max() - t0_ns) / 1e9 // slice_s) + 1):
        lo, hi = t0_ns + start * 1e9, t0_ns + (start + slice_s) * 1e9
        inside = (arrival >= lo) & (arrival < hi)
        row = {"start_s": round(float(start), 2), "frames": int(inside.sum())}
        if inside.any():
            lat = latency[inside]
            row.update(p50_ms=round(float(np.median(lat)), 1), p99_ms=round(float(np.percentile(lat, 99)), 1),
                       max_ms=round(float(lat.max()), 1))
        i, j = int(np.abs(times - lo).argmin()), int(np.abs(times - hi).argmin())
        # A slice cut short by the window's end can find its two samples a few ms apart (the last
        # tick and the closing sample): too short a span for CPU seconds counted in clock ticks.
        if j > i and times[j] - times[i] >= CPU_SAMPLE_S * 1e9:
            (ta, ca), (tb, cb) = cpu_samples[i], cpu_samples[j]
            row["cpu_percent"] = {n: round(100.0 * (cb[n] - ca[n]) / ((tb - ta) / 1e9), 1) for n in cb if n in ca}
        out.append(row)
    return out


# -- report -------------------------------------------------------------------------------------------
