"""Where people are (mediapipe's selfie segmentation, converted by `facesculpt setup`), and the
background plate that learns nothing there (issue 16): on the shared videos, the person's face is
inside the mask and the green screen behind them is not; a plate with the segmenter never learns a
pixel of the person (hair, neck) where the face-only plate does; a renderer asked for the plate
without the network stops with one sentence."""

from __future__ import annotations

import os
import subprocess
import sys

import cv2
import numpy as np
import pytest
from conftest import free_port

from benchmarks.renderer_scene import read_frames
from facesculpt.nodes.fitter.config import FitterConfig
from facesculpt.runtime.parameters import EXIT_BAD_PARAMETER


@pytest.fixture(scope="module")
def segmenter(models_dir):
    from facesculpt.nodes.renderer.person_segmentation import PersonSegmenter

    return PersonSegmenter(models_dir)


def test_the_person_is_in_the_mask_and_the_green_screen_is_not(segmenter, models_dir, data_dir):
    from facesculpt.nodes.landmarks.detector import LandmarkDetector

    frame = read_frames(data_dir, "d0")[0]
    H, W = frame.shape[:2]
    faces = LandmarkDetector(models_dir).track(frame)
    assert faces, "no face found in d0's first frame"
    face = np.zeros((H, W), np.uint8)
    cv2.fillConvexPoly(face, cv2.convexHull(faces[0].points[:, :2].astype(np.float32)).astype(np.int32), 1)
    people = segmenter.mask(frame)
    assert people.shape == (H, W) and people.dtype == np.uint8
    assert people[face != 0].mean() > 0.99
    hsv = cv2.cvtColor(frame, cv2.COLOR_BGR2HSV)
    green = ((np.abs(hsv[..., 0].astype(int) - 60) < 20) & (hsv[..., 1] > 80)).view(np.uint8)
    green = cv2.erode(green, np.ones((15, 15), np.uint8)) != 0  # the screen behind them, off its edges
    assert green.mean() > 0.2, "expected d0's green screen in the frame"
    assert people[green].mean() < 0.02


def test_the_probability_covers_the_frame_and_its_threshold_is_the_mask(segmenter, data_dir):
    frame = read_frames(data_dir, "d3")[0]
    H, W = frame.shape[:2]
    p = segmenter.probability(frame)
    assert p.shape == (H, W) and p.dtype == np.float32
    assert p.min() >= 0.0 and p.max() <= 1.0
    assert 0.05 < (p > 0.5).mean() < 0.95  # the frame holds person and background
    np.testing.assert_array_equal(segmenter.mask(frame), (p > 0.5).view(np.uint8))


def test_people_grow_inside_the_plate_box_and_stay_as_they_are_outside():
    from facesculpt.nodes.renderer.plate_learning import grown_in_box

    mask = np.zeros((60, 80), np.uint8)
    mask[20:24, 10:14] = 1   # inside the box
    mask[50:52, 70:72] = 1   # outside it
    mask[30, 41] = 1         # just outside its right edge: grows into it
    out = grown_in_box(mask, 3, (5, 5, 40, 45))
    assert out[20:24, 7:17].all() and out[17, 11] and not out[15, 11]
    assert out[50:52, 70:72].all() and out[48, 70] == 0    # outside: not grown
    assert out[30, 38:40].all()                             # grown in from outside the box
    np.testing.assert_array_equal(grown_in_box(mask, 3, None), cv2.dilate(
        mask, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (7, 7))))


@pytest.mark.slow
def test_the_plate_learns_nothing_of_the_person(segmenter, models_dir, data_dir):
    from facesculpt.app.pipeline import Pipeline, read_preset
    from facesculpt.paths import preset_file

    frames = read_frames(data_dir, "d3", 96)[::4]  # the head moves: the face-only plate sees hair
    learned = {}
    for people in (True, False):
        with Pipeline("facemesh", plate="on", models_dir=models_dir, fit=FitterConfig(neutral_frames=8)) as pipe:
            if not people:
                pipe.segmenter = None
            pipe.calibrate(frames[:8], 25.0)
            pipe.set_edits(read_preset(preset_file("cheeks")))
            for i, frame in enumerate(frames):
                pipe.process(frame, i / 25.0)
            plate = pipe.compositor.plate
            pipe.compositor.plate_sync()
            learned[people] = (plate.known(), plate.frame)
    always = np.ones(frames[0].shape[:2], bool)   # a person's in every frame: the plate cannot know it
    for frame in frames:
        always &= segmenter.mask(frame) != 0
    with_people, face_only = learned[True][0], learned[False][0]
    assert with_people.sum() > 1000  # it learned the background
    assert not (with_people & always).any()
    assert (face_only & always).sum() > 1000  # the face-only plate learned the hair and the neck


def test_the_renderer_without_the_network_stops_with_one_sentence(tmp_path):
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}
    env.update(FACESCULPT_MASTER=f"tcp://127.0.0.1:{free_port()}", FACESCULPT_RUN_DIR=str(tmp_path / "run"),
               FACESCULPT_HOME=str(tmp_path / "empty"))
    result = subprocess.run([sys.executable, "-m", "facesculpt.cli", "run", "renderer", "plate=on"], env=env,
                            cwd=tmp_path, capture_output=True, text=True, timeout=60)
    assert result.returncode == EXIT_BAD_PARAMETER, result.stderr
    last = result.stderr.strip().splitlines()[-1]
    assert last.startswith("facesculpt: renderer: ") and "person_segmentation.onnx is missing: run `facesculpt " \
        "setup`" in last, result.stderr
    assert "Traceback" not in result.stderr


def test_the_plate_takes_only_what_the_drag_shows_as_background():
    """A strip the edit uncovered: pixels dragged onto the learned background take the plate; pixels
    dragged onto the person (their rim, past the fitted outline) keep the drag; pixels the drag did
    not fill take it only where the segmenter saw nobody."""
    from facesculpt.nodes.renderer.background_plate import BackgroundPlate
    from facesculpt.nodes.renderer.plate_learning import PlateLearner
    from facesculpt.nodes.renderer.source_map import UNCOVERED

    rng = np.random.default_rng(3)
    bg = rng.integers(0, 255, (40, 60, 3), np.uint8)
    frame = bg.copy()
    frame[:, 30:] = (40, 200, 90)                    # a person covers the right half now
    people = np.zeros((40, 60), np.uint8)
    people[:, 30:] = 1
    learner = PlateLearner(BackgroundPlate(60, 40), segmenter=lambda f: people)
    learner.plate.update(bg, None)                   # the background, seen when nobody was there
    learner.learn(frame, np.zeros((0, 2)), 0.0, None)
    learner.sync()
    box = (10, 5, 50, 35)                            # the strip: box columns 10-22, rows 5-15
    fill = np.zeros((30, 40), np.uint8)
    fill[5:15, 10:22] = 1
    dragged = np.full((30, 40, 2), UNCOVERED, np.float32)
    done = np.zeros((30, 40), bool)
    done[5:15, 10:16] = True
    dragged[5:15, 10:13] = (-8.0, 0.0)               # onto the background (frame columns 12-14)
    dragged[5:15, 13:16] = (14.0, 0.0)               # onto the person (frame columns 37-39)
    out = learner.background_pixels(frame, fill, done, dragged, box)
    assert out[5:15, 10:13].all() and not out[5:15, 13:16].any()
    assert out[5:15, 16:20].all()                    # not dragged, frame columns 26-29: nobody there
    assert not out[5:15, 20:22].any()                # not dragged, frame columns 30-31: the person
    assert not out[fill == 0].any()
    learner.close()
