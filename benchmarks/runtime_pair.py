"""What the landmarks and hands benchmarks share: a detector's networks on onnxruntime (the
project's converted networks) next to ai-edge-litert (the original .tflite networks), timed call
by call in the same run, reported as medians and the ratio onnxruntime / litert.

    from benchmarks.runtime_pair import BACKENDS, report, runtime_arguments, timed
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

from facesculpt.paths import model_home, shared_data_dir

BACKENDS = ("onnxruntime", "litert")


def timed(fn, *args) -> float:
    """Milliseconds ``fn(*args)`` took."""
    t0 = time.perf_counter()
    fn(*args)
    return (time.perf_counter() - t0) * 1000.0


def runtime_arguments(doc: str, add_arguments, argv=None):
    """The parsed command line: ``add_arguments(parser)``'s own options, then --threads, --models
    and --json; and the shared data folder and model folder. Returns (args, data, models);
    data is None (with a sentence on stderr) when the shared data is not found."""
    parser = argparse.ArgumentParser(description=doc, formatter_class=argparse.RawDescriptionHelpFormatter)
    add_arguments(parser)
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--models", type=Path, default=None, help="model directory (default: model home)")
    parser.add_argument("--json", type=Path, default=None, help="also write the figures here")
    args = parser.parse_args(argv)
    data = shared_data_dir()
    if data is None:
        print("shared data not found (set FACESCULPT_DATA)", file=sys.stderr)
    return args, data, args.models or model_home()


def report(title: str, rows, times: dict[str, list[float]], result: dict, json_path: Path | None) -> dict:
    """Print ``title`` and a table of ``rows`` ((label, key) pairs: medians of ``times[key/backend]``
    in ms per runtime and their ratio), add them to ``result`` (and write it to ``json_path``).
    Returns the medians by ``key/backend``."""
    med = {k: float(np.median(v)) for k, v in times.items()}
    width = max(len(label) for label, _ in rows) + 2
    print(title)
    print(f"{'':{width}s}{'onnxruntime':>12s}{'litert':>10s}{'ratio':>8s}")
    for label, key in rows:
        ours, peer = med[f"{key}/onnxruntime"], med[f"{key}/litert"]
        print(f"{label:{width}s}{ours:12.2f}{peer:10.2f}{ours / peer:8.2f}")
        result[key] = {"onnxruntime_ms": ours, "litert_ms": peer, "ratio": ours / peer}
    if json_path:
        json_path.write_text(json.dumps(result, indent=2))
    return med
