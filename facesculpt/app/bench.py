"""`facesculpt bench`: the paper's Table 2 on this machine, per stage and for the whole graph.

    facesculpt bench [--video FILE] [--model facemesh|sfm|both] [--frames N] [--window S] [--json FILE]

Input: the shared ``s18.mp4`` (1280x720) when the shared data is present, else the embedded face
photo under a moving virtual camera; frames resized to 856x480, the paper's size. Per model:

* **stages, in-process** (:class:`facesculpt.app.pipeline.Pipeline`, the graph's stage code called in
  sequence on one frame): landmark detection, model fitting (frontal |yaw| < 20 deg / oblique),
  merging (Eq. 5), inpainting (uncovered mask + fill) and texture + texcoord update + rendering
  (the compositor's other stages), mean ms over N frames with the paper's Fig. 6e edit (nose
  longer, chin, cheeks slimmer) solved on the fitted neutral; mesh deformation: a scripted drag
  of the nose tip (the deformer node's ROI radius, iterations and tolerance), ms per drag update
  (pointer step -> model-space handle move -> ARAP solve). The sequential total is the frame
  time plus one drag update, as in the paper's sum.
* **pipelined**: the graph as separate processes (camera -> landmarks -> fitter -> deformer ->
  renderer, ``facesculpt launch`` of a generated launch file, sync pairing, the same edit sent
  as a ``load_preset`` command); an in-process subscriber counts ``render/image`` messages over a
  fixed window (frames out per second) and takes each one's age at arrival (camera stamp ->
  composited frame: end-to-end latency p50/p99). Each node's stage times and rate come from
  the ``diagnostics`` topic, and its CPU use from the OS, to show where the time goes; the
  window's timeline (2-s slices: frames, latency p50/p99/max, each node's CPU) shows when, and the
  table lists its slowest slices.

The machine is what it is (2 cores, no GPU here): the load average is reported with the figures,
and a fixed reference workload (:mod:`facesculpt.app.bench_reference`) is measured at the start and
the end of the run; each figure is also given over it (the "/ ref" columns, JSON "stages_ratio",
"frame_period_ratio", "latency_ratio"), a ratio that holds across machines as the ms do not.
"""

from __future__ import annotations

import json
import math
import os
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from facesculpt.app.bench_graph import SIZE
from facesculpt.app.bench_reference import add_ratios, as_ratio, reference_workload
from facesculpt.app.option_arguments import add_option_argument
from facesculpt.nodes.camera.node import CameraNode
from facesculpt.nodes.fitter.config import FitterConfig

FRONTAL_YAW_DEG = 20.0
PRESETS = ("nose_longer.json", "chin.json", "cheeks.json")  # the paper's Fig. 6e, in order

#: The paper's Table 2 (i7-3770 + GTX TITAN, 856x480, 3448 vertices), ms.
PAPER_MS = {
    "landmark_detection": 36.28,
    "model_fitting_frontal": 20.63,
    "model_fitting_oblique": 30.58,
    "mesh_deformation": 7.14,
    "merging": 5.34,
    "inpainting": 31.16,
    "texture_update_rendering": 10.55,
    "sequential_total": 112.68,
}
PAPER_PIPELINED_FPS = 15.0

ROWS = [  # (key, label)
    ("landmark_detection", "landmark detection"),
    ("model_fitting", "model fitting (all frames)"),
    ("model_fitting_frontal", f"  frontal (|yaw| < {FRONTAL_YAW_DEG:.0f} deg)"),
    ("model_fitting_oblique", "  oblique"),
    ("mesh_deformation", "mesh deformation (ARAP per drag update)"),
    ("merging", "merging fitted and deformed models"),
    ("inpainting", "inpainting"),
    ("texture_update_rendering", "texture + texcoord update + rendering"),
    ("sequential_total", "sequential total"),
]

# The compositor's stages in the paper's two rendering rows.
INPAINT_PARTS = ("masks", "inpaint")
RENDER_PARTS = ("camera", "texture", "draw", "readback", "composite")


def register(sub) -> None:
    p = sub.add_parser("bench", help="per-stage times (the paper's Table 2), pipelined rate and latency",
                       description="The paper's Table 2 on this machine: per-stage times in-process, and the "
                                   "whole graph's frame rate and end-to-end latency as separate processes.")
    p.add_argument("--video", default="", help="input video (default: shared s18.mp4, else the embedded face photo)")
    p.add_argument("--model", default="both", choices=["facemesh", "sfm", "both"],
                   help="face model(s) to measure (default both; sfm needs the shared data)")
    p.add_argument("--frames", type=int, default=200, help="frames timed per model in-process (default 200)")
    p.add_argument("--drags", type=int, default=60, help="drag updates of the scripted nose drag (default 60)")
    p.add_argument("--window", type=float, default=10.0, help="seconds the pipelined graph is measured (default 10)")
    p.add_argument("--warmup", type=float, default=2.0, help="seconds of graph output before the window (default 2)")
    p.add_argument("--camera-fps", type=float, default=60.0,
                   help="camera rate in the graph (default 60; -1: as fast as it reads)")
    pace = CameraNode.PARAMS["pace_in_flight"].default
    p.add_argument("--pace", type=int, default=pace, metavar="N",
                   help="the graph's camera sends a frame while fewer than N wait for the renderer "
                        f"(camera.pace_in_flight, default {pace}); 0: every frame it reads")
    p.add_argument("--threads", type=int, default=1,
                   help="OpenBLAS and OpenCV threads per process, in-process and in the graph's nodes "
                        "(default 1; 0: the libraries' own defaults, one per core)")
    p.add_argument("--size", default="", metavar="WxH",
                   help="measure at this frame size, e.g. 1280x720 (the input is scaled to cover it and cropped "
                        "to its aspect); default: the paper's 856x480 pixel count at the input's aspect")
    p.add_argument("--pose", default="", metavar="yaw=D,pitch=D,...",
                   help="the graph's edit also turns the head by this pose offset (docs/guide/new-views.md)")
    p.add_argument("--load", type=int, default=0, metavar="N",
                   help="run N busy loops (one core's demand each) beside the measurement, as a browser or a video "
                        "call would (default 0)")
    p.add_argument("--scenario", action="store_true",
                   help="the graph's window starts with its first frames (the neutral is learnt inside it) and "
                        "holds a preset load, nose drags, a reset and a second load (use --window 60)")
    add_option_argument(p, FitterConfig(), "refine", "--refine", extra_help="in-process and in the graph (fitter.refine)")
    p.add_argument("--memory", choices=("off", "on"), default="off",
                   help="the renderer's background plate and texture atlas on, in-process and in the graph "
                        "(renderer.plate, renderer.atlas; docs/guide/process.md)")
    p.add_argument("--no-graph", action="store_true", help="only the in-process stages")
    p.add_argument("--json", default="", metavar="FILE", help="write the figures here")
    p.set_defaults(func=cmd_bench)


# -- input --------------------------------------------------------------------------------------
def bench_source(video: str) -> tuple[str, str]:
    """(camera source spec, description): the given video, else shared s18.mp4, else embedded."""
    from facesculpt.paths import shared_data_dir

    if video:
        if not Path(video).is_file():
            raise FileNotFoundError(f"cannot read {video}: no such file")
        return str(Path(video).resolve()), Path(video).name
    data = shared_data_dir()
    if data is not None and (data / "video" / "s18.mp4").is_file():
        return str(data / "video" / "s18.mp4"), "s18.mp4 (shared data)"
    return "embedded", "embedded face photo (astronaut.png, 512x512) under a moving virtual camera"


def bench_size(width: int, height: int) -> tuple[int, int]:
    """The size (px) a ``width`` x ``height`` input is measured at: the paper's 856x480 for an
    input of that aspect ratio (within 1 %), else the paper's pixel count at the input's own
    aspect ratio (even sides), so a portrait video is not squashed."""
    aspect = width / height
    if abs(aspect / (SIZE[0] / SIZE[1]) - 1.0) <= 0.01:
        return SIZE
    pixels = SIZE[0] * SIZE[1]
    w = 2 * max(1, round(math.sqrt(pixels * aspect) / 2))
    return w, 2 * max(1, round(pixels / w / 2))


def parse_size(text: str) -> tuple[int, int] | None:
    """"WxH" -> (W, H) px; "" -> None; ValueError in one sentence otherwise."""
    if not text:
        return None
    w, sep, h = text.lower().partition("x")
    if not (sep and w.isdigit() and h.isdigit() and 16 <= int(w) <= 16384 and 16 <= int(h) <= 16384):
        raise ValueError(f"--size {text!r} must be WIDTHxHEIGHT in pixels, e.g. 1280x720 (16 to 16384 each)")
    return int(w), int(h)


def read_frames(spec: str, count: int, size: tuple[int, int] | None = None
                ) -> tuple[list[np.ndarray], float, tuple[int, int]]:
    """The first ``count`` frames of a camera source (a video loops) at ``size`` (scaled to cover
    it and cropped) or else :func:`bench_size`, its fps and that size."""
    from facesculpt.nodes.camera.source_opening import open_source
    from facesculpt.nodes.camera.sources import resize_frame

    source = open_source(spec, loop=True)
    mode = "fill" if size else "stretch"  # bench_size keeps the input's aspect: nothing to crop
    try:
        frames = []
        for frame, _ in source.frames():
            size = size or bench_size(frame.shape[1], frame.shape[0])
            frames.append(resize_frame(frame, *size, mode=mode))
            if len(frames) >= count:
                break
    finally:
        source.close()
    if not frames:
        raise ValueError(f"cannot read frames from {spec}")
    return frames, source.native_fps or 30.0, size


def preset_paths() -> list[Path]:
    from facesculpt.paths import preset_file

    return [preset_file(name) for name in PRESETS]


# -- in-process stages ----------------------------------------------------------------------------
def drag_updates(pipeline, fit, drags: int) -> tuple[list[float], float]:
    """A scripted drag of the nose tip on the fitted neutral, as the deformer node does it: press,
    then ``drags`` pointer steps of 1 px (right and up) each turned into a model-space handle move
    and an ARAP solve. Returns the ms of each drag update and of the press (anchor set factorised)."""
    from facesculpt.nodes.deformer.dragging import drag_delta
    from facesculpt.nodes.deformer.node import DeformerNode

    params = DeformerNode.default_params()
    stack = pipeline.edit_stack(roi_radius=params["roi_radius"], roi_metric=params["roi_metric"], grip=params["grip"],
                                iterations=params["iterations"], tolerance=params["tolerance"],
                                acceleration=params["acceleration"], clamp_weights=params["clamp_weights"])
    nose = stack.landmark_vertex("nose_tip")
    t0 = time.perf_counter()
    stack.begin([nose])
    stack.solve()
    press_ms = (time.perf_counter() - t0) * 1e3
    x, y = (float(v) for v in fit.projected[nose])
    times = []
    for _ in range(drags):
        t0 = time.perf_counter()
        handle_cam = fit.vertices[nose].astype(np.float64) + fit.scale * (fit.R @ (stack.handle_position(nose) - stack.rest[nose]))
        delta = drag_delta(handle_cam, (x, y), (x + 1.0, y - 0.5), fit.K, fit.R, fit.scale, fit.projection)
        stack.move_handle(nose, delta)
        stack.solve()
        times.append((time.perf_counter() - t0) * 1e3)
        x, y = x + 1.0, y - 0.5
    return times, press_ms


def _mean(values) -> float | None:
    return round(float(np.mean(values)), 3) if len(values) else None


def measure_stages(model: str, frames: list[np.ndarray], fps: float, preset: dict, drags: int,
                   refine: str | None = None, memory: str = "off") -> dict:
    """Per-stage ms of the in-process pipeline over ``frames`` (see the module doc); ``refine``:
    the fitter's (None: landmarks only); ``memory`` "on": the background plate and texture atlas."""
    from facesculpt.app.pipeline import Pipeline

    skip = 3  # the first frames create the GL context and warm the caches
    with Pipeline(model, plate=memory, atlas=memory, fit=FitterConfig(refine=refine)) as pipeline:
        pipeline.calibrate(iter(frames), fps)
        if pipeline.fitted_frames == 0:
            raise RuntimeError(f"no face found in the bench input with the {model} model")
        pipeline.set_edits(preset)
        per: dict[str, list[float]] = {k: [] for k, _ in ROWS}
        parts: dict[str, list[float]] = {}
        wall: list[float] = []
        last_fit = None
        faces = 0
        for i, frame in enumerate(frames):
            t0 = time.perf_counter()
            result = pipeline.process(frame, i / fps)
            elapsed = (time.perf_counter() - t0) * 1e3
            if result.fit is None:
                continue
            faces += 1
            last_fit = result.fit
            if i < skip:
                continue
            wall.append(elapsed)
            t = result.timings_ms
            per["landmark_detection"].append(t["landmarks"])
            per["model_fitting"].append(t["fit"])
            yaw = abs(result.fit.yaw_pitch_roll[0])
            per["model_fitting_frontal" if yaw < FRONTAL_YAW_DEG else "model_fitting_oblique"].append(t["fit"])
            per["merging"].append(t["merge"])
            per["inpainting"].append(sum(result.render_ms.get(k, 0.0) for k in INPAINT_PARTS))
            per["texture_update_rendering"].append(sum(result.render_ms.get(k, 0.0) for k in RENDER_PARTS))
            for k, v in result.render_ms.items():
                parts.setdefault(k, []).append(v)
        if last_fit is None or not wall:
            raise RuntimeError(f"too few frames with a face to time ({faces} of {len(frames)})")
        drag_ms, press_ms = drag_updates(pipeline, last_fit, drags)
        per["mesh_deformation"] = drag_ms
        stages = {k: _mean(v) for k, v in per.items() if len(v)}
        stages_p50 = {k: round(float(np.median(v)), 3) for k, v in per.items() if len(v)}
        frame_ms = float(np.mean(wall))
        total = frame_ms + stages["mesh_deformation"]
        stages["sequential_total"] = round(total, 3)
        return {
            "model_id": pipeline.model.model_id,
            "vertices": int(pipeline.model.num_vertices),
            "stages_ms": stages,
            "stages_p50_ms": stages_p50,
            "render_parts_ms": {k: _mean(v) for k, v in parts.items()},
            "frames_timed": len(wall),
            "frames_with_face": faces,
            "fit_frames": {"frontal": len(per["model_fitting_frontal"]), "oblique": len(per["model_fitting_oblique"])},
            "frame_ms": round(frame_ms, 3),
            "press_ms": round(press_ms, 3),
            "sequential_fps": round(1000.0 / total, 2),
        }


# -- the pipelined graph ----------------------------------------------------------------------------
def _fmt(value, digits=2) -> str:
    return "-" if value is None else f"{value:.{digits}f}"


def table(result: dict) -> str:
    models = list(result["models"])
    ref = (result.get("reference") or {}).get("total_ms")
    head = f"{'stage (ms)':<42}{'paper':>9}" + "".join(f"{m:>12}{'/ ref':>8}" for m in models)
    lines = [head, "-" * len(head)]
    for key, label in ROWS:
        paper = PAPER_MS.get(key)
        row = f"{label:<42}{_fmt(paper):>9}"
        for m in models:
            ms = result['models'][m]['stages_ms'].get(key)
            row += f"{_fmt(ms):>12}{_fmt(as_ratio(ms, ref), 3):>8}"
        lines.append(row)
    extra = [("sequential rate (fps)", None, lambda r: r.get("sequential_fps")),
             ("pipelined rate (fps)", PAPER_PIPELINED_FPS, lambda r: r.get("pipelined_fps")),
             ("end-to-end latency p50 (ms)", None, lambda r: r.get("latency_ms", {}).get("p50")),
             ("end-to-end latency p95 (ms)", None, lambda r: r.get("latency_ms", {}).get("p95")),
             ("end-to-end latency p99 (ms)", None, lambda r: r.get("latency_ms", {}).get("p99")),
             ("longest stall (ms)", None, lambda r: r.get("longest_stall_ms")),
             ("camera frames dropped", None, lambda r: r.get("frames_dropped"))]
    period = {"pipelined rate (fps)": lambda r: r.get("frame_period_ratio"),
              "end-to-end latency p50 (ms)": lambda r: (r.get("latency_ratio") or {}).get("p50"),
              "end-to-end latency p99 (ms)": lambda r: (r.get("latency_ratio") or {}).get("p99")}
    for label, paper, get in extra:
        ratio = period.get(label, lambda r: None)
        lines.append(f"{label:<42}{_fmt(paper):>9}" + "".join(
            f"{_fmt(get(result['models'][m])):>12}{_fmt(ratio(result['models'][m]), 3):>8}" for m in models))
    if ref:
        lines.append(f"/ ref: each figure over the reference workload measured in the same run, {ref:.2f} ms "
                     f"(the rate as its frame period, 1000 / fps)")
    for m in models:
        nodes = result["models"][m].get("nodes")
        if not nodes:
            continue
        lines.append(f"\n{m}: graph nodes over the window (cpu %, stage mean ms, input rate Hz)")
        for name, info in sorted(nodes.items()):
            stages = ", ".join(f"{k} {v:.1f}" for k, v in info.get("stages_ms", {}).items())
            rates = ", ".join(f"{k} {v:.1f}" for k, v in info.get("rate_hz", {}).items() if k != "diagnostics")
            lines.append(f"  {name:<10} cpu {info.get('cpu_percent', 0):5.1f}%   {stages}   {rates}")
        lines += _worst_slices(result["models"][m].get("timeline") or [])
    return "\n".join(lines)


def _worst_slices(timeline: list[dict], count: int = 3) -> list[str]:
    """The ``count`` slices of the window with the highest latency p99, with the nodes' CPU then."""
    slices = sorted((t for t in timeline if "p99_ms" in t), key=lambda t: -t["p99_ms"])[:count]
    if not slices:
        return []
    lines = ["  slowest slices of the window (latency p50 / p99 / max ms; cpu % of a core):"]
    for t in slices:
        cpu = ", ".join(f"{n} {v:.0f}" for n, v in sorted((t.get("cpu_percent") or {}).items(), key=lambda x: -x[1]))
        lines.append(f"    {t['start_s']:5.1f} s: {t['p50_ms']:.0f} / {t['p99_ms']:.0f} / {t['max_ms']:.0f}   {cpu}")
    return lines


def cmd_bench(args) -> int:
    from facesculpt.app.busy_load import competing_load
    from facesculpt.app.pipeline import load_face_model, read_preset
    from facesculpt.geometry.pose_offset import parse_pose_offset
    from facesculpt.nodes.deformer.preset_format import merge_presets, pose_to_preset
    from facesculpt.runtime.process_limits import limit_threads

    limit_threads(args.threads)  # also in the environment the graph's processes inherit
    if args.frames < 5 or args.drags < 1 or args.window <= 0 or not 0 <= args.load <= 64:
        raise ValueError("--frames must be >= 5, --drags >= 1, --window > 0 and --load 0 to 64")
    models = ["facemesh", "sfm"] if args.model == "both" else [args.model]
    skipped = {}
    if "sfm" in models:
        try:
            load_face_model("sfm")  # a clear error now when the shared data is missing
        except FileNotFoundError as exc:
            if args.model == "sfm":
                raise
            models.remove("sfm")
            skipped["sfm"] = str(exc)
            print(f"facesculpt bench: sfm skipped: {exc}", file=sys.stderr)
    source, description = bench_source(args.video)
    paths = preset_paths()
    preset = merge_presets([read_preset(p) for p in paths])
    if args.pose:  # the graph's deformer loads it with the edit; the in-process stages turn the head too
        preset["pose"] = pose_to_preset(parse_pose_offset(args.pose))
    preset_file = Path(tempfile.mkdtemp(prefix="fs-bench-preset-")) / "fig6e.json"
    preset_file.write_text(json.dumps(preset))
    wanted = parse_size(args.size)
    frames, fps, size = read_frames(source, args.frames, wanted)
    load_start = os.getloadavg()
    print(f"facesculpt bench: {description}, {size[0]}x{size[1]}, {len(frames)} frames; "
          f"{os.cpu_count()} CPUs, load average {load_start[0]:.2f}", file=sys.stderr, flush=True)
    result = {
        "input": description, "size": list(size), "frames": len(frames),
        "edit": [p.stem for p in paths], "pose": preset.get("pose", {}), "camera_fps": args.camera_fps,
        "pairing": "sync", "camera_pace": args.pace, "competing_busy_loops": args.load, "scenario": args.scenario,
        "refine": args.refine, "memory": args.memory,
        "threads": args.threads or "default",
        "machine": {"cpus": os.cpu_count(), "load_avg_start": [round(v, 2) for v in load_start]},
        "paper_ms": PAPER_MS, "paper_pipelined_fps": PAPER_PIPELINED_FPS, "models": {}, "skipped": skipped,
    }
    try:
        with competing_load(args.load):
            start = reference_workload()
            _measure_models(args, models, frames, fps, preset, preset_file, source, size, wanted, result)
            add_ratios(result, start, reference_workload())
    finally:
        shutil.rmtree(preset_file.parent, ignore_errors=True)
    result["machine"]["load_avg_end"] = [round(v, 2) for v in os.getloadavg()]
    print(table(result))
    if args.refine != "off":
        print(f"the fitter refines by {args.refine} (--refine)")
    if args.memory != "off":
        print("the renderer keeps a background plate and a texture atlas (--memory on)")
    if args.load:
        print(f"with {args.load} competing busy loop(s) running (--load)")
    print(f"load average {result['machine']['load_avg_start'][0]:.2f} -> {result['machine']['load_avg_end'][0]:.2f} "
          f"on {os.cpu_count()} CPUs")
    if args.json:
        Path(args.json).write_text(json.dumps(result, indent=1))
    return 0


def _measure_models(args, models, frames, fps, preset, preset_file, source, size, wanted, result) -> None:
    """Each model's in-process stages and (unless --no-graph) its graph figures, into ``result``."""
    from facesculpt.app.bench_graph import measure_graph

    for model in models:
        print(f"[{model}] stages in-process ...", file=sys.stderr, flush=True)
        refine = None if args.refine == "off" else args.refine
        entry = measure_stages(model, frames, fps, preset, args.drags, refine, args.memory)
        if not args.no_graph:
            print(f"[{model}] the graph as separate processes, {args.window:.0f} s window ...",
                  file=sys.stderr, flush=True)
            entry.update(measure_graph(source, model, preset_file, args.camera_fps, args.window, args.warmup, size,
                                       resize="fill" if wanted else "stretch", scenario=args.scenario,
                                       pace=args.pace, refine=refine, memory=args.memory))
        result["models"][model] = entry
