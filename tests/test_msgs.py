"""Message encoding and validation, and node parameters (no sockets)."""

from __future__ import annotations

import msgpack
import numpy as np
import pytest

from facesculpt.msgs import (
    REGISTRY,
    DecodeError,
    Deformation,
    Diagnostics,
    FaceLandmarks,
    FaceModel,
    FaceState,
    Image,
    InputEvent,
    decode,
    encode,
    summarize,
)
from facesculpt.runtime.parameters import coerce_param, parse_assignments

rng = np.random.default_rng(3)

EXAMPLES = [
    Image(stamp=11, seq=2, frame_id="camera", image=rng.integers(0, 255, (48, 64, 3), dtype=np.uint8)),
    FaceLandmarks(stamp=12, points=rng.random((2, 468, 3), dtype=np.float32), scores=np.array([0.9, 0.8], np.float32),
                  rois=rng.random((2, 5), dtype=np.float32), image_size=[64, 48]),
    FaceModel(model_id="sfm", vertices=rng.random((10, 3), dtype=np.float32), triangles=np.array([[0, 1, 2]], np.int32),
              landmark_names=["nose_tip"], landmark_vertices=np.array([4], np.int32), version=3),
    FaceState(stamp=13, model_id="sfm", t=np.array([0, 0, 500.0]), scale=1.2, alpha=np.zeros(63, np.float32),
              beta=np.zeros(6, np.float32), vertices=rng.random((10, 3), dtype=np.float32),
              projected=rng.random((10, 2), dtype=np.float32), residual_px=1.5, image_size=[64, 48]),
    InputEvent(stamp=14, kind="move", vector=np.array([0, 0, 5], np.float32), source="test"),
    InputEvent(stamp=15, kind="axes", axes=np.array([0.5, -1, 0], np.float32), buttons=3),
    Deformation(model_id="sfm", displacement=rng.random((10, 3), dtype=np.float32), handles=np.array([4], np.int32),
                roi=np.arange(5, dtype=np.int32), version=9),
    Diagnostics(node="camera", pid=1, values={"rate_hz": {"camera/image": 30.0}, "errors": 0}),
]


@pytest.mark.parametrize("msg", EXAMPLES, ids=lambda m: m.TYPE)
def test_every_type_round_trips(msg):
    frames = encode(msg, "some/topic")
    topic, back = decode([bytes(f) for f in frames])
    assert topic == "some/topic" and type(back) is type(msg)
    for name, value in vars(msg).items():
        got = getattr(back, name)
        if isinstance(value, np.ndarray):
            assert got.dtype == value.dtype and np.array_equal(got, value)
        elif value is None:
            assert got is None
        elif isinstance(value, float) and np.isnan(value):
            assert np.isnan(got)
        else:
            assert got == value
    assert set(REGISTRY) >= {"Image", "FaceLandmarks", "FaceModel", "FaceState", "InputEvent", "Deformation",
                             "Diagnostics"}


def test_arrays_travel_as_their_own_frames_and_decode_without_copy():
    img = EXAMPLES[0]
    frames = encode(img, "camera/image")
    assert len(frames) == 4 and len(frames[2]) == img.image.nbytes   # topic, header, image, K
    _, back = decode([bytes(f) for f in frames])
    assert not back.image.flags.writeable and not back.image.flags.owndata  # a view onto the frame


@pytest.mark.parametrize("bad, match", [
    (dict(image=np.zeros((4, 4), np.uint8)), "2 dims"),
    (dict(image=np.zeros((4, 4, 3), np.float32)), "dtype"),
    (dict(image=np.zeros((4, 4, 4), np.uint8)), "shape"),
    (dict(K=np.eye(4)), "shape"),
])
def test_invalid_fields_are_refused_before_sending(bad, match):
    with pytest.raises(DecodeError, match=match):
        encode(Image(**bad), "camera/image")


def test_named_dimensions_must_agree():
    with pytest.raises(DecodeError, match="disagrees"):
        encode(FaceState(vertices=np.zeros((5, 3), np.float32), projected=np.zeros((4, 2), np.float32)), "x")
    with pytest.raises(DecodeError, match="kind"):
        encode(InputEvent(kind="teleport"), "input/events")


@pytest.mark.parametrize("msg, match", [
    (Image(image=np.zeros((4, 4), np.uint8)), "descriptor"),
    (Image(image=np.zeros((4, 4, 4), np.uint8)), "shape"),
    (Image(K=np.eye(4)), "shape"),
    (Image(seq="7"), "seq: expected int"),
    (Image(stamp=True), "stamp: expected int"),
    (FaceState(vertices=np.zeros((5, 3), np.float32), projected=np.zeros((4, 2), np.float32)), "disagrees"),
    (InputEvent(kind="teleport"), "kind"),
], ids=lambda v: v if isinstance(v, str) else v.TYPE)
def test_decode_refuses_what_validate_refuses(msg, match):
    """decode checks in one pass what validate() checks: forged frames (encoded without
    validation, as a foreign publisher might send them) are refused with the same reasons."""
    with pytest.raises(DecodeError):
        msg.validate()
    with pytest.raises(DecodeError):
        msg.to_frames()  # our own publishers never send it
    frames = [b"topic"] + _frames_without_checks(msg)
    with pytest.raises(DecodeError, match=match):
        decode(frames)


def _frames_without_checks(msg) -> list:
    """``msg`` framed as a foreign publisher might frame it: the wire format, no checks at all."""
    arrays, scalars = msg._schema()
    present = [(name, getattr(msg, name)) for name, _ in arrays if getattr(msg, name) is not None]
    header = {"type": msg.TYPE, "v": 1, "f": {name: getattr(msg, name) for name, _ in scalars},
              "a": [[name, value.dtype.str, list(value.shape)] for name, value in present]}
    return [msgpack.packb(header, use_bin_type=True)] + [value.tobytes() for _, value in present]


def test_decode_refuses_the_wrong_type_for_a_topic():
    frames = [bytes(f) for f in encode(EXAMPLES[0], "camera/image")]
    with pytest.raises(DecodeError, match="Image where InputEvent"):
        decode(frames, InputEvent)


def test_summary_reports_shapes_and_ranges():
    s = summarize(EXAMPLES[0])
    assert s["image"]["shape"] == [48, 64, 3] and s["image"]["dtype"] == "uint8"
    assert s["image"]["max"] == float(EXAMPLES[0].image.max())


def test_params_are_typed_by_their_defaults():
    assert coerce_param("p", "3", 1.0) == 3.0 and isinstance(coerce_param("p", "3", 1.0), float)
    assert coerce_param("p", "true", False) is True
    assert coerce_param("p", "[1, 2]", []) == [1, 2]
    assert coerce_param("p", 7, "x") == "7"
    with pytest.raises(ValueError, match="expected int"):
        coerce_param("p", "2.5", 1)
    with pytest.raises(ValueError, match="true/false"):
        coerce_param("p", "maybe", False)
    assert parse_assignments(["a=1", "b=x=y"]) == {"a": "1", "b": "x=y"}
    with pytest.raises(ValueError, match="name=value"):
        parse_assignments(["oops"])
