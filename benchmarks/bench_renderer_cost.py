"""The compositor's cost per frame in CPU time, this checkout against one or more others (e.g. the
pre-realism renderer, 22775c8, and the code before a change, each in a worktree with its own venv),
alternating, in one run.

    python -m benchmarks.bench_renderer_cost --against /work/wt/speed-old [--against DIR ...]
                                             [--model facemesh|sfm] [--frames 100] [--rounds 3]
                                             [--json out.json]

The renderer's inputs are captured once, here, from the bench's own pipeline (`facesculpt bench`'s
frames of s18.mp4 at 856x480, its Fig. 6e edit, the model's fits per frame): the very calls
``Pipeline.process`` makes to ``Compositor.render``. Each round then replays them through this
checkout's compositor and through each other checkout's (its python, ``DIR/.venv/bin/python``, in a
subprocess running this file with ``--replay``), one after the other. Times are the process's CPU
time (``time.process_time``, every thread: llvmpipe's too), not the wall clock: on a machine shared
with other work the wall clock measures the others as much as the renderer. Reported per stage
(mean ms over the frames after the first 3) and as "renderer" (camera + texture + draw + readback +
composite: `facesculpt bench`'s "texture + texcoord update + rendering") and "inpainting" (masks +
inpaint), each checkout's, and their ratios (this / other), per round and the median over rounds,
for each ``--against`` checkout.

``--paired DIR`` (DIR: a checkout of the same layout, e.g. the code before a change) loads DIR's
renderer package (``facesculpt/nodes/renderer``) into one process beside this checkout's and
renders every captured frame through both, alternating which goes first, for ``--rounds`` passes:
the two meet the same caches and the same load, so their ratio is far steadier than that of
separate processes (it can tell a change of a few per cent). Everything outside the renderer
package is this checkout's. It also counts the frames whose pixels differ between the two.
"""

from __future__ import annotations

import argparse
import importlib
import importlib.util
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

    if shared_data_dir() is None:
        raise SystemExit("the shared data (../shared/data or FACESCULPT_DATA) is needed: it holds video/s18.mp4")
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


def _other_compositor(root: Path) -> types.ModuleType:
    """The compositor module of the checkout at ``root``, its renderer package loaded into this
    process under another name: its relative imports resolve within it, the rest of facesculpt
    to this checkout's."""
    package = root / "facesculpt" / "nodes" / "renderer"
    if not (package / "compositor.py").is_file():
        raise SystemExit(f"--paired needs a checkout with facesculpt/nodes/renderer/compositor.py; none in {root}")
    name = "_paired_renderer"
    spec = importlib.util.spec_from_file_location(name, package / "__init__.py",
                                                  submodule_search_locations=[str(package)])
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    spec.loader.exec_module(module)
    return importlib.import_module(f"{name}.compositor")


def _means(parts: dict[str, list[float]]) -> dict:
    import numpy as np

    means = {k: float(np.mean(v)) for k, v in parts.items()}
    means["renderer"] = sum(means.get(k, 0.0) for k in RENDER_PARTS)
    means["inpainting"] = sum(means.get(k, 0.0) for k in INPAINT_PARTS)
    return {k: round(v, 3) for k, v in means.items()}


def replay_paired(path: Path, other: Path, rounds: int) -> dict:
    """Mean stage ms (process CPU time) of this checkout's compositor ("this") and ``other``'s
    (:func:`_other_compositor`), each captured call rendered by both in turn, which goes first
    alternating, ``rounds`` times over; "frames differing": the frames whose pixels differ."""
    from facesculpt.runtime.process_limits import limit_threads

    limit_threads(1)
    import numpy as np

    import facesculpt.nodes.renderer.compositor as this_module

    other_module = _other_compositor(other)
    data = pickle.loads(path.read_bytes())
    known = inspect.signature(this_module.Compositor.render).parameters
    calls = [(args, {k: v for k, v in kwargs.items() if k in known}) for args, kwargs in data["calls"]]
    comps = {}
    for label, module in (("this", this_module), ("other", other_module)):
        module.time = types.SimpleNamespace(perf_counter=time.process_time)   # the stages in CPU time
        comps[label] = module.Compositor(*data["size"])
    parts: dict[str, dict[str, list[float]]] = {"this": {}, "other": {}}
    differing = 0
    for r in range(rounds):
        for i, (args, kwargs) in enumerate(calls):
            frames = {}
            for label in (("this", "other") if (i + r) % 2 == 0 else ("other", "this")):
                frames[label] = comps[label].render(*args, **kwargs)
                if i >= SKIP:
                    for k, v in comps[label].timings.items():
                        parts[label].setdefault(k, []).append(v)
            if r == 0 and not np.array_equal(frames["this"], frames["other"]):
                differing += 1
    for comp in comps.values():
        comp.release()
    return {"this": _means(parts["this"]), "other": _means(parts["other"]), "frames differing": int(differing),
            "frames": len(calls)}


def _run(python: str, cwd: Path, path: Path) -> dict:
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    done = subprocess.run([python, str(Path(__file__).resolve()), "--replay", str(path)], cwd=cwd, env=env,
                          capture_output=True, text=True, check=True)
    return json.loads(done.stdout.strip().splitlines()[-1])


def _ratios(this: dict, other: dict) -> dict:
    return {k: round(this[k] / other[k], 2) for k in ("renderer", "inpainting", "total")}


def _summary(label: str, rounds: list[dict]) -> dict:
    """Print the per-stage medians of this checkout and ``label``'s over ``rounds`` and the median
    ratios; returns the median ratios."""
    median = {k: statistics.median(r["ratio"][k] for r in rounds) for k in ("renderer", "inpainting", "total")}
    stages = sorted({k for r in rounds for k in r["this"]})
    print(f"against {label}:")
    print(f"{'stage (CPU ms)':<14}{'this':>9}{'other':>9}")
    for k in stages:
        a = statistics.median(r["this"].get(k, 0.0) for r in rounds)
        b = statistics.median(r["other"].get(k, 0.0) for r in rounds)
        print(f"{k:<14}{a:>9.2f}{b:>9.2f}")
    print(f"median ratio this / {label} over {len(rounds)} rounds: "
          + ", ".join(f"{k} {v:.2f}x" for k, v in median.items()))
    return median


def _paired(args: argparse.Namespace) -> int:
    """``--paired``: capture, then :func:`replay_paired` in a fresh process of this python."""
    if not (args.paired / "facesculpt" / "nodes" / "renderer" / "compositor.py").is_file():
        raise SystemExit(f"--paired needs a checkout with facesculpt/nodes/renderer/compositor.py; none in {args.paired}")
    with tempfile.TemporaryDirectory() as tmp:
        calls = Path(tmp) / "calls.pkl"
        capture(args.model, args.frames, calls)
        env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
        done = subprocess.run([sys.executable, str(Path(__file__).resolve()), "--replay-paired", str(calls),
                               str(args.paired.resolve()), "--rounds", str(args.rounds)],
                              env=env, capture_output=True, text=True, check=True)
    result = json.loads(done.stdout.strip().splitlines()[-1])
    this, other = result["this"], result["other"]
    print(f"paired with {args.paired}, {args.rounds} passes over {result['frames']} frames, in one process:")
    print(f"{'stage (CPU ms)':<14}{'this':>9}{'other':>9}{'ratio':>8}")
    for k in sorted(this):
        if other.get(k):
            print(f"{k:<14}{this[k]:>9.3f}{other[k]:>9.3f}{this[k] / other[k]:>8.3f}")
    print(f"frames whose pixels differ: {result['frames differing']} of {result['frames']}")
    if args.json:
        args.json.write_text(json.dumps({"model": args.model, "paired": str(args.paired), **result}, indent=1))
    return 0


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--against", type=Path, action="append",
                    help="another checkout (with DIR/.venv); repeat it to alternate with several in one run")
    ap.add_argument("--model", default="facemesh", choices=["facemesh", "sfm"])
    ap.add_argument("--frames", type=int, default=100)
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--paired", type=Path,
                    help="a checkout whose renderer package runs in this process beside this one's, frame by frame")
    ap.add_argument("--replay", type=Path, help=argparse.SUPPRESS)
    ap.add_argument("--replay-paired", type=Path, nargs=2, help=argparse.SUPPRESS)
    ap.add_argument("--json", type=Path)
    args = ap.parse_args()
    if args.replay:
        print(json.dumps(replay(args.replay)))
        return 0
    if args.replay_paired:
        print(json.dumps(replay_paired(*args.replay_paired, args.rounds)))
        return 0
    if args.paired is not None:
        return _paired(args)
    others = args.against or []
    missing = [str(d) for d in others if not (d / ".venv" / "bin" / "python").is_file()]
    if not others or missing:
        raise SystemExit("--against needs a checkout with its own venv (DIR/.venv/bin/python)"
                         + (f"; none in {', '.join(missing)}" if missing else ""))
    here = Path(__file__).resolve().parent.parent
    rounds: dict[str, list[dict]] = {str(d): [] for d in others}
    with tempfile.TemporaryDirectory() as tmp:
        calls = Path(tmp) / "calls.pkl"
        capture(args.model, args.frames, calls)
        for r in range(args.rounds):
            this = _run(sys.executable, here, calls)
            for d in others:
                other = _run(str(d / ".venv" / "bin" / "python"), d, calls)
                rounds[str(d)].append({"this": this, "other": other, "ratio": _ratios(this, other)})
                ratio = rounds[str(d)][-1]["ratio"]
                print(f"round {r + 1}, against {d}: renderer {this['renderer']:.2f} / {other['renderer']:.2f} ms = "
                      f"{ratio['renderer']:.2f}x; inpainting {this['inpainting']:.2f} / "
                      f"{other['inpainting']:.2f} ms = {ratio['inpainting']:.2f}x; "
                      f"total {this['total']:.2f} / {other['total']:.2f} ms", flush=True)
    medians = {label: _summary(label, rs) for label, rs in rounds.items()}
    if args.json:
        out = {"model": args.model, "against": {label: {"rounds": rounds[label], "median_ratio": medians[label]}
                                                for label in rounds}}
        args.json.write_text(json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
