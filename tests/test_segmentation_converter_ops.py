"""Converter operators the selfie (person) segmentation brought: MUL with a per-channel computed
operand (its squeeze-and-excitation blocks), HARD_SWISH, and mediapipe's custom
Convolution2DTransposeBias, on small random TFLite models written with LiteRT's own schema
bindings and run by LiteRT as the reference. LiteRT cannot run the custom operator, so its
reference is the same model with the builtin TRANSPOSE_CONV followed by the bias ADD."""

from __future__ import annotations

import struct

import numpy as np
import pytest
from test_landmarks_converter_ops import OP, OPT, _ModelWriter, _options, assert_matches_litert, schema

from facesculpt.nodes.landmarks.tflite_reader import read_tflite

Interpreter = pytest.importorskip("ai_edge_litert.interpreter").Interpreter

CUSTOM_TRANSPOSE = "Convolution2DTransposeBias"


class _CustomModelWriter(_ModelWriter):
    """A :class:`_ModelWriter` that also writes custom operators (code CUSTOM with a name)."""

    def custom(self, name: str, inputs, outputs, options: bytes) -> None:
        key = ("custom", name)
        if key not in self.codes:
            self.codes.append(key)
        o = schema.OperatorT()
        o.opcodeIndex, o.inputs, o.outputs = self.codes.index(key), list(inputs), list(outputs)
        o.customOptions = list(options)
        self.operators.append(o)

    def finish(self, inputs, outputs) -> bytes:
        customs = {i: c for i, c in enumerate(self.codes) if isinstance(c, tuple)}
        self.codes = [OP.CUSTOM if isinstance(c, tuple) else c for c in self.codes]
        data = super().finish(inputs, outputs)
        if not customs:
            return data
        model = schema.ModelT.InitFromObj(schema.Model.GetRootAs(data, 0))
        for i, (_, name) in customs.items():
            model.operatorCodes[i].customCode = name
        import flatbuffers

        builder = flatbuffers.Builder(1024)
        builder.Finish(model.Pack(builder), file_identifier=b"TFL3")
        return bytes(builder.Output())


def _build(seed: int, custom: bool) -> bytes:
    """input (1, 6, 5, 4) -> conv 3x3 -> HARD_SWISH -> x * sigmoid(conv1x1(mean)) -> 2x2 stride-2
    transposed convolution to 3 channels with a bias."""
    m = _CustomModelWriter(np.random.default_rng(seed))
    x = m.tensor([1, 6, 5, 4], name="input")
    conv = m.tensor([1, 6, 5, 8])
    m.conv(x, conv, m.weights([8, 3, 3, 4], fp16=True), m.weights([8]))
    swish = m.tensor([1, 6, 5, 8])
    m.op(OP.HARD_SWISH, [conv], [swish])
    pooled = m.tensor([1, 1, 1, 8])
    m.op(OP.AVERAGE_POOL_2D, [swish], [pooled], OPT.Pool2DOptions,
         _options(schema.Pool2DOptionsT, padding=schema.Padding.VALID, strideW=5, strideH=6, filterWidth=5,
                  filterHeight=6))
    gate = m.tensor([1, 1, 1, 8])
    m.conv(pooled, gate, m.weights([8, 1, 1, 8]), m.weights([8]), padding=schema.Padding.VALID)
    sig = m.tensor([1, 1, 1, 8])
    m.op(OP.LOGISTIC, [gate], [sig])
    scaled = m.tensor([1, 6, 5, 8])
    m.op(OP.MUL, [swish, sig], [scaled], OPT.MulOptions, _options(schema.MulOptionsT))
    weights, bias = m.weights([3, 2, 2, 8]), m.weights([3])
    out = m.tensor([1, 12, 10, 3], name="output")
    if custom:
        m.custom(CUSTOM_TRANSPOSE, [scaled, weights, bias], [out], struct.pack("<3i", 1, 2, 2))  # SAME, 2, 2
    else:
        up = m.tensor([1, 12, 10, 3])
        shape = m.tensor([4], np.array([1, 12, 10, 3], np.int32), schema.TensorType.INT32)
        m.op(OP.TRANSPOSE_CONV, [shape, weights, scaled], [up], OPT.TransposeConvOptions,
             _options(schema.TransposeConvOptionsT, padding=schema.Padding.SAME, strideW=2, strideH=2))
        m.op(OP.ADD, [up, bias], [out], OPT.AddOptions, _options(schema.AddOptionsT))
    return m.finish([x], [out, swish])


@pytest.mark.parametrize("seed", [0, 1])
def test_the_segmentation_operators_match_litert(seed, tmp_path):
    custom, reference = _build(seed, custom=True), _build(seed, custom=False)
    graph = read_tflite(custom)
    names = [op.name for op in graph.operators]
    assert "HARD_SWISH" in names and "MUL" in names and names[-1] == CUSTOM_TRANSPOSE
    assert graph.operators[-1].custom and len(graph.operators[-1].custom_options) == 12
    for trial in range(3):
        x = np.random.default_rng(10 + trial).uniform(-4, 4, (1, 6, 5, 4)).astype(np.float32)
        swish = assert_matches_litert(reference, custom, x, tmp_path, tol=1e-4)[1]
        assert (swish < 0).any() and (swish > 3).any()  # both bends of the hard swish were compared
