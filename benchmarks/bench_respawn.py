"""How fast a killed node is back at work: the demo graph on a looping real video (as in
tests/test_reliability_chaos.py), one node killed with SIGKILL a few times, in this checkout and in
another one (its own venv), alternating, in one run.

    python -m benchmarks.bench_respawn --against /work/wt/startup-old [--node fitter] [--kills 3]
                                       [--rounds 2] [--json out.json]

Per kill: the wall-clock time from the kill to the first ``render/image`` whose capture stamp is
later than the kill ("back", the chaos test's figure), and the CPU time (user + system, from
/proc) the respawned node process had used when that image arrived ("node CPU": its imports, model
load, first frames; on a machine shared with other work the CPU time measures the node's own start-up,
the wall clock the others' too). Reported per checkout as medians over all its kills, and the
ratios this / other. Before each graph, the fitter's start-up in phases (PHASES: imports, model
load, first fit; CPU time of a fresh process of each checkout), also alone with --phases-only.
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import socket
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import psutil
import yaml

from facesculpt.app.bench_graph import node_processes

REPO = Path(__file__).resolve().parents[1]
KEYS = ("spawned_s", "state_s", "back_s", "node_cpu_s")


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def forever_graph(demo_launch: Path, video: Path) -> list[dict]:
    """The nodes of the launch file ``demo_launch`` (the demo's) made to run until stopped: its
    gesture script left out (scripted edits end), every node respawned and none required, the
    camera looping ``video`` with no frame limit, the renderer writing no file. The chaos test's
    graph too."""
    nodes = []
    for entry in yaml.safe_load(Path(demo_launch).read_text())["nodes"]:
        if entry["name"] == "script":
            continue
        entry = dict(entry, respawn=True, required=False)
        if entry["name"] == "camera":
            entry["params"] = dict(entry["params"], source=str(video), loop=True, max_frames=0, wait_subscribers=0)
        if entry["name"] == "renderer":
            entry["params"] = dict(entry["params"], output="")
        nodes.append(entry)
    return nodes


def _launch_file(checkout: Path, video: Path, out: Path) -> Path:
    launch = next(d for d in (checkout / "facesculpt" / "launch", checkout / "launch") if d.is_dir())  # after, before the move
    out.write_text(yaml.safe_dump({"nodes": forever_graph(launch / "demo.yaml", video)}))
    return out


def _cpu_s(proc: psutil.Process | None) -> float:
    try:
        t = proc.cpu_times()
        return t.user + t.system
    except (psutil.NoSuchProcess, AttributeError):
        return float("nan")


# The fitter's start-up in phases, in a fresh process of a checkout: CPU seconds (time.process_time)
# of the imports `facesculpt run fitter` makes, the model load, and the first fits of a frame's
# landmarks (the model's mean seen from the front, 30 frames: the dense neutral is learned then).
PHASES = """
import sys, time
c0 = time.process_time()
from facesculpt import cli
try:
    cli.build_parser(["run", "fitter"])   # what `facesculpt run fitter` builds
except TypeError:                         # a checkout whose parser always has every command
    cli.build_parser()
from facesculpt.nodes import node_class
node_class("fitter")
c1 = time.process_time()
from facesculpt.nodes.fitter import FitterConfig, fit_landmarks, load_model, make_fitter
model = load_model("facemesh")
c2 = time.process_time()
import numpy as np
fitter = make_fitter(model, FitterConfig(), image_size=(640, 480))
pts = np.asarray(model.mean, np.float64)[:468]
pts = np.column_stack([320 + 2 * pts[:, 0], 240 - 2 * pts[:, 1], -2 * pts[:, 2]])[None]
fit_landmarks(fitter, pts, np.ones(1), 0.0)
c3 = time.process_time()
for k in range(1, 30):
    fit_landmarks(fitter, pts, np.ones(1), k / 30)
c4 = time.process_time()
print(c1 - c0, c2 - c1, c3 - c2, c4 - c3, int("scipy" in sys.modules))
"""
PHASE_KEYS = ("imports_cpu_s", "model_cpu_s", "first_fit_cpu_s", "next_29_fits_cpu_s", "scipy_loaded")


def phases(checkout: Path) -> dict:
    """The fitter's start-up phases (PHASES) in a fresh process of ``checkout``'s python."""
    out = subprocess.run([str(checkout / ".venv" / "bin" / "python"), "-c", PHASES], cwd=checkout,
                         capture_output=True, text=True, check=True).stdout.split()
    return dict(zip(PHASE_KEYS, map(float, out)))


def measure(checkout: Path, node_name: str, kills: int, video: Path) -> list[dict]:
    """Launch ``checkout``'s demo graph with its own python, kill ``node_name`` ``kills`` times."""
    from facesculpt.msgs import FaceState, Image
    from facesculpt.runtime.node import Node

    python = checkout / ".venv" / "bin" / "python"
    run_dir = tempfile.mkdtemp(prefix="fs-respawn-")
    master = f"tcp://127.0.0.1:{_free_port()}"
    env = dict(os.environ, FACESCULPT_MASTER=master, FACESCULPT_RUN_DIR=run_dir, PYTHONUNBUFFERED="1")
    os.environ.update(FACESCULPT_MASTER=master, FACESCULPT_RUN_DIR=run_dir)
    launch_path = _launch_file(checkout, video, Path(run_dir) / "graph.yaml")
    proc = subprocess.Popen([str(python), "-m", "facesculpt.cli", "launch", str(launch_path)], env=env,
                            cwd=checkout, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    renders: list[tuple[float, int]] = []
    states: list[tuple[float, int]] = []
    watcher = None
    results = []
    try:
        deadline = time.monotonic() + 90
        while watcher is None:
            try:
                watcher = Node(name="respawn_watcher")
                watcher.subscribe("render/image", Image, lambda m: renders.append((time.monotonic(), m.stamp)))
                watcher.subscribe("face/state", FaceState, lambda m: states.append((time.monotonic(), m.stamp))
                                  if m.vertices.shape[0] else None)
                watcher.start()
            except Exception:
                watcher = None
                time.sleep(0.5)
                if time.monotonic() > deadline:
                    raise

        def spin(predicate, timeout):
            end = time.monotonic() + timeout
            while time.monotonic() < end and not predicate():
                watcher.spin_once(0.02)
            return predicate()

        if not spin(lambda: len(renders) > 20, 120):
            raise RuntimeError(f"{checkout}: the graph never rendered")
        spin(lambda: False, 3.0)   # past the first frames' model updates
        for _ in range(kills):
            victim = node_processes(proc.pid).get(node_name)
            if victim is None:
                raise RuntimeError(f"{checkout}: no {node_name} process")
            victim.send_signal(signal.SIGKILL)
            killed_at, killed_ns = time.monotonic(), time.time_ns()
            new = None
            while new is None and time.monotonic() < killed_at + 10:
                new = node_processes(proc.pid).get(node_name)
                new = None if new is None or new.pid == victim.pid else new
                time.sleep(0.005)
            spawned = time.monotonic() - killed_at
            back = spin(lambda: any(s > killed_ns for _, s in renders), 30)
            arrival = next((t for t, s in renders if s > killed_ns), float("inf"))
            state = next((t for t, s in states if s > killed_ns), float("inf"))
            results.append({"back_s": (arrival - killed_at) if back else float("inf"), "node_cpu_s": _cpu_s(new),
                            "spawned_s": spawned, "state_s": state - killed_at})
            renders.clear()
            states.clear()
            spin(lambda: False, 4.0)
    finally:
        if watcher is not None:
            watcher.close()
        proc.send_signal(signal.SIGINT)
        try:
            proc.wait(15)
        except subprocess.TimeoutExpired:
            proc.kill()
    return results


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--against", type=Path, required=True, help="the other checkout (with DIR/.venv)")
    ap.add_argument("--node", default="fitter")
    ap.add_argument("--kills", type=int, default=3)
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument("--json", type=Path, default=None)
    ap.add_argument("--phases-only", action="store_true", help="only the start-up phases (PHASES), no graph")
    args = ap.parse_args()
    from facesculpt.paths import shared_data_dir

    data = shared_data_dir()
    if data is None:
        print("shared data not found (set FACESCULPT_DATA)", file=sys.stderr)
        return 1
    video = data / "video" / "d3.mp4"
    runs: dict[str, list[dict]] = {"this": [], "other": []}
    steps: dict[str, list[dict]] = {"this": [], "other": []}
    for r in range(args.rounds):
        for label, checkout in (("other", args.against.resolve()), ("this", REPO)) if r % 2 else (
                ("this", REPO), ("other", args.against.resolve())):
            steps[label].append(phases(checkout))
            print(f"round {r + 1} {label} fitter start-up, CPU s: " + ", ".join(
                f"{k} {v:.3f}" for k, v in steps[label][-1].items()), flush=True)
            if args.phases_only:
                continue
            got = measure(checkout, args.node, args.kills, video)
            print(f"round {r + 1} {label}: " + ", ".join(
                f"spawned {g['spawned_s']:.2f} s, face/state {g['state_s']:.2f} s, back {g['back_s']:.2f} s, "
                f"node CPU {g['node_cpu_s']:.2f} s" for g in got), flush=True)
            runs[label] += got
    med = {label: {k: statistics.median(g[k] for g in got) for k in PHASE_KEYS[:4]} for label, got in steps.items()}
    for label in med:
        med[label]["start_up_cpu_s"] = statistics.median(sum(g[k] for k in PHASE_KEYS[:3]) for g in steps[label])
    print("fitter start-up (imports + model + first fit), CPU s, medians over the rounds:")
    for k in (*PHASE_KEYS[:4], "start_up_cpu_s"):
        print(f"  {k:19s} this {med['this'][k]:.3f}  other {med['other'][k]:.3f}  "
              f"this/other {med['this'][k] / max(med['other'][k], 1e-9):.2f}")
    if args.json and args.phases_only:
        args.json.write_text(json.dumps({"phases": steps, "medians": med}, indent=2))
    if args.phases_only:
        return 0
    med = {label: {k: statistics.median(g[k] for g in got) for k in KEYS}
           for label, got in runs.items()}
    print(f"{args.node} killed, medians over {len(runs['this'])} kills each:")
    for k in KEYS:
        print(f"  {k:11s} this {med['this'][k]:.2f}  other {med['other'][k]:.2f}  "
              f"this/other {med['this'][k] / med['other'][k]:.2f}")
    if args.json:
        args.json.write_text(json.dumps({"node": args.node, "runs": runs, "phases": steps, "medians": med}, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
