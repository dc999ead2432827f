"""`facesculpt process` never loses a user's file: it refuses to write over its input, and a
failed run leaves no file under the target's name (an older file there stays as it was)."""

from __future__ import annotations

import hashlib
import os
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from facesculpt.app.safe_output import partial_name, refuse_output_over_input, temporary_name


def _process(*args, cwd: Path) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "facesculpt.cli", "process", *map(str, args), "--quiet"],
                          cwd=cwd, capture_output=True, text=True, timeout=180)


def _sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _small_video(path: Path, frames: int = 3) -> Path:
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 25.0, (64, 48))
    for i in range(frames):
        writer.write(np.full((48, 64, 3), 40 * i, np.uint8))
    writer.release()
    return path


def test_the_output_may_not_be_the_input(tmp_path):
    video = _small_video(tmp_path / "in.avi")
    link = tmp_path / "link.avi"
    link.symlink_to(video)
    before = _sha(video)
    for out in (video, link, tmp_path / "." / "in.avi"):
        result = _process(video, "-o", out, cwd=tmp_path)
        assert result.returncode == 1, result.stderr
        last = result.stderr.strip().splitlines()[-1]
        assert last.startswith("facesculpt: refusing to write the output") and "same file" in last, last
    assert _sha(video) == before and sorted(p.name for p in tmp_path.iterdir()) == ["in.avi", "link.avi"]


def test_a_frame_pattern_that_can_name_the_input_is_refused(tmp_path):
    frames = tmp_path / "frames"
    frames.mkdir()
    video = _small_video(frames / "00007.avi")
    with pytest.raises(ValueError, match="one of its frame names is the input's"):
        refuse_output_over_input(video, str(frames / "%05d.avi"))
    refuse_output_over_input(video, str(frames / "%05d.png"))  # other names: allowed
    refuse_output_over_input(video, str(tmp_path / "%05d.avi"))  # another folder: allowed


def test_a_failed_run_leaves_no_file_and_an_older_output_untouched(tmp_path):
    broken = tmp_path / "broken.mp4"
    broken.write_bytes(b"not a video at all")
    target = tmp_path / "out.mp4"
    target.write_bytes(b"the user's earlier result")
    before = _sha(target)
    result = _process(broken, "-o", target, cwd=tmp_path)
    assert result.returncode == 1 and "Traceback" not in result.stderr, result.stderr
    assert _sha(target) == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["broken.mp4", "out.mp4"]  # no temporary left


def test_a_completed_run_replaces_the_target_and_leaves_nothing_else(tmp_path, models_dir):
    video = _small_video(tmp_path / "in.avi", frames=4)
    target = tmp_path / "out.mp4"
    target.write_bytes(b"old")
    result = _process(video, "-o", target, cwd=tmp_path)
    assert result.returncode == 0, result.stderr
    assert "edits from" not in result.stderr  # no edit asked, none claimed
    cap = cv2.VideoCapture(str(target))
    count = 0
    while cap.read()[0]:
        count += 1
    assert count == 4
    assert sorted(p.name for p in tmp_path.iterdir()) == ["in.avi", "out.mp4"]


def test_no_face_means_no_edits_are_claimed(tmp_path, models_dir):
    video = _small_video(tmp_path / "in.avi", frames=3)  # flat grey frames: no face
    result = _process(video, "-o", tmp_path / "out.mp4", "--edits", "nose_longer", cwd=tmp_path)
    assert result.returncode == 0, result.stderr
    assert "the edits are not applied" in result.stderr and "edits from" not in result.stderr


def test_names_beside_the_target():
    target = Path("/videos/out.mp4")
    assert partial_name(target) == Path("/videos/out.partial.mp4")
    staged = temporary_name(target)
    assert staged.parent == target.parent and staged.name.startswith(".out.") and staged.suffix == ".mp4"
    assert str(os.getpid()) in staged.name
