"""The encoder node: ``facesculpt run encoder`` (facesculpt/launch/coding.yaml): a talking head coded live.

Subscribes the fitter's ``face/state`` and latched ``face/model`` (the person's neutral and the
mesh's triangles) and ``camera/image`` (for the keyframe), and codes the first face it sees
(:class:`.live_encoder.LiveEncoder`; other faces are skipped and counted): after
``learn_frames`` frames with a face it publishes the latched ``coding/key`` (CodedKey: the
keyframe) and ``coding/basis`` (CodedBasis: the expression basis), then one ``coding/frame``
(CodedFrame) per state, a frame without a face included; a new basis when the basis keeps
missing the face's expression (``refresh_mm``). The decoder node
(renderer room) renders them, on this machine or another.

Over tcp between hosts, run it with ``transport: tcp`` and CURVE keys (docs/security.md).
"""

from __future__ import annotations

import collections
import json

import numpy as np

from facesculpt.coding.fsc import KEY_QUALITY
from facesculpt.msgs import CodedBasis, CodedFrame, CodedKey, FaceModel, FaceState, Image
from facesculpt.runtime.node import Node
from facesculpt.runtime.parameters import Param
from facesculpt.runtime.qos import EVERY_MESSAGE, LATCHED

from .live_encoder import LiveEncoder
from .transfer import model_space_shape

#: Frames kept while the keyframe's image is looked up by its state's stamp.
IMAGES_KEPT = 30


class EncoderNode(Node):
    """Publishes coding/key and coding/frame (see the module docstring)."""

    NAME = "encoder"
    TOPICS = ("coding/key", "coding/basis", "coding/frame", "face/model", "camera/image", "face/state")
    PARAMS = {
        "components": Param(12, "expression coefficients per frame (one byte each)", range=(1, 64)),
        "learn_frames": Param(90, "frames with a face the expression basis is learnt from before the key is sent",
                              range=(2, 100000)),
        "refresh_mm": Param(1.0, "a frame whose expression the basis misses by more (RMS over the vertices, mm) "
                                 "counts toward learning the basis again and sending it again (0: never)",
                            range=(0.0, 100.0)),
        "refresh_frames": Param(15, "frames missed by refresh_mm that call for a new basis", range=(1, 100000)),
        "key_quality": Param(KEY_QUALITY, "keyframe WebP quality", range=(1, 100)),
        "fps": Param(30.0, "frame rate written in the key (the decoder's video output uses it), frames/s",
                     range=(1.0, 1000.0)),
    }

    def setup(self):
        self.key_pub = self.advertise("coding/key", CodedKey, qos=LATCHED)
        self.basis_pub = self.advertise("coding/basis", CodedBasis, qos=LATCHED)
        self.frame_pub = self.advertise("coding/frame", CodedFrame)
        self.version = self.basis_version = 0
        self.encoder: LiveEncoder | None = None  # made with the first face/model (it needs the mesh)
        self.model: FaceModel | None = None
        self.face_id: int | None = None
        self.images: collections.OrderedDict[int, Image] = collections.OrderedDict()
        self.subscribe("face/model", FaceModel, self.on_model, qos=LATCHED)
        self.subscribe("camera/image", Image, self.on_image, qos=EVERY_MESSAGE)
        self.subscribe("face/state", FaceState, self.on_state, qos=EVERY_MESSAGE)

    def on_model(self, msg: FaceModel) -> None:
        self.model = msg
        if self.encoder is None:
            p = self.params
            self.encoder = LiveEncoder(msg.triangles, p.components, p.learn_frames, p.key_quality, p.fps,
                                       refresh_mm=p.refresh_mm, refresh_frames=p.refresh_frames)

    def on_image(self, msg: Image) -> None:
        if self.encoder is None or self.encoder.learning:
            self.images[msg.stamp] = msg
            while len(self.images) > IMAGES_KEPT:
                self.images.popitem(last=False)

    def on_state(self, msg: FaceState) -> None:
        if self.model is None:
            self.count("no_model_yet")
            return
        if len(msg.vertices) == 0:
            self._send(self.encoder.empty_record(), msg)
            return
        if self.face_id is None:
            self.face_id = msg.face_id
        if msg.face_id != self.face_id or msg.vertices.shape != self.model.vertices.shape:
            self.count("other_face_skipped")
            return
        shape = model_space_shape(msg.vertices, msg.R, msg.t, msg.scale, msg.projection)
        image = self.images.get(msg.stamp)
        key, basis, record = self.encoder.add(shape, msg.vertices, msg.projected,
                                              None if image is None else image.image,
                                              None if image is None else image.K, self.model.vertices)
        if key is not None:
            self.images.clear()
            self.version += 1
            self.key_pub.publish(CodedKey(stamp=msg.stamp, frame_id=msg.frame_id, header=json.dumps(key.header),
                                          keyframe=np.frombuffer(key.keyframe, np.uint8),
                                          arrays=np.frombuffer(key.arrays, np.uint8), triangles=self.model.triangles,
                                          version=self.version))
            self.log.info("coding: key %d sent (image %d bytes, arrays %d)", self.version, len(key.keyframe),
                          len(key.arrays))
            self.count("keys_sent")
        if basis is not None:
            self.basis_version = basis.version
            self.basis_pub.publish(CodedBasis(stamp=msg.stamp, frame_id=msg.frame_id, key_version=self.version,
                                              version=basis.version, arrays=np.frombuffer(basis.arrays, np.uint8),
                                              basis_steps=basis.basis_steps, coeff_steps=basis.coeff_steps,
                                              record=np.frombuffer(basis.record, np.uint8)))
            self.log.info("coding: basis %d sent (%d bytes); %d bytes a frame", basis.version, len(basis.arrays),
                          len(basis.record))
            self.count("bases_sent")
        self._send(record, msg)

    def _send(self, record: bytes | None, msg) -> None:
        if record is None:
            self.count("learning")
            return
        self.frame_pub.publish(CodedFrame(stamp=msg.stamp, frame_id=msg.frame_id,
                                          record=np.frombuffer(record, np.uint8), key_version=self.version,
                                          basis_version=self.basis_version))
        self.count("frames_sent")


if __name__ == "__main__":
    EncoderNode.main()
