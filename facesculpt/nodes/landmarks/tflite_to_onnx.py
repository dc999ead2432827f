"""The project's own TFLite -> ONNX converter, for the operators of mediapipe's face, hand and selfie
segmentation networks.

Layout: TFLite is NHWC, ONNX convolutions are NCHW. The converted graph keeps the TFLite
model's NHWC inputs and outputs (so the same arrays feed both runtimes) and runs NCHW
inside: a 4-D activation is transposed to NCHW once where it enters the convolutional part
and back to NHWC only where an operator needs TFLite's layout (RESHAPE, the graph outputs).
Each converted value remembers its layout; transposes are made on demand and cached.

Constants: DEQUANTIZE of a constant float16 tensor (how mediapipe stores weights) is folded
into a float32 initializer, exactly; weights are permuted to ONNX layouts at conversion.

Supported operators (those of the face networks and of the palm detector and hand landmark
networks): DEQUANTIZE (float16 constants), CONV_2D, DEPTHWISE_CONV_2D (any depth multiplier),
PRELU, ADD, MUL, MAX_POOL_2D, AVERAGE_POOL_2D, PAD, RELU, RELU6, HARD_SWISH, LOGISTIC, TANH,
RESHAPE, CONCATENATION, MEAN, FULLY_CONNECTED (constant weights), RESIZE_BILINEAR (constant size;
the three sampling rules), and mediapipe's custom Convolution2DTransposeBias (the selfie
segmentation's last layer). Anything else raises :class:`UnsupportedOperatorError` naming it.
SAME padding is computed explicitly from the static shapes (TensorFlow's rule: the extra
pixel goes after), fused activations become separate ONNX nodes.

Two lowerings keep onnxruntime inside its fast blocked-layout (NCHWc) convolution kernels:
a per-channel PRELU becomes ``x + (1 - a) * relu(-x)`` with 1x1 depthwise convolutions, and a
PAD that only appends whole blocks of 16 zero channels becomes a 1x1 convolution with identity
weights. Both are exact up to float rounding.
"""

from __future__ import annotations

import struct

import numpy as np
import onnx
from onnx import TensorProto, helper, numpy_helper

from .tflite_reader import ACTIVATION_NAMES, TfliteGraph, read_tflite

CONVERTER_VERSION = "3"
OPSET = 13
NHWC_TO_NCHW = (0, 3, 1, 2)
NCHW_TO_NHWC = (0, 2, 3, 1)

_ONNX_TYPES = {
    np.dtype(np.float32): TensorProto.FLOAT,
    np.dtype(np.int32): TensorProto.INT32,
    np.dtype(np.int64): TensorProto.INT64,
}


class UnsupportedOperatorError(ValueError):
    """The TFLite graph uses an operator (or a variant of one) this converter does not handle."""


def _same_pads(in_size: int, kernel: int, stride: int, dilation: int) -> tuple[int, int]:
    """TensorFlow SAME padding along one axis: (before, after) in pixels."""
    out = -(-in_size // stride)
    total = max((out - 1) * stride + (kernel - 1) * dilation + 1 - in_size, 0)
    return total // 2, total - total // 2


class _Converter:
    def __init__(self, graph: TfliteGraph):
        self.g = graph
        self.nodes: list[onnx.NodeProto] = []
        self.initializers: list[onnx.TensorProto] = []
        self.consts: dict[int, np.ndarray] = {t.index: t.data for t in graph.tensors if t.data is not None}
        self.values: dict[int, tuple[str, str]] = {}  # tensor index -> (onnx name, "nchw" | "plain")
        self.transposed: dict[tuple[str, str], str] = {}
        self.counter = 0

    # ---- helpers ---------------------------------------------------------------------------
    def fresh(self, stem: str) -> str:
        self.counter += 1
        return f"{stem}__{self.counter}"

    def add_const(self, array: np.ndarray, stem: str) -> str:
        name = self.fresh(stem)
        self.initializers.append(numpy_helper.from_array(np.ascontiguousarray(array), name))
        return name

    def node(self, op: str, inputs: list[str], stem: str, **attrs) -> str:
        out = self.fresh(stem)
        self.nodes.append(helper.make_node(op, inputs, [out], name=out, **attrs))
        return out

    def rank(self, index: int) -> int:
        return len(self.g.tensors[index].shape)

    def value(self, index: int, layout: str) -> str:
        """ONNX name of TFLite tensor ``index`` in ``layout`` ("nchw" or "plain" = TFLite's)."""
        if index in self.consts and index not in self.values:
            arr = self.consts[index]
            if arr.dtype == np.float16:
                raise UnsupportedOperatorError(
                    f"float16 tensor {self.g.tensors[index].name!r} used without DEQUANTIZE")
            if layout == "nchw" and arr.ndim == 4:
                arr = arr.transpose(NHWC_TO_NCHW)
            return self.add_const(arr, "const")
        name, have = self.values[index]
        if have == layout or self.rank(index) != 4:
            return name
        key = (name, layout)
        if key not in self.transposed:
            perm = NHWC_TO_NCHW if layout == "nchw" else NCHW_TO_NHWC
            self.transposed[key] = self.node("Transpose", [name], "transpose", perm=list(perm))
        return self.transposed[key]

    def const(self, index: int, what: str) -> np.ndarray:
        if index not in self.consts:
            raise UnsupportedOperatorError(f"{what} must be a constant tensor")
        return self.consts[index]

    def activation(self, name: str, code: int, stem: str) -> str:
        act = ACTIVATION_NAMES.get(code, f"activation {code}")
        if act == "NONE":
            return name
        if act == "RELU":
            return self.node("Relu", [name], stem + "_relu")
        if act == "RELU6":
            return self.clip(name, 0.0, 6.0, stem)
        if act == "RELU_N1_TO_1":
            return self.clip(name, -1.0, 1.0, stem)
        # TANH and SIGN_BIT exist in the schema but TFLite's kernels do not apply them as fused
        # activations, so there is no reference behaviour to reproduce.
        raise UnsupportedOperatorError(f"fused activation {act} is not supported")

    def clip(self, name: str, lo: float, hi: float, stem: str) -> str:
        lo_name = self.add_const(np.array(lo, np.float32), "clip_min")
        hi_name = self.add_const(np.array(hi, np.float32), "clip_max")
        return self.node("Clip", [name, lo_name, hi_name], stem + "_clip")

    def set(self, index: int, name: str, layout: str) -> None:
        self.values[index] = (name, layout)

    def spatial_pads(self, x_shape, kernel_hw, strides_hw, dilations_hw, padding: int) -> list[int]:
        if padding == 1:  # VALID
            return [0, 0, 0, 0]
        (ph0, ph1) = _same_pads(x_shape[1], kernel_hw[0], strides_hw[0], dilations_hw[0])
        (pw0, pw1) = _same_pads(x_shape[2], kernel_hw[1], strides_hw[1], dilations_hw[1])
        return [ph0, pw0, ph1, pw1]

    # ---- operators -------------------------------------------------------------------------
    def op_DEQUANTIZE(self, op):
        src = op.inputs[0]
        if src not in self.consts:
            raise UnsupportedOperatorError("DEQUANTIZE of a non-constant tensor is not supported")
        arr = self.consts[src]
        if arr.dtype != np.float16:
            raise UnsupportedOperatorError(f"DEQUANTIZE of {arr.dtype} data is not supported (only float16)")
        self.consts[op.outputs[0]] = arr.astype(np.float32)

    def _conv(self, op, depthwise: bool):
        o = op.options
        x_idx, w_idx = op.inputs[0], op.inputs[1]
        x_shape = self.g.tensors[x_idx].shape
        if len(x_shape) != 4:
            raise UnsupportedOperatorError(f"{op.name} on a {len(x_shape)}-D input")
        w = self.const(w_idx, f"{op.name} weights").astype(np.float32)
        kh, kw = w.shape[1], w.shape[2]
        if depthwise:
            # TFLite (1, kh, kw, C*M), output channel c*M + m; ONNX grouped conv, group = C.
            channels = x_shape[3]
            w_onnx = w.transpose(3, 0, 1, 2)  # (C*M, 1, kh, kw)
            group = channels
            mult = o.get("depth_multiplier", 0) or w.shape[3] // channels
            if w.shape[3] != channels * mult:
                raise UnsupportedOperatorError(
                    f"DEPTHWISE_CONV_2D weights {w.shape} do not match {channels} channels x {mult}")
        else:
            w_onnx = w.transpose(0, 3, 1, 2)  # (O, kh, kw, I) -> (O, I, kh, kw)
            group = 1
        strides = [o["stride_h"], o["stride_w"]]
        dil = [o["dilation_h_factor"], o["dilation_w_factor"]]
        pads = self.spatial_pads(x_shape, (kh, kw), strides, dil, o["padding"])
        inputs = [self.value(x_idx, "nchw"), self.add_const(w_onnx, "weight")]
        if len(op.inputs) > 2 and op.inputs[2] >= 0:
            inputs.append(self.add_const(self.const(op.inputs[2], "bias").astype(np.float32), "bias"))
        out = self.node("Conv", inputs, "conv", kernel_shape=[kh, kw], strides=strides,
                        dilations=dil, pads=pads, group=group)
        self.set(op.outputs[0], self.activation(out, o["fused_activation_function"], "conv"), "nchw")

    def op_CONV_2D(self, op):
        self._conv(op, depthwise=False)

    def op_DEPTHWISE_CONV_2D(self, op):
        self._conv(op, depthwise=True)

    def _pool(self, op, onnx_op: str):
        o = op.options
        x_shape = self.g.tensors[op.inputs[0]].shape
        kernel = [o["filter_height"], o["filter_width"]]
        strides = [o["stride_h"], o["stride_w"]]
        pads = self.spatial_pads(x_shape, kernel, strides, (1, 1), o["padding"])
        attrs = dict(kernel_shape=kernel, strides=strides, pads=pads)
        if onnx_op == "AveragePool":
            attrs["count_include_pad"] = 0  # TFLite averages over the valid pixels only
        out = self.node(onnx_op, [self.value(op.inputs[0], "nchw")], onnx_op.lower(), **attrs)
        self.set(op.outputs[0], self.activation(out, o["fused_activation_function"], "pool"), "nchw")

    def op_MAX_POOL_2D(self, op):
        self._pool(op, "MaxPool")

    def op_AVERAGE_POOL_2D(self, op):
        self._pool(op, "AveragePool")

    def _binary_layout(self, op) -> str:
        # Run in NCHW when every 4-D operand is (or can be) NCHW and the result is 4-D.
        # Constant operands are re-laid out at conversion, so only computed ones matter.
        return "nchw" if self.rank(op.outputs[0]) == 4 and all(
            self.rank(i) in (0, 4) for i in op.inputs if i not in self.consts) else "plain"

    def _broadcast_const(self, index: int, layout: str) -> str:
        arr = self.consts[index].astype(np.float32)
        if layout == "nchw":
            arr = arr.reshape((1,) * (4 - arr.ndim) + arr.shape).transpose(NHWC_TO_NCHW)
        return self.add_const(arr, "operand")

    def _binary(self, op, onnx_op: str):
        layout = self._binary_layout(op)
        names = [self._broadcast_const(i, layout) if i in self.consts and i not in self.values
                 else self.value(i, layout) for i in op.inputs]
        out = self.node(onnx_op, names, onnx_op.lower())
        self.set(op.outputs[0], self.activation(out, op.options["fused_activation_function"], onnx_op.lower()),
                 layout)

    def op_ADD(self, op):
        self._binary(op, "Add")

    def op_MUL(self, op):
        self._binary(op, "Mul")

    def op_PRELU(self, op):
        layout = self._binary_layout(op)
        x = self.value(op.inputs[0], layout)
        alpha_idx = op.inputs[1]
        if layout == "nchw" and alpha_idx in self.consts and self.consts[alpha_idx].size == self.g.tensors[
                op.inputs[0]].shape[3]:
            # Per-channel slope a: PRelu(x) = x + (1 - a) * relu(-x), written as two 1x1 depthwise
            # convolutions (the first with a fused Relu, the second with a fused sum). onnxruntime's
            # own PRelu is a slow generic broadcast outside its blocked NCHWc kernels; this form
            # keeps the whole network inside them (benchmarks/bench_landmarks.py times the result).
            a = self.consts[alpha_idx].astype(np.float32).reshape(-1, 1, 1, 1)
            channels = a.shape[0]
            neg = self.node("Conv", [x, self.add_const(-np.ones_like(a), "minus_one")], "prelu_neg",
                            kernel_shape=[1, 1], group=channels)
            neg = self.node("Relu", [neg], "prelu_relu")
            scaled = self.node("Conv", [neg, self.add_const(1.0 - a, "one_minus_slope")], "prelu_scale",
                               kernel_shape=[1, 1], group=channels)
            self.set(op.outputs[0], self.node("Add", [scaled, x], "prelu"), layout)
            return
        alpha = self._broadcast_const(alpha_idx, layout) if alpha_idx in self.consts \
            else self.value(alpha_idx, layout)
        self.set(op.outputs[0], self.node("PRelu", [x, alpha], "prelu"), layout)

    def op_PAD(self, op):
        paddings = self.const(op.inputs[1], "PAD paddings").astype(np.int64)  # (rank, 2), TFLite axes
        layout = "nchw" if paddings.shape[0] == 4 else "plain"
        c_in = self.g.tensors[op.inputs[0]].shape[-1]
        before, after = int(paddings[-1, 0]), int(paddings[-1, 1])
        if layout == "nchw" and not paddings[:3].any() and c_in % 16 == 0 and (before + after) % 16 == 0:
            # Zero channels appended/prepended (how these networks widen a residual shortcut): a 1x1
            # convolution with identity weights, so onnxruntime stays in its blocked NCHWc layout
            # instead of reordering around a Pad node. Only worth it when the channel counts are
            # whole NCHWc blocks (16); otherwise the extra multiply-adds cost more than the reorder.
            weight = np.zeros((before + c_in + after, c_in, 1, 1), np.float32)
            weight[before + np.arange(c_in), np.arange(c_in)] = 1.0
            out = self.node("Conv", [self.value(op.inputs[0], "nchw"), self.add_const(weight, "channel_pad")],
                            "pad_channels", kernel_shape=[1, 1])
            self.set(op.outputs[0], out, "nchw")
            return
        if layout == "nchw":
            paddings = paddings[list(NHWC_TO_NCHW)]
        pads = np.concatenate([paddings[:, 0], paddings[:, 1]])
        out = self.node("Pad", [self.value(op.inputs[0], layout), self.add_const(pads, "pads")], "pad",
                        mode="constant")
        self.set(op.outputs[0], out, layout)

    def _unary(self, op, onnx_op: str):
        index = op.inputs[0]
        layout = self.values[index][1] if index in self.values else "plain"
        self.set(op.outputs[0], self.node(onnx_op, [self.value(index, layout)], onnx_op.lower()), layout)

    def op_RELU(self, op):
        self._unary(op, "Relu")

    def op_LOGISTIC(self, op):
        self._unary(op, "Sigmoid")

    def op_TANH(self, op):
        self._unary(op, "Tanh")

    def op_HARD_SWISH(self, op):
        # x * relu6(x + 3) / 6, as x * HardSigmoid(x) (ONNX's HardSwish needs opset 14)
        index = op.inputs[0]
        layout = self.values[index][1] if index in self.values else "plain"
        x = self.value(index, layout)
        gate = self.node("HardSigmoid", [x], "hard_swish_gate", alpha=1.0 / 6.0, beta=0.5)
        self.set(op.outputs[0], self.node("Mul", [x, gate], "hard_swish"), layout)

    def custom_Convolution2DTransposeBias(self, op):
        # mediapipe's transposed convolution; options: padding (1 SAME, 2 VALID), stride w, stride h
        # (three int32); weights (O, kh, kw, I), bias (O,).
        if len(op.custom_options) < 12:
            raise UnsupportedOperatorError("Convolution2DTransposeBias without its padding and strides")
        padding, stride_w, stride_h = struct.unpack_from("<3i", op.custom_options)
        x_shape = self.g.tensors[op.inputs[0]].shape
        out_shape = self.g.tensors[op.outputs[0]].shape
        w = self.const(op.inputs[1], "Convolution2DTransposeBias weights").astype(np.float32)
        kh, kw = w.shape[1], w.shape[2]
        pads = []
        for size, out, k, stride in ((x_shape[1], out_shape[1], kh, stride_h), (x_shape[2], out_shape[2], kw, stride_w)):
            total = (size - 1) * stride + k - out   # what the full transposed convolution has beyond the output
            if total < 0 or (padding == 2 and total):
                raise UnsupportedOperatorError(f"Convolution2DTransposeBias: {size} -> {out} px with kernel {k}, "
                                               f"stride {stride}")
            pads.append((total // 2, total - total // 2))
        inputs = [self.value(op.inputs[0], "nchw"), self.add_const(w.transpose(3, 0, 1, 2), "weight"),
                  self.add_const(self.const(op.inputs[2], "bias").astype(np.float32), "bias")]
        out = self.node("ConvTranspose", inputs, "conv_transpose", kernel_shape=[kh, kw], strides=[stride_h, stride_w],
                        pads=[pads[0][0], pads[1][0], pads[0][1], pads[1][1]])
        self.set(op.outputs[0], out, "nchw")

    def op_RELU6(self, op):
        index = op.inputs[0]
        layout = self.values[index][1] if index in self.values else "plain"
        self.set(op.outputs[0], self.clip(self.value(index, layout), 0.0, 6.0, "relu6"), layout)

    def op_RESHAPE(self, op):
        shape = np.array(self.g.tensors[op.outputs[0]].shape, np.int64)  # static, from the model
        out = self.node("Reshape", [self.value(op.inputs[0], "plain"), self.add_const(shape, "shape")],
                        "reshape")
        self.set(op.outputs[0], out, "plain")

    def op_CONCATENATION(self, op):
        axis = op.options["axis"]
        rank = self.rank(op.outputs[0])
        axis = axis + rank if axis < 0 else axis
        layout = "plain"
        if rank == 4 and all(self.values.get(i, ("", "plain"))[1] == "nchw" for i in op.inputs):
            layout = "nchw"
            axis = NHWC_TO_NCHW.index(axis)
        out = self.node("Concat", [self.value(i, layout) for i in op.inputs], "concat", axis=axis)
        self.set(op.outputs[0], self.activation(out, op.options["fused_activation_function"], "concat"), layout)

    def op_MEAN(self, op):
        axes = sorted(int(a) % self.rank(op.inputs[0]) for a in
                      np.atleast_1d(self.const(op.inputs[1], "MEAN axes")))
        keep = bool(op.options.get("keep_dims", 0))
        index = op.inputs[0]
        if self.rank(index) == 4 and axes == [1, 2]:
            # The spatial mean (global average pooling) runs in NCHW, in onnxruntime's blocked kernels.
            out = self.node("GlobalAveragePool", [self.value(index, "nchw")], "mean")
            if keep:
                self.set(op.outputs[0], out, "nchw")
                return
            shape = np.array(self.g.tensors[op.outputs[0]].shape, np.int64)
            self.set(op.outputs[0], self.node("Reshape", [out, self.add_const(shape, "shape")], "mean_flat"),
                     "plain")
            return
        out = self.node("ReduceMean", [self.value(index, "plain")], "mean", axes=axes, keepdims=int(keep))
        self.set(op.outputs[0], out, "plain")

    def op_FULLY_CONNECTED(self, op):
        o = op.options
        if o.get("weights_format", 0) != 0:
            raise UnsupportedOperatorError("FULLY_CONNECTED with shuffled weights is not supported")
        w = self.const(op.inputs[1], "FULLY_CONNECTED weights").astype(np.float32)  # (O, I)
        x = self.value(op.inputs[0], "plain")
        if self.rank(op.inputs[0]) != 2:  # TFLite flattens every leading axis into the batch
            x = self.node("Reshape", [x, self.add_const(np.array([-1, w.shape[1]], np.int64), "shape")], "fc_in")
        inputs = [x, self.add_const(w, "weight")]
        if len(op.inputs) > 2 and op.inputs[2] >= 0:
            inputs.append(self.add_const(self.const(op.inputs[2], "bias").astype(np.float32), "bias"))
        out = self.node("Gemm", inputs, "fc", transB=1)
        out_shape = self.g.tensors[op.outputs[0]].shape
        if len(out_shape) != 2:
            out = self.node("Reshape", [out, self.add_const(np.array(out_shape, np.int64), "shape")], "fc_out")
        self.set(op.outputs[0], self.activation(out, o["fused_activation_function"], "fc"), "plain")

    def op_RESIZE_BILINEAR(self, op):
        o = op.options
        if self.rank(op.inputs[0]) != 4:
            raise UnsupportedOperatorError("RESIZE_BILINEAR of a tensor that is not 4-D")
        height, width = (int(v) for v in self.const(op.inputs[1], "RESIZE_BILINEAR size"))
        channels = self.g.tensors[op.inputs[0]].shape[3]
        # TFLite's three sampling rules are ONNX's coordinate transformation modes (the
        # half-pixel rule clamps the source coordinate to the image, as onnxruntime does).
        mode = ("align_corners" if o.get("align_corners") else
                "half_pixel" if o.get("half_pixel_centers") else "asymmetric")
        sizes = self.add_const(np.array([1, channels, height, width], np.int64), "sizes")
        out = self.node("Resize", [self.value(op.inputs[0], "nchw"), "", "", sizes], "resize",
                        mode="linear", coordinate_transformation_mode=mode)
        self.set(op.outputs[0], out, "nchw")

    # ---- driver ----------------------------------------------------------------------------
    def convert(self, name: str) -> onnx.ModelProto:
        g = self.g
        inputs = []
        for index in g.inputs:
            t = g.tensors[index]
            if t.dtype != np.float32:
                raise UnsupportedOperatorError(f"graph input {t.name!r} has type {t.dtype} (only float32)")
            inputs.append(helper.make_tensor_value_info(t.name, TensorProto.FLOAT, list(t.shape)))
            self.set(index, t.name, "plain")
        for op in g.operators:
            handler = getattr(self, f"custom_{op.name}" if op.custom else f"op_{op.name}", None)
            if handler is None:
                raise UnsupportedOperatorError(f"TFLite operator {op.name} is not supported by the converter")
            handler(op)
        outputs = []
        for index in g.outputs:
            t = g.tensors[index]
            if index not in self.values:
                raise UnsupportedOperatorError(f"graph output {t.name!r} is not computed by any operator")
            self.nodes.append(helper.make_node("Identity", [self.value(index, "plain")], [t.name], name=t.name))
            outputs.append(helper.make_tensor_value_info(t.name, _ONNX_TYPES.get(t.dtype, TensorProto.FLOAT),
                                                         list(t.shape)))
        graph = helper.make_graph(self.nodes, name, inputs, outputs, self.initializers)
        model = helper.make_model(graph, producer_name="facesculpt.tflite_to_onnx",
                                  producer_version=CONVERTER_VERSION,
                                  opset_imports=[helper.make_opsetid("", OPSET)])
        model.ir_version = 8  # readable by every onnxruntime >= 1.14
        onnx.checker.check_model(model)
        return model


def convert_tflite(data: bytes | TfliteGraph, name: str = "converted") -> onnx.ModelProto:
    """Convert a TFLite model (file bytes or a parsed graph) to an ONNX model.

    The ONNX model has the TFLite model's input and output names, shapes and NHWC layout.
    Raises :class:`UnsupportedOperatorError` naming the first operator it cannot convert.
    """
    graph = data if isinstance(data, TfliteGraph) else read_tflite(data)
    return _Converter(graph).convert(name)
