"""The TFLite reader and the TFLite->ONNX converter against ai-edge-litert running the
original .tflite networks, on real face crops from the shared photos and videos."""

from __future__ import annotations

import zipfile

import cv2
import numpy as np
import onnx
import pytest
from detector_checks import reader_matches_litert

from facesculpt.app.setup_models import DOWNLOADS_DIR, WHEEL_NAME
from facesculpt.networks import LiteRtNetwork, OnnxNetwork
from facesculpt.nodes.landmarks.detector import (
    DETECTOR_SIZE,
    MESH_SIZE,
    LandmarkDetector,
    crop_image,
)
from facesculpt.nodes.landmarks.tflite_reader import TfliteFormatError, read_tflite
from facesculpt.nodes.landmarks.tflite_to_onnx import UnsupportedOperatorError, convert_tflite

Interpreter = pytest.importorskip("ai_edge_litert.interpreter").Interpreter


def _video_frames(path, step):
    cap = cv2.VideoCapture(str(path))
    frames, i = [], 0
    while True:
        ok, frame = cap.read()
        if not ok:
            return frames
        if i % step == 0:
            frames.append(frame)
        i += 1


@pytest.fixture(scope="module")
def crops(models_dir, data_dir):
    """Detector inputs (letterboxed frames) and mesh inputs (face crops found by the detector)
    from every shared photo and a few frames of every shared video."""
    images = [cv2.imread(str(p)) for p in sorted((data_dir / "faces").glob("*.jpg"))]
    for video in sorted((data_dir / "video").glob("*.mp4")):
        images.extend(_video_frames(video, 40))
    detector = LandmarkDetector(models_dir, max_faces=4, min_face=0.1)
    det_inputs, mesh_inputs = [], []
    for image in images:
        rgb = cv2.cvtColor(image, cv2.COLOR_BGR2RGB)
        h, w = rgb.shape[:2]
        side = max(h, w)
        box = crop_image(rgb, np.array([w / 2, h / 2, side, side, 0.0]), DETECTOR_SIZE, cv2.BORDER_CONSTANT)
        det_inputs.append(box.astype(np.float32) / 127.5 - 1.0)
        for face in detector.detect(image):
            roi = face.roi.astype(np.float64)
            roi[:2] += 0.5  # back to the continuous coordinates crops use
            mesh_inputs.append(crop_image(rgb, roi, MESH_SIZE).astype(np.float32) / 255.0)
    assert len(det_inputs) >= 20 and len(mesh_inputs) >= 20
    return np.stack(det_inputs), np.stack(mesh_inputs)


def test_reader_sees_the_tensors_and_operators_litert_sees(models_dir):
    for name in ("face_detector", "face_landmark"):
        assert reader_matches_litert(models_dir / f"{name}.tflite", Interpreter)


def test_reader_refuses_bytes_that_are_not_tflite():
    with pytest.raises(TfliteFormatError):
        read_tflite(b"\x00" * 64)
    with pytest.raises(TfliteFormatError):
        read_tflite(b"")


def _compare(models_dir, name, inputs):
    onnx_net = OnnxNetwork(models_dir / f"{name}.onnx")
    tflite_net = LiteRtNetwork(models_dir / f"{name}.tflite")
    for x in inputs:
        ours, ref = onnx_net.run(x[None]), tflite_net.run(x[None])
        assert [o.shape for o in ours] == [r.shape for r in ref]
        yield ours, ref


@pytest.mark.slow
def test_face_mesh_network_matches_tflite_on_face_crops(models_dir, crops):
    worst_points, worst_score = 0.0, 0.0
    for (points, flag), (ref_points, ref_flag) in _compare(models_dir, "face_landmark", crops[1]):
        worst_points = max(worst_points, float(np.abs(points - ref_points).max()) / MESH_SIZE)
        score = 1 / (1 + np.exp(-flag.astype(np.float64)))
        ref_score = 1 / (1 + np.exp(-ref_flag.astype(np.float64)))
        worst_score = max(worst_score, float(np.abs(score - ref_score).max()))
        assert ref_score.min() > 0.5  # these really are faces
    print(f"face mesh: max |points| diff {worst_points:.2e} of the crop, max |score| diff {worst_score:.2e}")
    assert worst_points <= 1e-3
    assert worst_score <= 1e-3


@pytest.mark.slow
def test_face_detector_network_matches_tflite_on_frames(models_dir, crops):
    worst_box, worst_score = 0.0, 0.0
    for (boxes, logits), (ref_boxes, ref_logits) in _compare(models_dir, "face_detector", crops[0]):
        worst_box = max(worst_box, float(np.abs(boxes - ref_boxes).max()) / DETECTOR_SIZE)
        score = 1 / (1 + np.exp(-np.clip(logits.astype(np.float64), -100, 100)))
        ref_score = 1 / (1 + np.exp(-np.clip(ref_logits.astype(np.float64), -100, 100)))
        worst_score = max(worst_score, float(np.abs(score - ref_score).max()))
    print(f"detector: max |box| diff {worst_box:.2e} of the input, max |score| diff {worst_score:.2e}")
    assert worst_box <= 1e-3
    assert worst_score <= 1e-3


def test_converted_graph_keeps_nhwc_interface_and_has_no_float16(models_dir):
    for name, shape in (("face_detector", [1, 128, 128, 3]), ("face_landmark", [1, 192, 192, 3])):
        model = onnx.load(str(models_dir / f"{name}.onnx"))
        dims = [d.dim_value for d in model.graph.input[0].type.tensor_type.shape.dim]
        assert dims == shape
        assert all(init.data_type == onnx.TensorProto.FLOAT or init.data_type == onnx.TensorProto.INT64
                   for init in model.graph.initializer)
        # Two layout changes at most per graph output and one at the input: NCHW inside.
        transposes = sum(node.op_type == "Transpose" for node in model.graph.node)
        assert transposes <= 1 + 2 * len(model.graph.output)


def test_unsupported_operator_is_an_error_naming_it(models_dir):
    wheel = models_dir / DOWNLOADS_DIR / WHEEL_NAME
    if not wheel.is_file():
        pytest.skip("the mediapipe wheel kept by `facesculpt setup` is not there")
    with zipfile.ZipFile(wheel) as zf:
        data = zf.read("mediapipe/modules/face_landmark/face_landmark_with_attention.tflite")
    with pytest.raises(UnsupportedOperatorError, match="TFLite operator Landmarks2TransformMatrix is not supported"):
        convert_tflite(data)
