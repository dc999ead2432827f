"""The compositor's cost per frame in CPU time, this checkout against another one (e.g. the
pre-realism renderer, 22775c8, in a second worktree with its own venv), alternating, in one run.

    python -m benchmarks.bench_renderer_cost --against /work/wt/speed-old [--model facemesh|sfm]
                                             [--frames 100] [--rounds 3] [--json out.json]

The renderer's inputs are captured once, here, from the bench's own pipeline (`facesculpt bench`'s
frames of s18.mp4 at 856x480, its Fig. 6e edit, the model's fits per frame): the very calls
``Pipeline.process`` makes to ``Compositor.render``. Each round then replays them through this
checkout's compositor and through the other checkout's (its python, ``DIR/.venv/bin/python``, in a
subprocess running this file with ``--replay``), one after the other. Times are the process's CPU
time (``time.process_time``, every thread: llvmpipe's too), not the wall clock: on a machine shared
with other work the wall clock measures the others as much as the renderer. Reported per stage
(mean ms over the frames after the first 3) and as "renderer" (camera + texture + draw + readback +
composite: `facesculpt bench`'s "texture + texcoord update + rendering") and "inpainting" (masks +
inpaint), each checkout's, and their ratios (this / other), per round and the median over rounds.
"""

from __future__ import annotations

import argparse
import inspect
import json
import os
import pickle
import statistics
import subprocess
import sys
import tempfile
import time
import types
from pathlib import Path

RENDER_PARTS = ("camera", "texture", "draw", "readback", "composite")
INPAINT_PARTS = ("masks", "inpaint")
SKIP = 3


def capture(model: str, frames: int, out: Path) -> None:
    """Write the Compositor.render calls of the bench's pipeline over ``frames`` frames to ``out``."""
    from facesculpt.app.bench import preset_paths, read_frames
    from facesculpt.app.pipeline import Pipeline, read_preset
    from facesculpt.nodes.deformer.preset_format import merge_presets
    from facesculpt.nodes.renderer import Compositor
    from facesculpt.paths import shared_data_dir

    video = shared_data_dir() / "video" / "s18.mp4"
    images, fps, size = read_frames(str(video), frames)
    preset = merge_presets([read_preset(p) for p in preset_paths()])
    calls = []
    render = Compositor.render

    def recording(self, *args, **kwargs):
        calls.append((args, kwargs))
        return render(self, *args, **kwargs)

    Compositor.render = recording
    try:
        with Pipeline(model) as pipeline:
            pipeline.calibrate(iter(images), fps)
            pipeline.set_edits(preset)
            calls.clear()
            for i, image in enumerate(images):
                pipeline.process(image, i / fps)
    finally:
        Compositor.render = render
    out.write_bytes(pickle.dumps({"size": size, "calls": calls}))


def replay(path: Path) -> dict:
    """Mean stage ms (process CPU time) of this checkout's compositor over the captured calls."""
    try:
        from facesculpt.runtime.process_limits import limit_threads
    except ImportError:   # an older checkout
        from facesculpt.process_limits import limit_threads
    limit_threads(1)
    import numpy as np

    import facesculpt.nodes.renderer.compositor as module
    from facesculpt.nodes.renderer import Compositor

    module.time = types.SimpleNamespace(perf_counter=time.process_time)   # the stages in CPU time
    data = pickle.loads(path.read_bytes())
    known = inspect.signature(Compositor.render).parameters
    calls = [(args, {k: v for k, v in kwargs.items() if k in known}) for args, kwargs in data["calls"]]
    comp = Compositor(*data["size"])
    parts: dict[str, list[float]] = {}
    for i, (args, kwargs) in enumerate(calls):
        comp.render(*args, **kwargs)
        if i >= SKIP:
            for k, v in comp.timings.items():
                parts.setdefault(k, []).append(v)
    comp.release()
    means = {k: float(np.mean(v)) for k, v in parts.items()}
    means["renderer"] = sum(means.get(k, 0.0) for k in RENDER_PARTS)
    means["inpainting"] = sum(means.get(k, 0.0) for k in INPAINT_PARTS)
    return {k: round(v, 3) for k, v in means.items()}


def _run(python: str, cwd: Path, path: Path) -> dict:
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    done = subprocess.run([python, str(Path(__file__).resolve()), "--replay", str(path)], cwd=cwd, env=env,
                          capture_output=True, text=True, check=True)
    return json.loads(done.stdout.strip().splitlines()[-1])


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--against", type=Path, help="the other checkout (with DIR/.venv)")
    ap.add_argument("--model", default="facemesh", choices=["facemesh", "sfm"])
    ap.add_argument("--frames", type=int, default=100)
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--replay", type=Path, help=argparse.SUPPRESS)
    ap.add_argument("--json", type=Path)
    args = ap.parse_args()
    if args.replay:
        print(json.dumps(replay(args.replay)))
        return 0
    if args.against is None or not (args.against / ".venv" / "bin" / "python").is_file():
        raise SystemExit("--against needs a checkout with its own venv (DIR/.venv/bin/python)")
    here = Path(__file__).resolve().parent.parent
    rounds = []
    with tempfile.TemporaryDirectory() as tmp:
        calls = Path(tmp) / "calls.pkl"
        capture(args.model, args.frames, calls)
        for r in range(args.rounds):
            this = _run(sys.executable, here, calls)
            other = _run(str(args.against / ".venv" / "bin" / "python"), args.against, calls)
            rounds.append({"this": this, "other": other,
                           "ratio": {k: round(this[k] / other[k], 2) for k in ("renderer", "inpainting", "total")}})
            print(f"round {r + 1}: renderer {this['renderer']:.2f} / {other['renderer']:.2f} ms = "
                  f"{rounds[-1]['ratio']['renderer']:.2f}x; inpainting {this['inpainting']:.2f} / "
                  f"{other['inpainting']:.2f} ms = {rounds[-1]['ratio']['inpainting']:.2f}x; "
                  f"total {this['total']:.2f} / {other['total']:.2f} ms", flush=True)
    median = {k: statistics.median(r["ratio"][k] for r in rounds) for k in ("renderer", "inpainting", "total")}
    stages = sorted({k for r in rounds for k in r["this"]})
    print(f"{'stage (CPU ms)':<14}{'this':>9}{'other':>9}")
    for k in stages:
        a = statistics.median(r["this"].get(k, 0.0) for r in rounds)
        b = statistics.median(r["other"].get(k, 0.0) for r in rounds)
        print(f"{k:<14}{a:>9.2f}{b:>9.2f}")
    print(f"median ratio this / other over {len(rounds)} rounds: " + ", ".join(f"{k} {v:.2f}x" for k, v in median.items()))
    if args.json:
        args.json.write_text(json.dumps({"model": args.model, "against": str(args.against), "rounds": rounds,
                                         "median_ratio": median}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
