"""A converted network run on one input: onnxruntime (what the nodes use) and LiteRT (the original
.tflite, the reference that tests and benchmarks compare against).

The face, hand and person networks of ``facesculpt setup`` are all run so: one session per
network, on a given number of threads, inputs (1, H, W, 3) float32, the outputs in the TFLite
model's order.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from facesculpt.paths import MissingModelsError, model_home


class OnnxNetwork:
    """OnnxNetwork(path, threads=1): the converted network at ``path`` (.onnx) on onnxruntime's
    CPU provider, ``threads`` intra-op threads (0: onnxruntime's default), operators run one
    after another. ``run(x)`` with x (1, H, W, 3) float32 returns the outputs as a list."""

    def __init__(self, path: str | Path, threads: int = 1):
        import onnxruntime as ort

        options = ort.SessionOptions()
        options.intra_op_num_threads = max(int(threads), 0)
        options.inter_op_num_threads = 1
        options.execution_mode = ort.ExecutionMode.ORT_SEQUENTIAL
        options.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
        self.session = ort.InferenceSession(str(path), options, providers=["CPUExecutionProvider"])
        self.input_name = self.session.get_inputs()[0].name

    def run(self, x: np.ndarray) -> list[np.ndarray]:
        return self.session.run(None, {self.input_name: x})


class LiteRtNetwork:
    """LiteRtNetwork(path, threads=1): the original .tflite network on ai-edge-litert (at least
    one thread), with the same ``run(x)`` as :class:`OnnxNetwork`."""

    def __init__(self, path: str | Path, threads: int = 1):
        from ai_edge_litert.interpreter import Interpreter

        self.interpreter = Interpreter(model_path=str(path), num_threads=max(int(threads), 1))
        self.interpreter.allocate_tensors()
        self.input_index = self.interpreter.get_input_details()[0]["index"]
        self.output_indices = [d["index"] for d in self.interpreter.get_output_details()]

    def run(self, x: np.ndarray) -> list[np.ndarray]:
        self.interpreter.set_tensor(self.input_index, x)
        self.interpreter.invoke()
        return [self.interpreter.get_tensor(i).copy() for i in self.output_indices]


def load_networks(models_dir, files: tuple[str, ...], backend: str = "onnxruntime", threads: int = 1,
                  what: str = "face") -> list:
    """The networks ``files`` (names ending .onnx) of ``models_dir`` (None or "": :func:`model_home`)
    on ``backend``: "onnxruntime" (:class:`OnnxNetwork`) or "litert" (:class:`LiteRtNetwork` on
    the .tflite of the same name). A missing file raises :class:`MissingModelsError` naming
    `facesculpt setup` and ``what`` networks it fetches; an unknown backend ValueError."""
    home = Path(models_dir) if models_dir else model_home()
    ext = {"onnxruntime": ".onnx", "litert": ".tflite"}.get(backend)
    if ext is None:
        raise ValueError(f"unknown backend {backend!r} (onnxruntime or litert)")
    paths = [home / name.replace(".onnx", ext) for name in files]
    for path in paths:
        if not path.is_file():
            raise MissingModelsError(
                f"{path} is missing: run `facesculpt setup` to fetch and convert the {what} networks "
                f"(or point FACESCULPT_HOME / models_dir at the directory where it put them)")
    network = OnnxNetwork if backend == "onnxruntime" else LiteRtNetwork
    return [network(p, threads) for p in paths]
