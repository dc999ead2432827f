"""Irises and eyelids: MediaPipe's iris landmark network on the two eye crops the face mesh gives.

The steps follow mediapipe's iris graph (``iris_landmark_left_and_right_cpu``), written out here:

1. **Eye crops.** Each eye's crop is a square turned along the line through its two corners of
   the face mesh (the person's right eye: points 33 -> 133, image left; the left eye: 362 ->
   263), centred between them, its side 2.3 x their distance.
2. **Network** (64x64 RGB in [0, 1]): trained on the person's right eye; the left eye's crop is
   mirrored before and the points mirrored back after. Outputs 71 eye-contour points (the first
   16 are the lids, in the face mesh's eye order: lower lid from the outer corner to the inner,
   then the upper lid) and 5 iris points (the centre, then four on the limbus), x, y in crop
   pixels and z relative depth on the same scale.
3. The points are carried back through the crop into image pixels (z scaled like x).

Eye 0 is always the person's right eye (image left in an unmirrored frame), eye 1 the left.
Coordinates: pixel indices (the centre of pixel (i, j) at (x=i, y=j)), as the face mesh's
points of :class:`~facesculpt.nodes.landmarks.detector.Face`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from facesculpt.geometry.bgr_image import as_bgr_uint8
from facesculpt.geometry.crops import crop_to_image, network_input
from facesculpt.geometry.eye_points import MESH_EYE_LIDS
from facesculpt.networks import load_networks
from facesculpt.options import option

IRIS_SIZE = 64
#: The face mesh's eye corners: (start, end) of the crop's axis, per eye (right, left).
EYE_CORNERS = ((33, 133), (362, 263))
#: The face mesh's 16 lid points per eye, in the order of the network's first 16 contour points.
EYE_CONTOUR_MESH = MESH_EYE_LIDS
EYE_SCALE = 2.3
NUM_CONTOUR = 71
NUM_LIDS = 16
NUM_IRIS = 5
_FILES = ("iris_landmark.onnx",)


@dataclass(frozen=True)
class IrisOptions:
    """Whether the irises are found (the landmarks node's ``irises``, ``process --gaze``)."""

    irises: bool = option(False, "run the iris network on each face's eyes: face/landmarks then carries irises and "
                                 "eye_lids, and the fitter publishes face/gaze (costs about two face-mesh networks "
                                 "a face)")


IRIS_OPTIONS = IrisOptions()


def eye_roi(points_xy: np.ndarray, eye: int) -> np.ndarray:
    """The crop (5,) [cx, cy, side, side, angle] (continuous pixels) of eye ``eye`` (0: right,
    1: left) from the face mesh's points (468, 2) in continuous pixels."""
    a, b = (np.asarray(points_xy[i], np.float64) for i in EYE_CORNERS[eye])
    d = b - a
    side = float(np.hypot(*d)) * EYE_SCALE
    angle = math.atan2(float(d[1]), float(d[0]))
    c = (a + b) / 2.0
    return np.array([c[0], c[1], side, side, angle])


def eye_inputs(image: np.ndarray, points_xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The network's input (2, 64, 64, 3) float32 RGB in [0, 1] for both eyes (the left one
    mirrored) and their crops (2, 5), from an (H, W, 3) uint8 BGR image and the face mesh's
    points (468, 2) in continuous pixels."""
    rois = np.stack([eye_roi(points_xy, e) for e in (0, 1)])
    x = np.concatenate([network_input(image, rois[e], IRIS_SIZE) for e in (0, 1)])
    x[1] = x[1, :, ::-1]
    return np.ascontiguousarray(x), rois


def eye_points(raw_contour: np.ndarray, raw_iris: np.ndarray, rois: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The network's outputs for both eyes, contour (2, 213) and iris (2, 15) in crop pixels ->
    (irises (2, 5, 3), lids (2, 16, 3)) float32 in image pixels (continuous)."""
    irises = np.empty((2, NUM_IRIS, 3))
    lids = np.empty((2, NUM_LIDS, 3))
    for e in (0, 1):
        contour = raw_contour[e].reshape(NUM_CONTOUR, 3)[:NUM_LIDS].astype(np.float64)
        iris = raw_iris[e].reshape(NUM_IRIS, 3).astype(np.float64)
        if e == 1:  # mirrored back
            contour[:, 0] = IRIS_SIZE - contour[:, 0]
            iris[:, 0] = IRIS_SIZE - iris[:, 0]
        lids[e] = crop_to_image(contour, rois[e], IRIS_SIZE)
        irises[e] = crop_to_image(iris, rois[e], IRIS_SIZE)
    return irises.astype(np.float32), lids.astype(np.float32)


class IrisDetector:
    """IrisDetector(models_dir="", threads=1, backend="onnxruntime"): the iris network that
    `facesculpt setup` converted (a missing file raises :class:`MissingModelsError` naming it).

    ``find(image, points)``: an (H, W, 3) uint8 BGR image and one face's mesh points (468, >=2)
    in pixel indices -> (irises (2, 5, 3), lids (2, 16, 3)) float32 in pixel indices, eye 0 the
    person's right. Both eyes run as one batch on onnxruntime.
    """

    def __init__(self, models_dir: str = "", threads: int = 1, backend: str = "onnxruntime"):
        (self.net,) = load_networks(models_dir, _FILES, backend, threads, "iris")
        self.batched = backend == "onnxruntime" and _batchable(self.net)

    def find(self, image: np.ndarray, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        image = as_bgr_uint8(image)
        xy = np.asarray(points, np.float64)[:, :2] + 0.5  # continuous pixels
        x, rois = eye_inputs(image, xy)
        if self.batched:
            contour, iris = self.net.run(x)
        else:
            outs = [self.net.run(x[e:e + 1]) for e in (0, 1)]
            contour, iris = (np.concatenate([o[k] for o in outs]) for k in (0, 1))
        irises, lids = eye_points(contour, iris, rois)
        irises[..., :2] -= 0.5
        lids[..., :2] -= 0.5
        return irises, lids


def free_batch_axis(model) -> None:
    """Give a converted ONNX ``model`` (onnx.ModelProto, changed in place) a free batch axis: its
    input's and outputs' first dimension named "N", each Reshape's target shape -1 there (the
    iris network's only Reshapes flatten each output per image, so both eyes run as one batch)."""
    from onnx import numpy_helper

    reshape_shapes = {n.input[1] for n in model.graph.node if n.op_type == "Reshape"}
    for init in model.graph.initializer:
        if init.name in reshape_shapes:
            shape = numpy_helper.to_array(init).copy()
            if shape.size and shape[0] == 1:
                shape[0] = -1
                init.CopyFrom(numpy_helper.from_array(shape, init.name))
    for value in (*model.graph.input, *model.graph.output):
        value.type.tensor_type.shape.dim[0].dim_param = "N"


def _batchable(net) -> bool:
    """Whether the converted network takes a batch of two (setup writes a free batch axis)."""
    shape = net.session.get_inputs()[0].shape
    return not isinstance(shape[0], int) or shape[0] != 1
