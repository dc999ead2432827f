"""`facesculpt bench`, short: the JSON it writes has, per model, the pipelined rate, the end-to-end
latency and every stage of the paper's Table 2, measured (positive), and consistent with each other.
The figures themselves are the benchmark's business, not this test's."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
STAGES = ("landmark_detection", "model_fitting", "mesh_deformation", "merging", "inpainting",
          "texture_update_rendering", "sequential_total")


def test_short_bench_writes_every_figure(data_dir, models_dir, tmp_path):
    out = tmp_path / "bench.json"
    result = subprocess.run(
        [sys.executable, "-m", "facesculpt.cli", "bench", "--model", "both", "--frames", "8", "--drags", "4",
         "--window", "2", "--warmup", "0.5", "--json", str(out)],
        cwd=REPO, capture_output=True, text=True, timeout=150)
    assert result.returncode == 0, result.stderr[-2000:]
    doc = json.loads(out.read_text())
    assert doc["size"] == [856, 480]
    assert set(doc["models"]) == {"facemesh", "sfm"}
    for name, m in doc["models"].items():
        assert m["pipelined_fps"] > 0 and m["frames_out"] >= 2, name
        assert 0 < m["latency_ms"]["p50"] <= m["latency_ms"]["p95"] <= m["latency_ms"]["p99"], name
        # the longest gap between two output frames is at least the mean gap
        assert m["longest_stall_ms"] >= 1000.0 / m["pipelined_fps"] * 0.99, name
        assert m["frames_dropped"] is None or m["frames_dropped"] >= 0, name
        for stage in STAGES:
            assert m["stages_ms"][stage] > 0, (name, stage)
        parts = sum(m["stages_ms"][k] for k in STAGES[:-1])
        # The sequential total is the measured frame time plus one drag update: never less than its parts.
        assert m["stages_ms"]["sequential_total"] >= 0.99 * parts, name
        assert m["nodes"]["fitter"]["stages_ms"]["fit"] > 0  # the graph's own diagnostics came in
    assert doc["models"]["sfm"]["vertices"] == 3448
    # The table names the paper's column beside the measured one.
    assert "36.28" in result.stdout and "pipelined rate (fps)" in result.stdout


def test_bench_at_a_chosen_size(data_dir, models_dir, tmp_path):
    out = tmp_path / "bench.json"
    result = subprocess.run(
        [sys.executable, "-m", "facesculpt.cli", "bench", "--model", "facemesh", "--frames", "6", "--drags", "2",
         "--no-graph", "--size", "1280x720", "--json", str(out)], cwd=REPO, capture_output=True, text=True, timeout=150)
    assert result.returncode == 0, result.stderr[-2000:]
    assert json.loads(out.read_text())["size"] == [1280, 720]
    bad = subprocess.run([sys.executable, "-m", "facesculpt.cli", "bench", "--size", "1280by720", "--no-graph"],
                         cwd=REPO, capture_output=True, text=True, timeout=60)
    assert bad.returncode != 0 and "must be WIDTHxHEIGHT" in bad.stderr.strip().splitlines()[-1]
