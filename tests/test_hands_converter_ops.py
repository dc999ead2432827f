"""Converter operators the hand networks brought (MEAN, FULLY_CONNECTED, RESIZE_BILINEAR with
its three sampling rules), on small random TFLite models written with LiteRT's own schema
bindings and run by LiteRT as the reference; and an operator outside the list stays an error
naming it."""

from __future__ import annotations

import numpy as np
import pytest
from test_landmarks_converter_ops import OP, OPT, TT, _ModelWriter, _options, assert_matches_litert, schema

from facesculpt.nodes.landmarks.tflite_to_onnx import UnsupportedOperatorError, convert_tflite

Interpreter = pytest.importorskip("ai_edge_litert.interpreter").Interpreter


def _build(seed: int, align_corners: bool, half_pixel: bool, keep_dims: bool) -> bytes:
    m = _ModelWriter(np.random.default_rng(seed))
    x = m.tensor([1, 5, 7, 6], name="input")
    # A convolution first, so the resize runs on an NCHW activation as in the palm detector.
    conv = m.tensor([1, 5, 7, 8])
    m.conv(x, conv, m.weights([8, 1, 1, 6], fp16=True), m.weights([8]))
    up = m.tensor([1, 11, 9, 8])
    m.op(OP.RESIZE_BILINEAR, [conv, m.tensor([2], np.array([11, 9], np.int32), TT.INT32)], [up],
         OPT.ResizeBilinearOptions, _options(schema.ResizeBilinearOptionsT, alignCorners=align_corners,
                                             halfPixelCenters=half_pixel))
    mean = m.tensor([1, 1, 1, 8] if keep_dims else [1, 8])
    m.op(OP.MEAN, [up, m.tensor([2], np.array([1, 2], np.int32), TT.INT32)], [mean], OPT.ReducerOptions,
         _options(schema.ReducerOptionsT, keepDims=keep_dims))
    fc = m.tensor([1, 5], name="fc")
    m.op(OP.FULLY_CONNECTED, [mean, m.weights([5, 8], fp16=True), m.weights([5])], [fc],
         OPT.FullyConnectedOptions, _options(schema.FullyConnectedOptionsT,
                                             fusedActivationFunction=schema.ActivationFunctionType.RELU))
    return m.finish([x], [fc, up])


@pytest.mark.parametrize("align_corners, half_pixel, keep_dims",
                         [(False, False, False), (True, False, True), (False, True, False)])
def test_small_models_match_litert(align_corners, half_pixel, keep_dims, tmp_path):
    data = _build(7, align_corners, half_pixel, keep_dims)
    positive = False
    for trial in range(6):
        x = np.random.default_rng(trial).uniform(-2, 2, (1, 5, 7, 6)).astype(np.float32)
        ours = assert_matches_litert(data, data, x, tmp_path)
        assert np.abs(ours[1]).max() > 0.1
        positive |= bool((ours[0] > 0).any())
    assert positive  # the fused RELU let something through: real values were compared


def test_an_operator_outside_the_list_is_an_error_naming_it():
    m = _ModelWriter(np.random.default_rng(0))
    x = m.tensor([1, 4], name="input")
    out = m.tensor([1, 4])
    m.op(OP.SOFTMAX, [x], [out], OPT.SoftmaxOptions, _options(schema.SoftmaxOptionsT, beta=1.0))
    with pytest.raises(UnsupportedOperatorError, match="TFLite operator SOFTMAX is not supported"):
        convert_tflite(m.finish([x], [out]))
