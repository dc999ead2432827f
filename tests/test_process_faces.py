"""Several faces: `facesculpt process --faces all` fits every face with its own identity and
edits each with its own preset (`--edits N:PRESET`); a face left unedited keeps its pixels; the
shared photo with three people gets three fitted, edited faces."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest
from two_people import write_two_people

from facesculpt.nodes.fitter.config import FitterConfig

REPO = Path(__file__).resolve().parent.parent
FRAMES = 12


def process(*args) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "facesculpt.cli", "process", *map(str, args), "--quiet"], cwd=REPO,
                          capture_output=True, text=True, timeout=300)


@pytest.fixture(scope="module")
def two_people(data_dir, tmp_path_factory) -> tuple[Path, list[np.ndarray]]:
    path = tmp_path_factory.mktemp("two") / "two_people.mkv"
    return path, write_two_people(data_dir, path, FRAMES)


def changed(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.abs(a.astype(np.int16) - b.astype(np.int16)).max(axis=2) > 8


@pytest.mark.slow
def test_two_faces_each_with_its_own_edit(two_people, models_dir, tmp_path):
    video, inputs = two_people
    both = tmp_path / "both" / "%03d.png"
    r = process(video, "-o", both, "--faces", "all", "--edits", "1:nose_longer", "--edits", "2:chin",
                "--neutral-frames", "5")
    assert r.returncode == 0, r.stderr
    assert "on 2 face(s)" in r.stderr
    only_left = tmp_path / "left" / "%03d.png"
    r = process(video, "-o", only_left, "--faces", "all", "--edits", "1:nose_longer", "--neutral-frames", "5")
    assert r.returncode == 0, r.stderr
    for i in (3, FRAMES - 1):
        src = inputs[i]
        out_both = cv2.imread(str(both).replace("%03d", f"{i:03d}"))
        out_left = cv2.imread(str(only_left).replace("%03d", f"{i:03d}"))
        d_both = changed(src, out_both)
        # both people are edited in the same output frame ...
        assert d_both[:, :512].sum() > 300 and d_both[:, 512:].sum() > 300
        # ... each with its own edit: the left face is the same whether or not the right one is edited,
        assert np.array_equal(out_both[:, :480], out_left[:, :480])
        # and a face no edit names keeps its pixels exactly
        assert np.array_equal(out_left[:, 544:], src[:, 544:])
        # the chin edit moves the lower face of the right person, not the area above the eyes
        assert d_both[300:, 512:].sum() > d_both[:150, 512:].sum()


@pytest.mark.slow
def test_largest_is_one_face_and_face_numbers_need_a_selection(two_people, models_dir, tmp_path):
    video, inputs = two_people
    out = tmp_path / "one" / "%03d.png"
    r = process(video, "-o", out, "--edits", "nose_longer", "--neutral-frames", "5", "--max-frames", "4")
    assert r.returncode == 0, r.stderr
    assert "on 1 face(s)" in r.stderr
    r = process(video, "-o", tmp_path / "x" / "%03d.png", "--edits", "2:chin")
    assert r.returncode != 0
    assert "--faces all" in r.stderr.strip().splitlines()[-1]
    r = process(video, "-o", tmp_path / "y" / "%03d.png", "--faces", "several")
    assert r.returncode != 0
    assert "faces must be all, largest or a face number" in r.stderr
    r = process(video, "-o", tmp_path / "z" / "%03d.png", "--edits", "chin", "--strength", "4")
    assert r.returncode != 0
    assert "--strength 4.0 is outside 0..3" in r.stderr.strip().splitlines()[-1]
    assert not any((tmp_path / d).exists() for d in "xyz")


def test_three_people_in_the_shared_photo(data_dir, models_dir):
    from facesculpt.app.pipeline import Pipeline, read_preset

    photo = cv2.imread(str(data_dir / "faces" / "2008_002506.jpg"))
    with Pipeline("facemesh", faces="all", fit=FitterConfig(neutral_frames=1)) as pipeline:
        pipeline.calibrate([photo], fps=1.0)
        pipeline.set_edits(read_preset("nose_longer"))
        result = pipeline.process(photo, 0.0)
    assert sorted(result.fits) == [0, 1, 2]  # three people, numbered from the left
    xs = [float(result.fits[k].projected[:, 0].mean()) for k in (0, 1, 2)]
    assert xs == sorted(xs)
    moved = changed(photo, result.image)
    for k in (0, 1, 2):  # each face's own region changed
        px = result.fits[k].projected
        x0, x1 = int(px[:, 0].min()), int(px[:, 0].max())
        y0, y1 = int(px[:, 1].min()), int(px[:, 1].max())
        assert moved[y0:y1, x0:x1].sum() > 50, k


@pytest.mark.slow
def test_a_face_number_beyond_the_faces_found_says_how_many_were_found(two_people, data_dir, models_dir, tmp_path):
    """`--faces 3` on two people (and `--faces 2` on one, in a batch) is an error naming how many
    faces were found, with no output left behind, not an unedited copy that exits 0."""
    video, _ = two_people
    out = tmp_path / "three.mp4"
    r = process(video, "-o", out, "--faces", "3", "--edits", "nose_longer", "--neutral-frames", "2", "--max-frames", "3")
    assert r.returncode == 1, r.stderr
    assert r.stderr.strip().splitlines()[-1] == (
        f"facesculpt: --faces 3: only 2 faces were found (faces 1 to 2, from the left) in {video}, "
        f"so there is no face 3 to fit; no output written")
    assert not out.exists()
    one = data_dir / "video" / "d0.mp4"
    r = process(one, "-o", f"{tmp_path / 'batch'}/", "--workers", "1", "--faces", "2", "--max-frames", "3")
    assert r.returncode == 1, r.stderr
    assert (f"FAILED {one}: --faces 2: only 1 face was found (face 1) in {one}, so there is no face 2 to fit; "
            f"no output written") in r.stderr
    assert not list((tmp_path / "batch").glob("*.mp4"))
