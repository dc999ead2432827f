"""The graph's commands: master, run, launch, node, topic, bag."""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import time

from facesculpt.msgs import REGISTRY, summarize
from facesculpt.runtime.node import Node
from facesculpt.runtime.qos import EVENTS, EVERY_MESSAGE, SENSOR_DATA


def register(sub) -> None:
    p = sub.add_parser("master", help="run the registry of nodes, topics and latched messages")
    p.add_argument("--address", help="endpoint to bind (default $FACESCULPT_MASTER or tcp://127.0.0.1:11411)")
    p.set_defaults(func=cmd_master)

    p = sub.add_parser("run", help="run one node: facesculpt run NODE [param=value ...]", add_help=False)
    p.add_argument("-h", "--help", action="store_true", dest="run_help", help="list the built-in nodes")
    p.add_argument("node", nargs="?", help="built-in name (camera, landmarks, fitter, ...) or module:Class")
    p.add_argument("args", nargs="...", help="[--name N] [--remap from=to] [param=value ...]; NODE --help lists params")
    p.set_defaults(func=cmd_run)

    p = sub.add_parser("launch", help="start a graph from a launch file", description=LAUNCH_DESCRIPTION,
                       epilog=shipped_launch_list(), formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("file", help="a launch file path, or the name of a shipped one (listed below)")
    p.add_argument("overrides", nargs="*", metavar="node.param=value",
                   help="override a node's param, or NODE.enabled=true|false to start or leave out a node")
    p.add_argument("--check", action="store_true",
                   help="check the file (node types, params, remaps) and say ok in one line; start nothing")
    p.set_defaults(func=cmd_launch)

    p = sub.add_parser("node", help="nodes of the running graph")
    nsub = p.add_subparsers(dest="node_command", metavar="list", required=True)
    q = nsub.add_parser("list", help="list running nodes")
    q.add_argument("--json", action="store_true")
    q.set_defaults(func=cmd_node_list)

    p = sub.add_parser("topic", help="topics of the running graph")
    tsub = p.add_subparsers(dest="topic_command", metavar="list|echo|hz", required=True)
    q = tsub.add_parser("list", help="list topics with types, publishers and subscribers")
    q.add_argument("--json", action="store_true")
    q.set_defaults(func=cmd_topic_list)
    q = tsub.add_parser("echo", help="print messages (arrays summarised by shape/dtype/min/max)")
    q.add_argument("topic")
    q.add_argument("--count", type=int, default=0, help="stop after N messages")
    q.add_argument("--json", action="store_true", help="one JSON object per line")
    q.add_argument("--timeout", type=float, default=0, help="give up after S seconds (0: wait forever)")
    q.set_defaults(func=cmd_topic_echo)
    q = tsub.add_parser("hz", help="measure a topic's rate")
    q.add_argument("topic")
    q.add_argument("--duration", type=float, default=5.0, help="seconds to measure")
    q.add_argument("--json", action="store_true")
    q.set_defaults(func=cmd_topic_hz)

    p = sub.add_parser("bag", help="record, play and inspect bag files (MCAP)")
    bsub = p.add_subparsers(dest="bag_command", metavar="record|play|info|export", required=True)
    q = bsub.add_parser("record", help="record topics into an MCAP bag")
    q.add_argument("topics", nargs="+")
    q.add_argument("-o", "--output", required=True,
                   help="bag file to write (MCAP; .mcap is added to a name without a suffix)")
    q.add_argument("--duration", type=float, default=0, help="stop after S seconds")
    q.add_argument("--count", type=int, default=0, help="stop after N messages")
    q.add_argument("--compression", choices=["none", "png", "jpeg"], default="none",
                   help="store images losslessly (png) or as jpeg; default raw")
    q.add_argument("--chunk-compression", choices=["lz4", "zstd", "none"], default="lz4",
                   help="compression of the MCAP chunks: lz4 (default: keeps up with a live camera), "
                        "zstd (smaller, about 4x the CPU), none")
    q.set_defaults(func=cmd_bag_record)
    q = bsub.add_parser("play", help="publish a bag's messages again")
    q.add_argument("file")
    rate = q.add_mutually_exclusive_group()
    rate.add_argument("--rate", type=float, default=1.0, help="speed factor (default 1: as recorded)")
    rate.add_argument("--fast", action="store_true", help="as fast as subscribers take them, losing none")
    q.add_argument("--loop", action="store_true",
                   help="play the bag again from the start until stopped; each pass's count is printed")
    q.add_argument("--start", type=float, default=0.0,
                   help="begin S seconds after the bag's first message (found through the MCAP index)")
    q.add_argument("--wait", type=float, default=2.0, help="seconds to wait for subscribers before playing")
    q.set_defaults(func=cmd_bag_play)
    q = bsub.add_parser("info", help="topics, counts, duration, types")
    q.add_argument("file")
    q.add_argument("--json", action="store_true")
    q.set_defaults(func=cmd_bag_info)
    q = bsub.add_parser("export", help="write a bag as another tool's MCAP: --foxglove (images, 3D scene)")
    q.add_argument("file")
    q.add_argument("--foxglove", action="store_true", required=True,
                   help="Foxglove's schemas: images, camera calibration, landmarks, meshes and handles, diagnostics")
    q.add_argument("-o", "--output", required=True, help="MCAP file to write")
    q.add_argument("--jpeg-quality", type=int, default=90, help="images as JPEG of this quality; 0: raw")
    q.set_defaults(func=cmd_bag_export)


# -- master / run / launch -------------------------------------------------------------------
def cmd_master(args) -> int:
    from facesculpt.runtime.master import serve

    serve(args.address)
    return 0


RUN_USAGE = """usage: facesculpt run NODE [--name N] [--remap FROM=TO] [param=value ...]

Runs one node of the graph as this process. NODE is a built-in name, module:Class, or
path/to/file.py:Class (your own node). `facesculpt run NODE --help` lists its parameters.

built-in nodes:
"""


def cmd_run(args) -> int:
    from facesculpt.runtime.stop_signals import hold_stop_signals

    hold_stop_signals()  # a Ctrl-C while the node's libraries load: the node stops, saying so
    from facesculpt.nodes import BUILTIN_NODES, node_class
    from facesculpt.runtime.node import run_node

    if args.node is None:
        width = max(map(len, BUILTIN_NODES))
        print(RUN_USAGE + "\n".join(f"  {name:<{width}}  {target}" for name, target in BUILTIN_NODES.items()))
        return 0 if args.run_help else 2
    return run_node(node_class(args.node), args.args)


LAUNCH_DESCRIPTION = """Start a graph from a launch file: a master and one process per node, respawned as the file
says, all stopped on Ctrl-C. Before anything starts, every node's type, parameters and remaps are
checked against the node itself; a file with a problem is refused in one sentence (exit 1)."""


def shipped_launch_list() -> str:
    """``launch --help``'s epilog: the shipped launch files, each with the first line of its comment."""
    from facesculpt.paths import shipped_launch_files

    lines = ["shipped launch files (facesculpt launch NAME):"]
    files = shipped_launch_files()
    width = max((len(f.stem) for f in files), default=0)
    for path in files:
        first = next((line.lstrip("# ").strip() for line in path.read_text().splitlines() if line.startswith("#")), "")
        lines.append(f"  {path.stem:<{width}}  {first}")
    return "\n".join(lines).replace("%", "%%")  # argparse formats an epilog with %


def cmd_launch(args) -> int:
    from facesculpt.nodes import node_class
    from facesculpt.paths import launch_file
    from facesculpt.runtime.launch_check import summary
    from facesculpt.runtime.launcher import Launcher, load_launch

    path = launch_file(args.file)
    specs = load_launch(path, args.overrides, node_class=node_class, left_out=True)
    if args.check:
        print(summary(path, specs), flush=True)
        return 0
    started = [spec for spec in specs if spec.enabled]
    return Launcher(started, status=lambda line: print(line, flush=True)).run()


# -- introspection ------------------------------------------------------------------------------
def _master_call(op: str) -> dict:
    from facesculpt.runtime.master import MasterClient

    client = MasterClient(timeout_s=2.0)
    try:
        return client.call(op)
    finally:
        client.close()


def _require_master(wait_s: float = 3.0) -> None:
    """RuntimeError in one sentence when no master answers within ``wait_s`` seconds."""
    from facesculpt.runtime.master import master_address, master_alive
    from facesculpt.runtime.security import Security

    security = Security.from_env()
    deadline = time.monotonic() + wait_s
    while not master_alive(master_address(), 0.3, security=security):
        if time.monotonic() > deadline:
            raise RuntimeError(f"no master answers at {master_address()} after {wait_s:.0f} s: start a graph "
                               f"(`facesculpt launch ...`) or a master (`facesculpt master`), or set FACESCULPT_MASTER")


def cmd_node_list(args) -> int:
    nodes = _master_call("nodes")["nodes"]
    if args.json:
        print(json.dumps(nodes, indent=1))
        return 0
    for n in nodes:
        print(f"{n['node']:<24} pid {n['pid']:<8} up {n['uptime_s']:>7.1f} s   "
              f"pub: {', '.join(n['publishes']) or '-'}   sub: {', '.join(n['subscribes']) or '-'}")
    return 0


def cmd_topic_list(args) -> int:
    topics = _master_call("topics")["topics"]
    if args.json:
        print(json.dumps(topics, indent=1))
        return 0
    for t in topics:
        print(f"{t['topic']:<24} {'/'.join(t['types']) or '?':<14} pub: {', '.join(t['publishers']) or '-'}   "
              f"sub: {', '.join(t['subscribers']) or '-'}" + ("   (latched)" if t["latched"] else ""))
    return 0


class _ToolNode(Node):
    """A short-lived node for command-line tools (named after the tool and its pid)."""

    def __init__(self, tool: str, **kw):
        super().__init__(name=f"_{tool}_{os.getpid()}", **kw)


def _run_tool(node: Node, until) -> None:
    import signal

    signal.signal(signal.SIGINT, lambda *a: node.shutdown())
    signal.signal(signal.SIGTERM, lambda *a: node.shutdown())
    node.start()
    try:
        while node.running and not until():
            node.spin_once(0.05)
    finally:
        node.close()


def cmd_topic_echo(args) -> int:
    _require_master()
    node = _ToolNode("echo")
    seen = [0]

    def on_msg(msg):
        seen[0] += 1
        summary = summarize(msg)
        print(json.dumps(_json_safe(summary), default=str, allow_nan=False) if args.json else _pretty(summary),
              flush=True)

    node.subscribe(args.topic, None, on_msg, qos=EVERY_MESSAGE)
    start = time.monotonic()
    _run_tool(node, lambda: (args.count and seen[0] >= args.count)
              or (args.timeout and time.monotonic() - start > args.timeout))
    return 0 if seen[0] or not args.timeout else 1


def _json_safe(value):
    """NaN and infinities are not JSON: they become null."""
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, dict):
        return {k: _json_safe(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_json_safe(v) for v in value]
    return value


def _pretty(summary: dict) -> str:
    lines = ["---"]
    for key, value in summary.items():
        lines.append(f"{key}: {value}")
    return "\n".join(lines)


def cmd_topic_hz(args) -> int:
    _require_master()
    node = _ToolNode("hz")
    arrivals: list[float] = []
    node.subscribe(args.topic, None, lambda msg: arrivals.append(time.monotonic()), qos=EVERY_MESSAGE)
    start = time.monotonic()
    _run_tool(node, lambda: time.monotonic() - start > args.duration)
    result = {"topic": args.topic, "messages": len(arrivals), "duration_s": args.duration}
    if len(arrivals) >= 2:
        import numpy as np

        gaps = np.diff(arrivals)
        result.update(rate_hz=round((len(arrivals) - 1) / (arrivals[-1] - arrivals[0]), 2),
                      min_gap_ms=round(gaps.min() * 1e3, 2), max_gap_ms=round(gaps.max() * 1e3, 2),
                      std_gap_ms=round(gaps.std() * 1e3, 2))
    if args.json:
        print(json.dumps(result))
    elif "rate_hz" in result:
        print(f"{args.topic}: {result['rate_hz']} Hz over {len(arrivals)} messages "
              f"(gap min {result['min_gap_ms']} ms, max {result['max_gap_ms']} ms, std {result['std_gap_ms']} ms)")
    else:
        print(f"{args.topic}: {len(arrivals)} messages in {args.duration} s")
    return 0


# -- bags ----------------------------------------------------------------------------------------
def cmd_bag_record(args) -> int:
    from pathlib import Path

    from facesculpt.runtime.bag import BagError, BagWriter

    if not Path(args.output).suffix:
        args.output += ".mcap"
    writer = BagWriter(args.output, compression=args.compression, chunk_compression=args.chunk_compression)
    node = _ToolNode("bag_record")
    failure: list[str] = []

    def on_msg(msg, frames, topic):
        if failure:
            return
        try:
            writer.write(time.time_ns(), topic, frames)
        except BagError as exc:
            failure.append(str(exc))

    for topic in args.topics:
        node.subscribe(topic, None, lambda m, f, t=topic: on_msg(m, f, t), qos=EVERY_MESSAGE, raw=True)
    start = time.monotonic()
    try:
        _run_tool(node, lambda: _flush_due(writer, failure) or bool(failure)
                  or (args.count and writer.count + writer.pending >= args.count)
                  or (args.duration and time.monotonic() - start > args.duration))
    finally:
        writer.close()
    print(f"recorded {writer.count} messages ({writer.bytes / 1e6:.1f} MB) into {args.output}", file=sys.stderr)
    if failure:
        print(f"facesculpt: {failure[0]}; the {writer.count} records before it are readable", file=sys.stderr)
        return 1
    return 0


def _flush_due(writer, failure: list) -> bool:
    """Write a chunk that waited long enough while no message came (False: never a reason to stop)."""
    from facesculpt.runtime.bag import BagError

    try:
        writer.flush_if_due()
    except BagError as exc:
        failure.append(str(exc))
    return False


def cmd_bag_play(args) -> int:
    from facesculpt.runtime.bag import BagReader

    reader = BagReader(args.file)
    node = _ToolNode("bag_play")
    publishers = {topic: node.advertise(topic, REGISTRY.get(typ), qos=EVENTS if args.fast else SENSOR_DATA)
                  for topic, typ in reader.topics().items()}
    first = reader.start_ns()
    start_ns = None if not args.start or first is None else first + int(args.start * 1e9)
    if not publishers:
        print(f"{args.file}: no complete records", file=sys.stderr)
        return 1
    import signal

    signal.signal(signal.SIGINT, lambda *a: node.shutdown())
    signal.signal(signal.SIGTERM, lambda *a: node.shutdown())
    node.start()
    passes: list[int] = []  # messages sent in each pass (the last one may be cut short by a stop)
    try:
        for pub in publishers.values():
            pub.wait_for_subscribers(1, args.wait)
        while node.running:
            passes.append(_play_pass(node, reader, publishers, start_ns, args))
            if not args.loop:
                break
            print(f"pass {len(passes)}{'' if node.running else ' (stopped)'}: played {passes[-1]} messages "
                  f"from {args.file}", file=sys.stderr, flush=True)
        node.spin_once(0.0)
    finally:
        node.close()
    foreign = sum(reader.foreign.values())
    sent = sum(passes)
    print(f"played {sent} messages from {args.file}"
          + (f" in {len(passes)} passes (each one's count above)" if args.loop else "")
          + (f" ({reader.ignored_bytes} trailing bytes ignored)" if reader.ignored_bytes else "")
          + (f"; skipped {foreign} messages of channels that are not facesculpt's "
             f"({', '.join(sorted(reader.foreign))})" if foreign else ""), file=sys.stderr)
    return 0


def _play_pass(node, reader, publishers: dict, start_ns, args) -> int:
    """One pass over the bag from ``start_ns`` (None: its first message), paced as recorded
    divided by ``args.rate`` or, with ``args.fast``, as fast as subscribers take the messages;
    returns how many were sent before the end or a stop."""
    sent = 0
    t0_rec = t0_wall = None
    for rec in reader.messages(start_ns):
        if not node.running:
            break
        if not args.fast:
            if t0_rec is None:
                t0_rec, t0_wall = rec.time_ns, time.monotonic()
            due = t0_wall + (rec.time_ns - t0_rec) / 1e9 / args.rate
            while node.running and time.monotonic() < due:
                node.spin_once(min(0.05, max(0.0, due - time.monotonic())))
        # --fast never drops: wait for a slow subscriber for as long as we are not stopped.
        while not publishers[rec.topic].publish_frames(rec.frames, timeout_s=1.0) and node.running:
            node.spin_once(0.0)
        sent += 1
    return sent


def cmd_bag_info(args) -> int:
    from facesculpt.runtime.bag import bag_info

    info = bag_info(args.file)
    if args.json:
        print(json.dumps(info, indent=1))
        return 0
    print(f"path:      {info['path']}")
    how = "" if info["format"] != "mcap" else " (indexed)" if info["indexed"] else " (no summary: read record by record)"
    print(f"format:    {info['format']}{how}")
    print(f"size:      {info['bytes']} bytes, {info['records']} complete records"
          + (f", {info['ignored_bytes']} bytes ignored (incomplete last record)" if info["ignored_bytes"] else ""))
    print(f"duration:  {info['duration_s']} s")
    for topic, t in info["topics"].items():
        print(f"  {topic:<24} {t['count']:>7} msgs   {', '.join(t['types'])}")
    if info["undecodable"]:
        print(f"note:      {info['undecodable']}")
    return 0


def cmd_bag_export(args) -> int:
    import foxglove

    from facesculpt.msgs import DecodeError, decode
    from facesculpt.nodes.foxglove.bridge import FoxgloveBridge
    from facesculpt.runtime.bag import BagReader

    reader = BagReader(args.file)
    if os.path.exists(args.output) and os.path.samefile(args.file, args.output):
        raise ValueError(f"bag export: the output {args.output} is the input bag")
    if not 0 <= args.jpeg_quality <= 100:
        raise ValueError(f"bag export: --jpeg-quality {args.jpeg_quality} is not in 0..100")
    context = foxglove.Context()
    shown = skipped = 0
    try:
        writer = foxglove.open_mcap(args.output, allow_overwrite=True, context=context)
    except Exception as exc:  # the SDK raises its own error types for an unwritable path
        raise ValueError(f"bag export: cannot write {args.output}: {exc}") from None
    with writer:
        bridge = FoxgloveBridge(context=context, jpeg_quality=args.jpeg_quality)
        for rec in reader:
            try:
                _, msg = decode([rec.topic.encode()] + rec.frames)
            except DecodeError:
                skipped += 1
                continue
            if bridge.handle(rec.topic, msg, rec.time_ns):
                shown += 1
        bridge.close()
    print(f"exported {shown} of {reader.records_read} messages from {args.file} into {args.output} "
          f"with Foxglove schemas" + (f" ({skipped} did not decode)" if skipped else ""), file=sys.stderr)
    return 0
