"""Converter operator variants the face networks do not all exercise (depth multiplier 2,
odd sizes with asymmetric SAME padding, VALID, fused activations, spatial PAD, average pooling,
PRELU, constant-broadcast ADD, 4-D concatenation, RESHAPE), on small random TFLite models
written with LiteRT's own schema bindings and run by LiteRT as the reference."""

from __future__ import annotations

import numpy as np
import onnxruntime as ort
import pytest

from facesculpt.nodes.landmarks.tflite_reader import read_tflite
from facesculpt.nodes.landmarks.tflite_to_onnx import convert_tflite

schema = pytest.importorskip("ai_edge_litert.schema_py_generated")
flatbuffers = pytest.importorskip("flatbuffers")
Interpreter = pytest.importorskip("ai_edge_litert.interpreter").Interpreter

OP, OPT, TT = schema.BuiltinOperator, schema.BuiltinOptions, schema.TensorType


class _ModelWriter:
    """Builds a one-subgraph TFLite model with the generated object API."""

    def __init__(self, rng):
        self.rng = rng
        self.tensors, self.buffers, self.operators, self.codes = [], [schema.BufferT()], [], []

    def tensor(self, shape, data=None, ttype=TT.FLOAT32, name=None):
        t = schema.TensorT()
        t.shape, t.type, t.name = list(shape), ttype, name or f"t{len(self.tensors)}"
        t.buffer = 0
        if data is not None:
            buf = schema.BufferT()
            buf.data = list(np.ascontiguousarray(data).tobytes())
            self.buffers.append(buf)
            t.buffer = len(self.buffers) - 1
        self.tensors.append(t)
        return len(self.tensors) - 1

    def weights(self, shape, scale=0.5, fp16=False):
        w = (self.rng.standard_normal(shape) * scale).astype(np.float32)
        if not fp16:
            return self.tensor(shape, w)
        half = self.tensor(shape, w.astype(np.float16), TT.FLOAT16)
        out = self.tensor(shape)
        self.op(OP.DEQUANTIZE, [half], [out])
        return out

    def op(self, code, inputs, outputs, options_type=OPT.NONE, options=None):
        if code not in self.codes:
            self.codes.append(code)
        o = schema.OperatorT()
        o.opcodeIndex, o.inputs, o.outputs = self.codes.index(code), list(inputs), list(outputs)
        o.builtinOptionsType, o.builtinOptions = options_type, options
        self.operators.append(o)

    def conv(self, x, out, weights, bias, padding=None, stride=1):
        """A CONV_2D of ``x`` into ``out`` (tensor indices), no activation, SAME padding by default."""
        self.op(OP.CONV_2D, [x, weights, bias], [out], OPT.Conv2DOptions,
                _options(schema.Conv2DOptionsT, padding=schema.Padding.SAME if padding is None else padding,
                         strideW=stride, strideH=stride, dilationWFactor=1, dilationHFactor=1))

    def finish(self, inputs, outputs) -> bytes:
        sub = schema.SubGraphT()
        sub.tensors, sub.inputs, sub.outputs, sub.operators = self.tensors, inputs, outputs, self.operators
        model = schema.ModelT()
        model.version, model.subgraphs, model.buffers, model.description = 3, [sub], self.buffers, "test"
        model.operatorCodes = []
        for code in self.codes:
            oc = schema.OperatorCodeT()
            oc.builtinCode, oc.deprecatedBuiltinCode, oc.version = code, min(code, 127), 1
            model.operatorCodes.append(oc)
        builder = flatbuffers.Builder(1024)
        builder.Finish(model.Pack(builder), file_identifier=b"TFL3")
        return bytes(builder.Output())


def _options(cls, **fields):
    o = cls()
    for k, v in fields.items():
        setattr(o, k, v)
    return o


def _build(seed: int) -> bytes:
    rng = np.random.default_rng(seed)
    m = _ModelWriter(rng)
    x = m.tensor([1, 9, 11, 3], name="input")
    # Depthwise, multiplier 2, stride 2, SAME on odd sizes (asymmetric padding), fused RELU6.
    dw = m.tensor([1, 5, 6, 6])
    m.op(OP.DEPTHWISE_CONV_2D, [x, m.weights([1, 3, 3, 6], fp16=True), m.weights([6])], [dw],
         OPT.DepthwiseConv2DOptions, _options(schema.DepthwiseConv2DOptionsT, padding=schema.Padding.SAME,
                                              strideW=2, strideH=2, depthMultiplier=2,
                                              fusedActivationFunction=schema.ActivationFunctionType.RELU6,
                                              dilationWFactor=1, dilationHFactor=1))
    # Conv VALID 2x3, fused RELU_N1_TO_1 (TFLite kernels ignore a fused TANH, so not that).
    conv = m.tensor([1, 4, 4, 4])
    m.op(OP.CONV_2D, [dw, m.weights([4, 2, 3, 6]), m.weights([4])], [conv], OPT.Conv2DOptions,
         _options(schema.Conv2DOptionsT, padding=schema.Padding.VALID, strideW=1, strideH=1,
                  fusedActivationFunction=schema.ActivationFunctionType.RELU_N1_TO_1,
                  dilationWFactor=1, dilationHFactor=1))
    # PRELU with a per-channel slope, ADD of a per-channel constant.
    pre = m.tensor([1, 4, 4, 4])
    m.op(OP.PRELU, [conv, m.weights([1, 1, 4])], [pre])
    added = m.tensor([1, 4, 4, 4])
    m.op(OP.ADD, [pre, m.weights([4])], [added], OPT.AddOptions, _options(schema.AddOptionsT))
    # Spatial PAD (not channel-only), average pool SAME 3x3 stride 2 (edge windows are partial).
    padded = m.tensor([1, 5, 7, 4])
    m.op(OP.PAD, [added, m.tensor([4, 2], np.array([[0, 0], [0, 1], [2, 1], [0, 0]], np.int32), TT.INT32)], [padded])
    pooled = m.tensor([1, 3, 4, 4])
    m.op(OP.AVERAGE_POOL_2D, [padded], [pooled], OPT.Pool2DOptions,
         _options(schema.Pool2DOptionsT, padding=schema.Padding.SAME, strideW=2, strideH=2, filterWidth=3,
                  filterHeight=3))
    maxed = m.tensor([1, 3, 4, 4])
    m.op(OP.MAX_POOL_2D, [pooled], [maxed], OPT.Pool2DOptions,
         _options(schema.Pool2DOptionsT, padding=schema.Padding.SAME, strideW=1, strideH=1, filterWidth=2,
                  filterHeight=2, fusedActivationFunction=schema.ActivationFunctionType.RELU))
    # Concatenate along channels (4-D, stays NCHW inside), then RESHAPE to TFLite's flat order.
    cat = m.tensor([1, 3, 4, 8])
    m.op(OP.CONCATENATION, [pooled, maxed], [cat], OPT.ConcatenationOptions,
         _options(schema.ConcatenationOptionsT, axis=3))
    flat = m.tensor([1, 96], name="flat")
    m.op(OP.RESHAPE, [cat], [flat], OPT.ReshapeOptions, _options(schema.ReshapeOptionsT, newShape=[1, 96]))
    return m.finish([x], [flat, dw])


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_small_models_match_litert(seed, tmp_path):
    data = _build(seed)
    graph = read_tflite(data)
    assert [op.name for op in graph.operators][:2] == ["DEQUANTIZE", "DEPTHWISE_CONV_2D"]
    assert graph.operators[1].options["depth_multiplier"] == 2
    for trial in range(3):
        x = np.random.default_rng(100 + trial).uniform(-2, 2, (1, 9, 11, 3)).astype(np.float32)
        assert_matches_litert(data, data, x, tmp_path)


def assert_matches_litert(reference: bytes, converted: bytes, x: np.ndarray, tmp_path, tol: float = 1e-5) -> list:
    """Run ``reference`` (TFLite bytes) in LiteRT and ``converted`` (TFLite bytes, converted to ONNX)
    in onnxruntime on the input ``x`` (named "input"); assert every output matches within ``tol``
    (absolute and relative); returns the ONNX outputs."""
    path = tmp_path / "model.tflite"
    path.write_bytes(reference)
    interpreter = Interpreter(model_path=str(path))
    interpreter.allocate_tensors()
    session = ort.InferenceSession(convert_tflite(converted).SerializeToString(), providers=["CPUExecutionProvider"])
    interpreter.set_tensor(interpreter.get_input_details()[0]["index"], x)
    interpreter.invoke()
    ours = session.run(None, {"input": x})
    for out, detail in zip(ours, interpreter.get_output_details()):
        ref = interpreter.get_tensor(detail["index"])
        assert out.shape == ref.shape
        np.testing.assert_allclose(out, ref, atol=tol, rtol=tol)
    return ours
