"""Facesculpt data as Foxglove's well-known messages (``foxglove-sdk``): arrays in, messages out.

Images become ``RawImage`` (``bgr8``) or ``CompressedImage`` (JPEG); meshes (camera space)
``TriangleListPrimitive`` entities of a ``SceneUpdate`` in the camera's frame (OpenCV axes:
x right, y down, z forward, as Foxglove's camera frames), scaled from the model's units to
metres; handles become spheres; landmarks (pixels) ``ImageAnnotations`` points; a JSON object
from Foxglove's publish panel becomes an ``InputEvent``. The node (``node.py``) and
``facesculpt bag export --foxglove`` share these through ``bridge.py``.
"""

from __future__ import annotations

import json
import math

import cv2
import numpy as np
from foxglove.messages import (
    CameraCalibration,
    Color,
    CompressedImage,
    ImageAnnotations,
    Point2,
    Point3,
    PointsAnnotation,
    PointsAnnotationType,
    Pose,
    Quaternion,
    RawImage,
    SceneEntity,
    SpherePrimitive,
    Timestamp,
    TriangleListPrimitive,
    Vector3,
)

from facesculpt.msgs import INPUT_KINDS, InputEvent

IDENTITY = Pose(position=Vector3(x=0.0, y=0.0, z=0.0), orientation=Quaternion(x=0.0, y=0.0, z=0.0, w=1.0))


def timestamp(stamp_ns: int) -> Timestamp:
    """A Foxglove timestamp of a stamp in ns."""
    stamp_ns = max(0, int(stamp_ns))
    return Timestamp(stamp_ns // 1_000_000_000, stamp_ns % 1_000_000_000)


def image_message(image: np.ndarray, stamp_ns: int, frame_id: str, jpeg_quality: int = 0):
    """(H, W, 3) uint8 BGR as ``RawImage`` (``jpeg_quality`` 0) or a JPEG ``CompressedImage`` (1..100)."""
    image = np.ascontiguousarray(image)
    if jpeg_quality <= 0:
        h, w = image.shape[:2]
        return RawImage(timestamp=timestamp(stamp_ns), frame_id=frame_id, width=w, height=h,
                        encoding="bgr8", step=w * 3, data=image.tobytes())
    ok, data = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, int(jpeg_quality)])
    if not ok:
        raise ValueError("JPEG encoding of the image failed")
    return CompressedImage(timestamp=timestamp(stamp_ns), frame_id=frame_id, data=data.tobytes(), format="jpeg")


def calibration_message(K: np.ndarray, width: int, height: int, stamp_ns: int, frame_id: str) -> CameraCalibration:
    """The pinhole camera of K ((3, 3), pixels), so Foxglove can draw the 3D scene over the image."""
    k = [float(v) for v in np.asarray(K, np.float64).reshape(9)]
    P = [k[0], k[1], k[2], 0.0, k[3], k[4], k[5], 0.0, k[6], k[7], k[8], 0.0]
    return CameraCalibration(timestamp=timestamp(stamp_ns), frame_id=frame_id, width=int(width), height=int(height),
                             distortion_model="plumb_bob", D=[0.0] * 5, K=k,
                             R=[1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0], P=P)


def color(rgba) -> Color:
    r, g, b, a = (float(c) for c in rgba)
    return Color(r=r, g=g, b=b, a=a)


def mesh_primitive(vertices: np.ndarray, triangles: np.ndarray, rgba, to_m: float) -> TriangleListPrimitive:
    """(V, 3) camera-space vertices (model units; ``to_m`` metres per unit) and (T, 3) int triangles."""
    pts = np.asarray(vertices, np.float64) * to_m
    return TriangleListPrimitive(pose=IDENTITY, points=[Point3(x=x, y=y, z=z) for x, y, z in pts.tolist()],
                                 color=color(rgba), indices=np.asarray(triangles, np.int64).reshape(-1).tolist())


def sphere_primitives(centres: np.ndarray, diameter_m: float, rgba, to_m: float) -> list[SpherePrimitive]:
    """One sphere per (N, 3) camera-space centre (model units)."""
    size = Vector3(x=diameter_m, y=diameter_m, z=diameter_m)
    out = []
    for x, y, z in (np.asarray(centres, np.float64).reshape(-1, 3) * to_m).tolist():
        pose = Pose(position=Vector3(x=x, y=y, z=z), orientation=Quaternion(x=0.0, y=0.0, z=0.0, w=1.0))
        out.append(SpherePrimitive(pose=pose, size=size, color=color(rgba)))
    return out


def mesh_entity(entity_id: str, stamp_ns: int, frame_id: str, triangles=(), spheres=()) -> SceneEntity:
    """A scene entity of triangle lists and spheres in ``frame_id``."""
    return SceneEntity(timestamp=timestamp(stamp_ns), frame_id=frame_id, id=entity_id,
                       triangles=list(triangles), spheres=list(spheres))


def landmark_annotations(points: np.ndarray, stamp_ns: int, rgba=(0.1, 1.0, 0.3, 1.0),
                         diameter_px: float = 3.0) -> ImageAnnotations:
    """(F, N, 2+) landmark pixels of F faces as point annotations over the image."""
    faces = []
    for face in np.asarray(points, np.float64):
        faces.append(PointsAnnotation(timestamp=timestamp(stamp_ns), type=PointsAnnotationType.Points,
                                      points=[Point2(x=x, y=y) for x, y in face[:, :2].tolist()],
                                      outline_color=color(rgba), thickness=float(diameter_px)))
    return ImageAnnotations(points=faces)


def _number(d: dict, key: str, default: float) -> float:
    value = d.get(key, default)
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ValueError(f"input event field {key!r} must be a number, not {value!r}")
    return float(value)


def input_event_from_json(data: bytes | str | dict, source: str = "foxglove") -> InputEvent:
    """An InputEvent from Foxglove's publish panel: a JSON object with InputEvent's fields
    (``kind`` required; ``vector`` [x, y, z] mm, ``axes`` a list). ValueError in one sentence
    when it is not one."""
    try:
        d = data if isinstance(data, dict) else json.loads(data)
    except (ValueError, UnicodeDecodeError):
        raise ValueError("the published input event is not JSON") from None
    if not isinstance(d, dict):
        raise ValueError("the published input event is not a JSON object")
    kind = d.get("kind")
    if kind not in INPUT_KINDS:
        raise ValueError(f"input event kind {kind!r} is not one of {', '.join(INPUT_KINDS)}")
    known = {"kind", "x", "y", "landmark", "handle", "depth", "vector", "axes", "buttons", "command", "argument",
             "face", "stamp", "source", "pose"}
    unknown = sorted(set(d) - known)
    if unknown:
        raise ValueError(f"input event has unknown fields {', '.join(unknown)}")
    event = InputEvent(kind=kind, x=_number(d, "x", math.nan), y=_number(d, "y", math.nan),
                       landmark=str(d.get("landmark", "")), handle=int(_number(d, "handle", 0)),
                       depth=_number(d, "depth", 0.0), buttons=int(_number(d, "buttons", 0)),
                       command=str(d.get("command", "")), argument=str(d.get("argument", "")),
                       face=int(_number(d, "face", -1)), source=str(d.get("source", source)),
                       stamp=int(_number(d, "stamp", 0)))
    for key, size in (("vector", 3), ("axes", None), ("pose", 6)):
        if d.get(key) is not None:
            arr = np.asarray(d[key], np.float32) if isinstance(d[key], list) else None
            if arr is None or arr.ndim != 1 or (size and arr.size != size) or not np.isfinite(arr).all():
                raise ValueError(f"input event field {key!r} must be a list of {size or 'some'} numbers")
            setattr(event, key, arr)
    event.validate()
    return event
