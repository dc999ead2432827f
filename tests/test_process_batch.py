"""`facesculpt process` on a batch: three shared videos and a broken file on a real Dask cluster
of two local workers. Every output is the single-file command's, byte for byte; the broken input
is named and the exit status is non-zero; a rerun skips what is complete."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parent.parent
OPTIONS = ["--edits", "chin", "--max-frames", "8", "--neutral-frames", "4"]


def process(*args, cwd) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "facesculpt.cli", "process", *map(str, args)], cwd=cwd,
                          capture_output=True, text=True, timeout=300)


@pytest.fixture
def cluster():
    distributed = pytest.importorskip("distributed")
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=":0",
                                  silence_logs=40) as local:
        yield local.scheduler_address


@pytest.mark.slow
def test_batch_on_a_cluster_matches_the_single_file_command(cluster, data_dir, models_dir, tmp_path):
    videos = [data_dir / "video" / f"{name}.mp4" for name in ("d0", "d3", "d12")]
    broken = tmp_path / "broken.mp4"
    broken.write_bytes(b"not a video at all")
    before = broken.read_bytes()
    out = tmp_path / "out"
    r = process(*videos, broken, "-o", out, "--cluster", cluster, *OPTIONS, cwd=tmp_path)
    assert r.returncode == 1, r.stderr
    last = r.stderr.strip().splitlines()[-1]
    assert last == f"3 of 4 videos written to {out}; failed: {broken}", last
    assert f"FAILED {broken}: cannot read {broken}" in r.stderr
    assert sorted(p.name for p in out.iterdir()) == ["d0.mp4", "d12.mp4", "d3.mp4"]  # nothing half-written
    assert broken.read_bytes() == before
    for video in videos:
        single = tmp_path / f"single_{video.stem}.mp4"
        s = process(video, "-o", single, *OPTIONS, "--quiet", cwd=tmp_path)
        assert s.returncode == 0, s.stderr
        assert single.read_bytes() == (out / video.name).read_bytes(), video.name
    # a rerun skips the complete outputs and tries only what failed
    stamps = {p.name: p.stat().st_mtime_ns for p in out.iterdir()}
    r = process(*videos, broken, "-o", out, "--cluster", cluster, *OPTIONS, cwd=tmp_path)
    assert r.returncode == 1
    assert r.stderr.count("is already complete") == 3
    assert {p.name: p.stat().st_mtime_ns for p in out.iterdir()} == stamps


@pytest.mark.slow
def test_a_folder_of_videos_on_local_workers_and_clear_errors(data_dir, models_dir, tmp_path):
    src = tmp_path / "in"
    src.mkdir()
    (src / "a.mp4").symlink_to(data_dir / "video" / "d0.mp4")
    (src / "notes.txt").write_text("not a video")
    out = tmp_path / "out"
    r = process(src, "-o", out, "--workers", "1", *OPTIONS, cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    assert sorted(p.name for p in out.iterdir()) == ["a.mp4"]
    r = process(src, "-o", out / "x%03d.png", *OPTIONS, cwd=tmp_path)
    assert r.returncode != 0 and "must name a folder" in r.stderr.strip().splitlines()[-1]
    r = process(tmp_path / "missing" / "*.mp4", "-o", out, cwd=tmp_path)
    assert r.returncode != 0 and "holds no video" in r.stderr.strip().splitlines()[-1]
