"""The graph on a replayed RGB-D bag (issue 49): frames out per second at 640x480 with the fitter
refining every fit on the frame's depth, against the colour-only graph in the same run.

The bag: the synthetic RGB-D set of ``bench_rgbd.py`` (the realism benchmark's head rendered with
a depth buffer through its structured-light noise model, ``--seed``), ``--frames`` frames at
640x480 recorded as ``camera/image`` messages with their depth (16-bit PNG in the bag); the
colour-only bag holds the same colour frames without depth. Each graph is ``facesculpt bench``'s
(:func:`facesculpt.app.bench_graph.measure_graph`: camera -> landmarks -> fitter -> deformer ->
renderer as separate processes, the camera replaying the bag in a loop at ``--camera-fps``, paced
by the renderer, the nose edit loaded), measured over ``--window`` seconds after a warm-up; the
two graphs alternate ``--rounds`` times (colour, depth, colour, depth, ...) so a change in the
machine's load falls on both. Reported: each run's frames out per second, latency and the
fitter's CPU use, and the ratio of the depth graph's rate to the colour-only graph's (per round
and of the medians).

Run from the repository root: ``python -m benchmarks.bench_rgbd_graph [--frames 60] [--window 10]
[--rounds 2] [--model facemesh] [--json FILE]``; needs the shared data (the head's texture and
background) and ``facesculpt setup``.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from benchmarks.realism.depth import rgbd_frame
from benchmarks.realism.scene import make_scene
from facesculpt.paths import preset_file, shared_data_dir

SIZE = (640, 480)
FPS = 30


def write_bags(folder: Path, frames: int, seed: int) -> tuple[Path, Path]:
    """(the RGB-D bag, the colour-only bag) of the synthetic set's first ``frames`` frames."""
    from facesculpt.msgs import Image
    from facesculpt.runtime.bag import BagWriter

    scene = make_scene(shared_data_dir(), frames, seed=seed)
    K = scene.K.copy()
    K[:2, 2] -= 0.5  # the scene's pixel centres are at +0.5, the project's at integers
    rgbd, colour = folder / "rgbd.mcap", folder / "colour.mcap"
    with BagWriter(rgbd, compression="png") as wd, BagWriter(colour, compression="png") as wc:
        for i in range(frames):
            image, depth, _ = rgbd_frame(scene, i, np.random.default_rng((seed, i)))
            stamp = int(i * 1e9 / FPS)
            wd.write(stamp, "camera/image", Image(stamp=stamp, seq=i, image=image, K=K, frame_size=list(SIZE),
                                                  depth=depth, depth_K=K).to_frames())
            wc.write(stamp, "camera/image", Image(stamp=stamp, seq=i, image=image, K=K,
                                                  frame_size=list(SIZE)).to_frames())
    return rgbd, colour


def _summary(run: dict) -> dict:
    fitter = run["nodes"].get("fitter", {})
    return {"fps": run["pipelined_fps"], "latency_p50_ms": run["latency_ms"]["p50"],
            "latency_p99_ms": run["latency_ms"]["p99"], "fitter_cpu_percent": fitter.get("cpu_percent"),
            "fitter_stages_ms": fitter.get("stages_ms", {}), "frames_out": run["frames_out"],
            "window_s": run["window_s"],
            "nodes": {name: {"cpu_percent": n.get("cpu_percent"), "stages_ms": n.get("stages_ms", {})}
                      for name, n in run["nodes"].items()}}


def run(frames: int, seed: int, model: str, window_s: float, warmup_s: float, rounds: int,
        camera_fps: float) -> dict:
    from facesculpt.app.bench_graph import measure_graph

    folder = Path(tempfile.mkdtemp(prefix="fs-rgbd-graph-"))
    rgbd, colour = write_bags(folder, frames, seed)
    preset = preset_file("nose_longer")
    runs: dict[str, list[dict]] = {"colour": [], "depth": []}
    for r in range(rounds):
        for name, bag, depth in (("colour", colour, "off"), ("depth", rgbd, "on")):
            print(f"round {r + 1}/{rounds}: the {name} graph ...", file=sys.stderr, flush=True)
            figures = measure_graph(f"bag:{bag}", model, preset, camera_fps, window_s, warmup_s, SIZE, depth=depth)
            runs[name].append(_summary(figures))
    fps = {name: [x["fps"] for x in rs] for name, rs in runs.items()}
    return {"model": model, "frames": frames, "seed": seed, "size": list(SIZE), "camera_fps": camera_fps,
            "load_average": os.getloadavg(), "cpus": os.cpu_count(), "runs": runs,
            "ratio_per_round": [round(d / c, 3) for c, d in zip(fps["colour"], fps["depth"])],
            "ratio_of_medians": round(float(np.median(fps["depth"]) / np.median(fps["colour"])), 3),
            "date": time.strftime("%Y-%m-%d")}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--frames", type=int, default=60, help="frames in the bag, replayed in a loop (default 60)")
    p.add_argument("--seed", type=int, default=11, help="the synthetic head's identity and noise (default 11)")
    p.add_argument("--model", default="facemesh", help="the fitter's model (default facemesh, as launch/rgbd.yaml)")
    p.add_argument("--window", type=float, default=10.0, help="seconds each graph is measured (default 10)")
    p.add_argument("--warmup", type=float, default=3.0, help="seconds of output before each window (default 3)")
    p.add_argument("--rounds", type=int, default=2, help="colour/depth pairs measured in turn (default 2)")
    p.add_argument("--camera-fps", type=float, default=60.0, help="the camera's replay rate (default 60)")
    p.add_argument("--json", default="", metavar="FILE", help="write the figures here")
    args = p.parse_args(argv)
    result = run(args.frames, args.seed, args.model, args.window, args.warmup, args.rounds, args.camera_fps)
    for name in ("colour", "depth"):
        for x in result["runs"][name]:
            print(f"{name:6s} {x['fps']:6.2f} frames/s  latency p50 {x['latency_p50_ms']:7.1f} ms  "
                  f"fitter cpu {x['fitter_cpu_percent']} %  fit {x['fitter_stages_ms']}")
            print("        cpu % by node: " + ", ".join(f"{k} {v['cpu_percent']}" for k, v in x["nodes"].items()))
    print(f"depth / colour frame rate: {result['ratio_per_round']} per round, {result['ratio_of_medians']} "
          f"of the medians; load average {result['load_average']}, {result['cpus']} cpus")
    if args.json:
        Path(args.json).write_text(json.dumps(result, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
