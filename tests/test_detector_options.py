"""The face and hand detectors' one options class (facesculpt.geometry.detector_options): the
nodes declare their detector parameters from it, the detectors take it and their old keyword
names, and the hands detector's old method name warns once."""

from __future__ import annotations

import dataclasses
import warnings

import cv2
import numpy as np
import pytest

from facesculpt.geometry.detector_options import DetectorOptions, with_values
from facesculpt.nodes.hands.detector import HAND_ALIASES, HAND_OPTIONS, HandDetector
from facesculpt.nodes.hands.node import DETECTOR_PARAMS as HAND_PARAMS
from facesculpt.nodes.hands.node import HandsNode
from facesculpt.nodes.landmarks.detector import FACE_ALIASES, FACE_OPTIONS, LandmarkDetector
from facesculpt.nodes.landmarks.node import DETECTOR_PARAMS as FACE_PARAMS
from facesculpt.nodes.landmarks.node import LandmarksNode


def test_every_option_has_help_and_numbers_have_a_range():
    for f in dataclasses.fields(DetectorOptions):
        assert f.metadata["help"], f.name
        if f.type in ("int", "float"):
            assert f.metadata["range"] is not None, f.name
        assert f.metadata["choices"] is None or f.default in f.metadata["choices"]


@pytest.mark.parametrize("node, options, aliases, names", [
    (LandmarksNode, FACE_OPTIONS, FACE_ALIASES, FACE_PARAMS), (HandsNode, HAND_OPTIONS, HAND_ALIASES, HAND_PARAMS)])
def test_the_nodes_declare_their_detector_parameters_from_the_options(node, options, aliases, names):
    fields = {f.name: f for f in dataclasses.fields(DetectorOptions)}
    for name in names:
        field = fields[aliases.get(name, name)]
        param = node.PARAMS[name]
        assert param.default == getattr(options, field.name)
        assert param.range == field.metadata["range"] and param.description.startswith(field.metadata["help"])


def test_the_rooms_keep_their_own_defaults_written_once():
    assert (FACE_OPTIONS.max_tracked, FACE_OPTIONS.redetect_interval) == (1, 15)
    assert (HAND_OPTIONS.max_tracked, HAND_OPTIONS.redetect_interval) == (2, 10)
    assert LandmarksNode.PARAMS["max_faces"].default == 1 and HandsNode.PARAMS["max_hands"].default == 2


def test_an_unknown_option_is_refused_by_name():
    with pytest.raises(TypeError, match="max_handz"):
        with_values(HAND_OPTIONS, HAND_ALIASES, {"max_handz": 3})
    assert with_values(FACE_OPTIONS, FACE_ALIASES, {"max_faces": 4, "threads": None}).max_tracked == 4


def test_detectors_take_their_old_keywords_and_an_options_object(models_dir):
    faces = LandmarkDetector(models_dir, max_faces=3, min_face=0.1, redetect_interval=7)
    assert (faces.max_faces, faces.max_tracked, faces.min_face, faces.redetect_interval) == (3, 3, 0.1, 7)
    faces.max_faces = 0  # the pipeline sets it per selection; at least one
    assert faces.max_tracked == 1
    hands = HandDetector(models_dir, options=dataclasses.replace(HAND_OPTIONS, mirrored=True), max_hands=1)
    assert (hands.max_hands, hands.mirrored, hands.redetect_interval) == (1, True, 10)


def test_the_old_palm_detector_name_warns_once_and_still_works(models_dir, data_dir):
    image = cv2.imread(str(data_dir / "hands" / "victory.jpg"))
    detector = HandDetector(models_dir)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        palms = detector.run_palm_detector(image)
        detector.run_palm_detector(image)
    assert [w.category for w in caught] == [DeprecationWarning]
    expected = detector.run_detector(image)
    assert len(palms) == len(expected) >= 1
    assert all(np.array_equal(a.box, b.box) for a, b in zip(palms, expected))
