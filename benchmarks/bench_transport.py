"""One-way latency and throughput of an 856x480x3 image between two processes:
the facesculpt runtime (Node -> Node through the master) next to raw pyzmq
PUB/SUB of the same bytes, over ipc and tcp loopback, in the same run.

The two alternate in rounds (raw, runtime, raw, runtime, ...): this machine's speed drifts
within a minute, so each ratio compares neighbours, and the figure reported is the median of
the rounds' ratios.

    python -m benchmarks.bench_transport [--messages 400] [--rounds 3] [--json out.json]
"""

from __future__ import annotations

import argparse
import json
import multiprocessing as mp
import os
import struct
import tempfile
import threading
import time

import numpy as np
import zmq

SHAPE = (480, 856, 3)


def _free_port() -> int:
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


# -- raw pyzmq ------------------------------------------------------------------------------------
def _raw_receiver(endpoint: str, n: int, out: mp.Queue, ready: mp.Event) -> None:
    ctx = zmq.Context()
    sock = ctx.socket(zmq.SUB)
    sock.setsockopt(zmq.RCVHWM, 100000)
    sock.setsockopt(zmq.SUBSCRIBE, b"img")
    sock.connect(endpoint)
    ready.set()
    lat, first, last = [], None, None
    for _ in range(n):
        parts = sock.recv_multipart(copy=False)
        now = time.time_ns()
        (sent,) = struct.unpack("<q", parts[1].bytes)
        np.frombuffer(parts[2].buffer, np.uint8).reshape(SHAPE)
        lat.append((now - sent) / 1e6)
        first = first or now
        last = now
    out.put((lat, (n - 1) / ((last - first) / 1e9)))


def run_raw(transport: str, n: int, rate_hz: float) -> dict:
    endpoint = (f"ipc://{tempfile.mkdtemp()}/raw" if transport == "ipc" else f"tcp://127.0.0.1:{_free_port()}")
    ctx = zmq.Context()
    pub = ctx.socket(zmq.PUB)
    pub.setsockopt(zmq.SNDHWM, 100000)
    pub.bind(endpoint)
    img = np.zeros(SHAPE, np.uint8)
    results = {}
    for mode, rate in (("latency", rate_hz), ("throughput", 0.0)):
        out, ready = mp.Queue(), mp.Event()
        proc = mp.Process(target=_raw_receiver, args=(endpoint, n, out, ready))
        proc.start()
        ready.wait()
        time.sleep(0.5)
        for _ in range(n):
            if rate:
                time.sleep(1.0 / rate)
            pub.send_multipart([b"img", struct.pack("<q", time.time_ns()), img], copy=False)
        lat, thr = out.get(timeout=120)
        proc.join()
        results[mode] = (lat, thr)
    pub.close()
    ctx.term()
    return _summary(results)


# -- the runtime ----------------------------------------------------------------------------------
def _runtime_receiver(n: int, out: mp.Queue, env: dict) -> None:
    os.environ.update(env)
    from facesculpt.msgs import Image
    from facesculpt.runtime.node import Node
    from facesculpt.runtime.qos import EVERY_MESSAGE

    node = Node(name=f"bench_rx_{os.getpid()}")
    lat, times = [], []

    def on_image(msg):
        now = time.time_ns()
        lat.append((now - msg.stamp) / 1e6)
        times.append(now)

    node.subscribe("bench/image", Image, on_image, qos=EVERY_MESSAGE)
    node.start()
    while len(lat) < n:
        node.spin_once(0.05)
    node.close()
    out.put((lat, (n - 1) / ((times[-1] - times[0]) / 1e9)))


def run_runtime(transport: str, n: int, rate_hz: float, env: dict) -> dict:
    os.environ.update(env)
    from facesculpt.msgs import Image
    from facesculpt.runtime.node import Node
    from facesculpt.runtime.qos import EVENTS, SENSOR_DATA

    results = {}
    for mode, rate in (("latency", rate_hz), ("throughput", 0.0)):
        node = Node(name=f"bench_tx_{mode}", transport=transport)
        pub = node.advertise("bench/image", Image, qos=EVENTS if mode == "throughput" else SENSOR_DATA)
        node.start()
        out = mp.Queue()
        proc = mp.Process(target=_runtime_receiver, args=(n, out, env))
        proc.start()
        assert pub.wait_for_subscribers(1, 20), "receiver did not connect"
        time.sleep(0.5)
        img = np.zeros(SHAPE, np.uint8)
        for i in range(n):
            if rate:
                time.sleep(1.0 / rate)
            pub.publish(Image(stamp=time.time_ns(), seq=i + 1, image=img))
        lat, thr = out.get(timeout=120)
        proc.join()
        node.close()
        results[mode] = (lat, thr)
    return _summary(results)


def _summary(results: dict) -> dict:
    lat = np.array(results["latency"][0])
    return {"p50_ms": round(float(np.percentile(lat, 50)), 3), "p99_ms": round(float(np.percentile(lat, 99)), 3),
            "throughput_msgs_s": round(results["throughput"][1], 1),
            "throughput_MB_s": round(results["throughput"][1] * np.prod(SHAPE) / 1e6, 1)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--messages", type=int, default=400)
    parser.add_argument("--rate", type=float, default=100.0, help="send rate for the latency runs (Hz)")
    parser.add_argument("--rounds", type=int, default=3, help="alternating raw/runtime rounds per transport")
    parser.add_argument("--json", help="write the results here")
    args = parser.parse_args()
    mp.set_start_method("spawn")
    from facesculpt import master

    env = {"FACESCULPT_MASTER": f"tcp://127.0.0.1:{_free_port()}", "FACESCULPT_RUN_DIR": tempfile.mkdtemp()}
    os.environ.update(env)
    stop, ready = threading.Event(), threading.Event()
    threading.Thread(target=master.serve, kwargs=dict(ready=ready, stop=stop), daemon=True).start()
    ready.wait()
    rounds: dict[str, list[dict]] = {"ipc": [], "tcp": []}
    for _ in range(args.rounds):
        for transport in rounds:
            raw = run_raw(transport, args.messages, args.rate)
            rt = run_runtime(transport, args.messages, args.rate, env)
            rounds[transport].append({"raw_pyzmq": raw, "facesculpt": rt,
                                      "latency_ratio_p50": round(rt["p50_ms"] / raw["p50_ms"], 2),
                                      "latency_ratio_p99": round(rt["p99_ms"] / raw["p99_ms"], 2)})
    stop.set()
    table = {transport: {"rounds": rows, **{key: float(np.median([row[key] for row in rows]))
                                            for key in ("latency_ratio_p50", "latency_ratio_p99")}}
             for transport, rows in rounds.items()}
    print(f"856x480x3 uint8 image ({np.prod(SHAPE) / 1e6:.2f} MB), {args.messages} messages, latency at {args.rate} Hz, "
          f"{args.rounds} alternating rounds")
    print(f"{'':6} {'round':>5} {'path':<11} {'p50 ms':>8} {'p99 ms':>8} {'msgs/s':>8} {'MB/s':>8}")
    for transport, row in table.items():
        for i, one in enumerate(row["rounds"], 1):
            for name in ("raw_pyzmq", "facesculpt"):
                r = one[name]
                print(f"{transport:6} {i:5} {name:<11} {r['p50_ms']:8.3f} {r['p99_ms']:8.3f} "
                      f"{r['throughput_msgs_s']:8.1f} {r['throughput_MB_s']:8.1f}")
            print(f"{transport:6} {i:5} ratio       p50 {one['latency_ratio_p50']:.2f}x   p99 {one['latency_ratio_p99']:.2f}x")
        print(f"{transport:6} median ratio over rounds: p50 {row['latency_ratio_p50']:.2f}x   "
              f"p99 {row['latency_ratio_p99']:.2f}x (target p50 <= 1.2x)")
    if args.json:
        with open(args.json, "w") as f:
            json.dump(table, f, indent=1)


if __name__ == "__main__":
    main()
