"""Facesculpt messages onto Foxglove channels: one bridge for the live server and for MCAP export.

:class:`FoxgloveBridge` keeps the newest face model, deformation and camera intrinsics, and
logs each message it is given (``handle(topic, msg, log_time_ns)``) on the Foxglove channels of
a ``foxglove.Context``: the global one, which the node's WebSocket server serves, or a private
one whose sink is an MCAP file (``facesculpt bag export --foxglove``). Channels (topic: schema):

* ``camera/image``, ``render/image``: ``foxglove.RawImage`` or ``foxglove.CompressedImage`` (JPEG);
* ``camera/calibration``: ``foxglove.CameraCalibration`` from the image's K;
* ``face/landmarks``: ``foxglove.ImageAnnotations``, the landmark pixels as points;
* ``face/scene``: ``foxglove.SceneUpdate`` in the ``camera`` frame, per face the fitted mesh
  (``fitted/ID``), the deformed mesh (``deformed/ID``, paper Eq. 5) and the handles (spheres on
  the deformed mesh);
* ``diagnostics``: JSON, one object per node report (node, pid, values) for a table panel.
"""

from __future__ import annotations

import foxglove
from foxglove.channels import (
    CameraCalibrationChannel,
    CompressedImageChannel,
    ImageAnnotationsChannel,
    RawImageChannel,
    SceneUpdateChannel,
)
from foxglove.messages import SceneUpdate

from facesculpt.geometry import merge_deformation
from facesculpt.msgs import Deformation, Diagnostics, FaceLandmarks, FaceModel, FaceState, Image

from . import convert

IMAGE_TOPICS = ("camera/image", "render/image")
FITTED_RGBA = (0.2, 0.6, 1.0, 0.35)
DEFORMED_RGBA = (1.0, 0.55, 0.1, 0.6)
HANDLE_RGBA = (1.0, 0.1, 0.1, 1.0)
DIAGNOSTICS_SCHEMA = {
    "type": "object", "title": "facesculpt.Diagnostics",
    "properties": {"node": {"type": "string"}, "pid": {"type": "integer"}, "stamp": {"type": "integer"},
                   "values": {"type": "object"}},
}


class FoxgloveBridge:
    """Logs facesculpt messages as Foxglove messages on ``context`` (None: the global context).

    jpeg_quality: 0 sends images raw (``RawImage``), 1..100 as JPEG (``CompressedImage``).
    units_to_m: metres per unit of the face model (0.001 for millimetres).
    handle_diameter_m: size of the spheres drawn at the handles.
    """

    def __init__(self, context: foxglove.Context | None = None, jpeg_quality: int = 80,
                 units_to_m: float = 0.001, handle_diameter_m: float = 0.006, frame_id: str = "camera"):
        kw = {} if context is None else {"context": context}
        image_channel = CompressedImageChannel if jpeg_quality > 0 else RawImageChannel
        self.images = {topic: image_channel(topic, **kw) for topic in IMAGE_TOPICS}
        self.calibration = CameraCalibrationChannel("camera/calibration", **kw)
        self.landmarks = ImageAnnotationsChannel("face/landmarks", **kw)
        self.scene = SceneUpdateChannel("face/scene", **kw)
        self.diagnostics = foxglove.Channel("diagnostics", schema=DIAGNOSTICS_SCHEMA, message_encoding="json", **kw)
        self.jpeg_quality = int(jpeg_quality)
        self.units_to_m = float(units_to_m)
        self.handle_diameter_m = float(handle_diameter_m)
        self.frame_id = frame_id
        self.model: FaceModel | None = None
        self.deformation: Deformation | None = None
        self.logged = 0

    def handle(self, topic: str, msg, log_time_ns: int) -> bool:
        """Log ``msg`` (received on ``topic`` at ``log_time_ns``); False for a message it does not show.
        Nothing is converted for a channel no sink wants (no client subscribed to it)."""
        t = int(log_time_ns)
        if isinstance(msg, Image) and topic in IMAGE_TOPICS:
            if self.images[topic].has_sinks():
                self.images[topic].log(convert.image_message(msg.image, msg.stamp, self.frame_id, self.jpeg_quality),
                                       log_time=t)
            if topic == "camera/image" and self.calibration.has_sinks():
                h, w = msg.image.shape[:2]
                self.calibration.log(convert.calibration_message(msg.K, w, h, msg.stamp, self.frame_id), log_time=t)
        elif isinstance(msg, FaceLandmarks):
            if self.landmarks.has_sinks():
                self.landmarks.log(convert.landmark_annotations(msg.points, msg.stamp), log_time=t)
        elif isinstance(msg, FaceModel):
            self.model = msg
            return True
        elif isinstance(msg, Deformation):
            self.deformation = msg
            return True
        elif isinstance(msg, FaceState):
            if not self._log_scene(msg, t):
                return False
        elif isinstance(msg, Diagnostics):
            self.diagnostics.log({"node": msg.node, "pid": msg.pid, "stamp": msg.stamp, "values": msg.values},
                                 log_time=t)
        else:
            return False
        self.logged += 1
        return True

    def _log_scene(self, state: FaceState, t: int) -> bool:
        """The fitted and deformed meshes and the handles of one face state (needs the model's triangles)."""
        model = self.model
        if model is None or not len(state.vertices) or len(state.vertices) != len(model.vertices):
            return False
        if not self.scene.has_sinks():
            return True
        fid = state.face_id
        entities = [convert.mesh_entity(f"fitted/{fid}", state.stamp, self.frame_id, triangles=[
            convert.mesh_primitive(state.vertices, model.triangles, FITTED_RGBA, self.units_to_m)])]
        deformation = self.deformation
        if deformation is not None:
            displacement = deformation.displacement_of(fid)
            if displacement.shape == state.vertices.shape:
                deformed = merge_deformation(state.vertices, state.R, state.scale, displacement)
                handles = deformation.handles if deformation.face_id == fid else deformation.handles[:0]
                handles = handles[(handles >= 0) & (handles < len(deformed))]
                entities.append(convert.mesh_entity(
                    f"deformed/{fid}", state.stamp, self.frame_id,
                    triangles=[convert.mesh_primitive(deformed, model.triangles, DEFORMED_RGBA, self.units_to_m)],
                    spheres=convert.sphere_primitives(deformed[handles], self.handle_diameter_m, HANDLE_RGBA,
                                                      self.units_to_m)))
        self.scene.log(SceneUpdate(entities=entities), log_time=t)
        return True

    def close(self) -> None:
        for channel in (*self.images.values(), self.calibration, self.landmarks, self.scene, self.diagnostics):
            channel.close()
