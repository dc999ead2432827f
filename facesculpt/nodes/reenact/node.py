"""The reenact node: ``facesculpt run reenact`` (facesculpt/launch/reenact.yaml: two cameras, one face drives the other).

Subscribes the driving face's ``driver/state`` (FaceState) and its latched ``driver/model``
(FaceModel: the neutral its fitter learned) and publishes the latched ``face/deformation``
(Deformation): the driver's expression displacement from its own neutral
(:mod:`.transfer`), which the renderer merges into the source face's fit of every frame (paper
Eq. 5) and composites from the source camera's image. Remap the topics in a launch file to pair
other fitters. A state without a face keeps the last displacement.
"""

from __future__ import annotations

import numpy as np

from facesculpt.msgs import Deformation, FaceModel, FaceState
from facesculpt.runtime.node import Node
from facesculpt.runtime.parameters import Param
from facesculpt.runtime.qos import LATCHED

from .transfer import expression_displacement, model_space_shape


class ReenactNode(Node):
    """Publishes face/deformation = the driver's expression displacement (see the module docstring)."""

    NAME = "reenact"
    TOPICS = ("face/deformation", "driver/model", "driver/state")
    PARAMS = {
        "gain": Param(1.0, "scale of the carried expression (0: none, 1: as the driver, up to 3)", range=(0.0, 3.0)),
    }

    def setup(self):
        self.neutral: np.ndarray | None = None
        self.model_id = ""
        self.version = 0
        self.out = self.advertise("face/deformation", Deformation, qos=LATCHED)
        self.subscribe("driver/model", FaceModel, self.on_model)
        self.subscribe("driver/state", FaceState, self.on_state)

    def on_model(self, msg: FaceModel) -> None:
        self.neutral = np.asarray(msg.vertices, np.float64)
        self.model_id = msg.model_id

    def on_state(self, msg: FaceState) -> None:
        if self.neutral is None or len(msg.vertices) == 0:
            self.count("skipped")
            return
        if msg.vertices.shape != self.neutral.shape:
            self.count("model_mismatch")
            return
        shape = model_space_shape(msg.vertices, msg.R, msg.t, msg.scale, msg.projection)
        self.version += 1
        self.out.publish(Deformation(stamp=msg.stamp, frame_id=msg.frame_id, model_id=self.model_id,
                                     displacement=expression_displacement(shape, self.neutral, self.params.gain),
                                     version=self.version))
        self.count("published")


if __name__ == "__main__":
    ReenactNode.main()
