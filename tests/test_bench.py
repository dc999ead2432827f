"""`facesculpt bench`, short: the JSON it writes has, per model, the pipelined rate, the end-to-end
latency and every stage of the paper's Table 2, measured (positive), and consistent with each other.
The figures themselves are the benchmark's business, not this test's."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parent.parent
STAGES = ("landmark_detection", "model_fitting", "mesh_deformation", "merging", "inpainting",
          "texture_update_rendering", "sequential_total")


@pytest.mark.slow
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
        # the timeline: slices that hold every output frame, each with the nodes' CPU use
        timeline = m["timeline"]
        assert sum(t["frames"] for t in timeline) == m["frames_out"], name
        assert max(t.get("p99_ms", 0) for t in timeline) >= m["latency_ms"]["p99"] * 0.99, name
        assert all(t["cpu_percent"]["renderer"] > 0 for t in timeline if "cpu_percent" in t), name
    assert doc["models"]["sfm"]["vertices"] == 3448
    # The table names the paper's column beside the measured one.
    assert "36.28" in result.stdout and "pipelined rate (fps)" in result.stdout
    assert "slowest slices of the window" in result.stdout


@pytest.mark.slow
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


@pytest.mark.slow
def test_bench_gives_each_figure_over_a_reference_workload_of_the_same_run(data_dir, models_dir, tmp_path):
    """The report has the reference workload, measured at the start and the end of the run, and each
    stage's ms over it, in the JSON and beside the ms in the table (the ratio's value is the
    machine's business)."""
    from facesculpt.app.bench_reference import as_ratio, reference_workload

    out = tmp_path / "bench.json"
    result = subprocess.run(
        [sys.executable, "-m", "facesculpt.cli", "bench", "--model", "facemesh", "--frames", "6", "--drags", "2",
         "--no-graph", "--json", str(out)], cwd=REPO, capture_output=True, text=True, timeout=150)
    assert result.returncode == 0, result.stderr[-2000:]
    doc = json.loads(out.read_text())
    ref = doc["reference"]
    assert ref["start"]["total_ms"] > 0 and ref["end"]["total_ms"] > 0 and ref["start"]["gl_ms"] > 0
    assert min(ref["start"]["total_ms"], ref["end"]["total_ms"]) <= ref["total_ms"] \
        <= max(ref["start"]["total_ms"], ref["end"]["total_ms"])
    m = doc["models"]["facemesh"]
    for stage in STAGES:
        assert m["stages_ratio"][stage] == as_ratio(m["stages_ms"][stage], ref["total_ms"]) > 0, stage
    head = next(line for line in result.stdout.splitlines() if line.startswith("stage (ms)"))
    assert "/ ref" in head
    row = next(line for line in result.stdout.splitlines() if line.startswith("inpainting"))
    assert f"{m['stages_ratio']['inpainting']:.3f}" in row.split()
    assert "reference workload measured in the same run" in result.stdout
    assert as_ratio(None, 5.0) is None and as_ratio(3.0, 0.0) is None
    with pytest.raises(ValueError, match="repeats"):
        reference_workload(0)


@pytest.mark.slow
def test_bench_scenario_acts_in_the_window_beside_a_busy_loop(data_dir, models_dir, tmp_path):
    """--scenario: the first preset load and the first nose drag (8 s in) happen inside the measured
    window, and the deformer takes them; --load 1 runs a busy loop beside it and stops it after."""
    from facesculpt.app.bench_scenario import DRAGS_S, LOAD_AT_S, BenchScenario

    events = BenchScenario("p.json").due(60.0)
    kinds = [e.kind for e in events]
    assert kinds.count("press") == kinds.count("release") == len(DRAGS_S) and kinds.count("move") > 200
    assert [e.command for e in events if e.kind == "command"] == ["load_preset", "reset", "load_preset"]
    assert len(LOAD_AT_S) == 2 and BenchScenario("p.json").due(0.0)[0].command == "load_preset"
    out = tmp_path / "bench.json"
    result = subprocess.run(
        [sys.executable, "-m", "facesculpt.cli", "bench", "--model", "facemesh", "--frames", "6", "--drags", "2",
         "--window", "13", "--scenario", "--load", "1", "--json", str(out)],
        cwd=REPO, capture_output=True, text=True, timeout=240)
    assert result.returncode == 0, result.stderr[-2000:]
    figures = json.loads(out.read_text())
    assert figures["scenario"] is True and figures["competing_busy_loops"] == 1
    entry = figures["models"]["facemesh"]
    counters = entry["nodes"]["deformer"]["counters"]
    assert counters.get("preset_loaded", 0) >= 1 and counters.get("press", 0) >= 1, counters
    assert entry["pipelined_fps"] > 5
    assert "with 1 competing busy loop(s) running" in result.stdout


def test_timeline_gives_no_cpu_figure_for_a_slice_too_short_to_measure():
    from facesculpt.app.bench_graph import CPU_SAMPLE_S, timeline_figures

    t0, s = 1_000_000_000, 1_000_000_000
    # frames at 0.1 .. 2.0 s; CPU sampled every CPU_SAMPLE_S and once more 1 ms after the last tick,
    # as the window's close does: the slice from 2 s holds one frame and a 1-ms CPU span.
    window = [(t0 + int(k * 0.1 * s), t0 + int(k * 0.1 * s) - 20_000_000) for k in range(1, 21)]
    times = [t0 + int(k * CPU_SAMPLE_S * s) for k in range(int(2.0 / CPU_SAMPLE_S) + 1)] + [t0 + int(2.001 * s)]
    samples = [(t, {"renderer": 0.25 * (t - t0) / s}) for t in times]
    samples[-1] = (samples[-1][0], samples[-2][1])  # no clock tick counted in that 1 ms
    rows = timeline_figures(window, samples, t0)
    assert [r["frames"] for r in rows] == [19, 1]
    assert rows[0]["cpu_percent"]["renderer"] == 25.0
    assert "cpu_percent" not in rows[1]
    assert rows[1]["p50_ms"] == 20.0


@pytest.mark.slow
def test_bench_with_the_plate_and_the_atlas_runs_them_in_process_and_in_the_graph(data_dir, models_dir, tmp_path):
    out = tmp_path / "bench.json"
    result = subprocess.run(
        [sys.executable, "-m", "facesculpt.cli", "bench", "--model", "facemesh", "--frames", "6", "--drags", "2",
         "--window", "2", "--warmup", "0.5", "--memory", "on", "--json", str(out)],
        cwd=REPO, capture_output=True, text=True, timeout=150)
    assert result.returncode == 0, result.stderr[-2000:]
    doc = json.loads(out.read_text())
    assert doc["memory"] == "on"
    m = doc["models"]["facemesh"]
    assert m["pipelined_fps"] > 0
    # the renderer node learned its plate: its diagnostics time the plate's stage
    assert m["nodes"]["renderer"]["stages_ms"]["plate"] > 0
    assert "--memory on" in result.stdout
