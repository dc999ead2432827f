"""Each node's start-up in parts, in fresh processes, as CPU time and as a ratio to a fixed
reference measured in the same run (a fresh `python -c "import numpy"`), in this checkout and
optionally in another one (its own venv), alternating.

    python -m benchmarks.bench_startup [--against /work/wt/startup-ref] [--nodes camera,landmarks,...]
                                       [--rounds 3] [--json out.json]

Parts, CPU seconds (time.process_time) of one fresh process per node and round:
``imports`` what `facesculpt run NODE` imports (its parser and node class); ``setup`` the node
made and set up as a launch file's default would (models loaded: the landmarks' networks, the
fitter's face mesh); ``first`` its first piece of work where it does one alone: the camera's
first frame of d3.mp4, the landmarks on it, the fitter's first fit (the model's mean seen from
the front), the renderer's compositor (EGL context, programs) at 856x480; the deformer waits for
a model and does nothing alone. ``heavy`` names the large modules loaded by then. A killed node's
way back (`benchmarks.bench_respawn`) is these parts plus the graph's: spawning, connecting, the
frame in flight sent again.
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
NODES = ("camera", "landmarks", "fitter", "deformer", "renderer")
HEAVY = ("cv2", "scipy", "onnxruntime", "moderngl", "yaml", "PIL", "av", "mcap", "psutil")
REFERENCE = "import time\nc = time.process_time()\nimport numpy\nprint(time.process_time() - c)"

# One node's parts in a fresh process of a checkout (argv[1]: the node, argv[2]: the video).
NODE = """
import os, sys, tempfile, time
os.environ.setdefault("FACESCULPT_RUN_DIR", tempfile.mkdtemp(prefix="fs-startup-"))
name, video = sys.argv[1], sys.argv[2]
c0 = time.process_time()
from facesculpt import cli
cli.build_parser(["run", name])
from facesculpt.nodes import node_class
cls = node_class(name)
c1 = time.process_time()
params = {"camera": {"source": video}, "fitter": {"model": "facemesh"}, "renderer": {"output": ""}}.get(name, {})
node = cls(name=name, params=params)
node.setup()
c2 = time.process_time()
import numpy as np
if name == "camera":
    frame = next(node.frames)
elif name == "landmarks":
    from facesculpt.nodes.camera.sources import VideoSource
    node.detector.track(next(VideoSource(video).frames())[0])
elif name == "fitter":
    from facesculpt.nodes.fitter import FitterConfig, fit_landmarks, load_model, make_fitter
    model = load_model("facemesh")
    pts = np.asarray(model.mean, np.float64)[:468]
    pts = np.column_stack([320 + 2 * pts[:, 0], 240 - 2 * pts[:, 1], -2 * pts[:, 2]])[None]
    fit_landmarks(make_fitter(model, FitterConfig(), image_size=(640, 480)), pts, np.ones(1), 0.0)
elif name == "renderer":
    from facesculpt.nodes.renderer.compositor import Compositor
    Compositor(856, 480)
c3 = time.process_time()
heavy = [m for m in sys.argv[3].split(",") if m in sys.modules]
print(c1 - c0, c2 - c1, c3 - c2, ",".join(heavy) or "-")
node.close()
"""
PARTS = ("imports", "setup", "first")


def _python(checkout: Path) -> str:
    return str(checkout / ".venv" / "bin" / "python")


def reference_s(checkout: Path) -> float:
    """CPU s of a fresh ``import numpy`` with ``checkout``'s python."""
    return float(subprocess.run([_python(checkout), "-c", REFERENCE], capture_output=True, text=True,
                                check=True).stdout)


def node_parts(checkout: Path, node: str, video: Path) -> dict:
    """``{part: CPU s, "heavy": modules}`` of ``node``'s start-up in a fresh process of ``checkout``."""
    out = subprocess.run([_python(checkout), "-c", NODE, node, str(video), ",".join(HEAVY)], cwd=checkout,
                         capture_output=True, text=True)
    if out.returncode:
        raise RuntimeError(f"{checkout}: {node}: {out.stderr.strip().splitlines()[-1]}")
    *parts, heavy = out.stdout.split()
    return dict(zip(PARTS, map(float, parts)), heavy=heavy)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--against", type=Path, default=None, help="another checkout (with DIR/.venv)")
    ap.add_argument("--nodes", default=",".join(NODES))
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args()
    from facesculpt.paths import shared_data_dir

    data = shared_data_dir()
    if data is None:
        print("shared data not found (set FACESCULPT_DATA)")
        return 1
    video = data / "video" / "d3.mp4"
    checkouts = {"this": REPO} | ({"other": args.against.resolve()} if args.against else {})
    nodes = args.nodes.split(",")
    got: dict = {label: {"reference": [], **{n: [] for n in nodes}} for label in checkouts}
    for r in range(args.rounds):
        order = list(checkouts.items())
        for label, checkout in order[::-1] if r % 2 else order:
            got[label]["reference"].append(reference_s(checkout))
            for n in nodes:
                got[label][n].append(node_parts(checkout, n, video))
    print("CPU s, medians over the rounds; x: the ratio to a fresh `import numpy` in the same run")
    med = {}
    for label, runs in got.items():
        ref = statistics.median(runs["reference"])
        med[label] = {"reference": ref}
        print(f"{label} ({checkouts[label]}): reference (import numpy) {ref:.3f} s")
        for n in nodes:
            m = {p: statistics.median(g[p] for g in runs[n]) for p in PARTS}
            m["total"] = statistics.median(sum(g[p] for p in PARTS) for g in runs[n])
            med[label][n] = m
            print(f"  {n:10s} " + "  ".join(f"{p} {m[p]:.3f} ({m[p] / ref:.1f}x)" for p in (*PARTS, "total"))
                  + f"  heavy: {runs[n][-1]['heavy']}")
    if "other" in med:
        print("this / other, total:  " + "  ".join(
            f"{n} {med['this'][n]['total'] / med['other'][n]['total']:.2f}" for n in nodes))
    if args.json:
        args.json.write_text(json.dumps({"runs": got, "medians": med}, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
