"""benchmarks/bench_renderer_cost.py's paired replay: another checkout's renderer package run in
one process beside this one's, frame by frame, on captured Compositor.render calls (a synthetic
scene here; real OpenGL, EGL). A copy of this checkout's package renders the same pixels; a copy
with a wider soft edge does not, so the other package is the one that ran."""

from __future__ import annotations

import json
import pickle
import shutil
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np

from benchmarks.renderer_scene import plane_mesh

ROOT = Path(__file__).resolve().parent.parent


def _calls(path: Path, frames: int = 6) -> None:
    """Captured-like calls: a textured frame, a plane mesh whose middle moves 3 px right."""
    rng = np.random.default_rng(0)
    frame = cv2.GaussianBlur(rng.integers(0, 256, (120, 160, 3), np.uint8), (0, 0), 1.0)
    vertices, projected, triangles = plane_mesh((80, 60), 70, n=8)
    deformed = vertices.copy()
    middle = np.hypot(vertices[:, 0] - 80, vertices[:, 1] - 60) < 25
    calls = []
    for i in range(frames):
        moved = deformed.copy()
        moved[middle, 0] += 3.0 + 0.2 * i
        calls.append(((frame, vertices, projected, triangles, moved), {}))
    path.write_bytes(pickle.dumps({"size": (160, 120), "calls": calls}))


def _paired(calls: Path, other: Path) -> dict:
    done = subprocess.run([sys.executable, "-m", "benchmarks.bench_renderer_cost", "--replay-paired", str(calls),
                           str(other), "--rounds", "1"], cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-2000:]
    return json.loads(done.stdout.strip().splitlines()[-1])


def _copy_of_renderer(dest: Path) -> Path:
    package = dest / "facesculpt" / "nodes" / "renderer"
    shutil.copytree(ROOT / "facesculpt" / "nodes" / "renderer", package,
                    ignore=shutil.ignore_patterns("__pycache__"))
    return package


def test_the_paired_replay_runs_the_other_checkouts_renderer_beside_this_one(tmp_path):
    calls = tmp_path / "calls.pkl"
    _calls(calls)
    _copy_of_renderer(tmp_path / "same")
    same = _paired(calls, tmp_path / "same")
    assert same["frames"] == 6 and same["frames differing"] == 0
    for label in ("this", "other"):
        assert same[label]["renderer"] > 0 and same[label]["texture"] > 0
    wider = _copy_of_renderer(tmp_path / "wider") / "compositor.py"
    source = wider.read_text()
    assert "FEATHER_FRACTION = 0.015" in source
    wider.write_text(source.replace("FEATHER_FRACTION = 0.015", "FEATHER_FRACTION = 0.15"))
    assert _paired(calls, tmp_path / "wider")["frames differing"] == 6
