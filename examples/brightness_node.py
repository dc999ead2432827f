"""A user's own node in a few lines: brighten the camera and publish it.

Start a graph (`facesculpt launch video camera.source=face.mp4`), then, in
another terminal:

    python examples/brightness_node.py gain=1.8

It finds the running graph through the master (FACESCULPT_MASTER), receives
`camera/image` and publishes `camera/bright`; `facesculpt topic list` shows it.
"""

import numpy as np

from facesculpt.msgs import Image
from facesculpt.runtime import Node, Param


class Brightness(Node):
    NAME = "brightness"
    PARAMS = {"gain": Param(1.5, "brightness factor", range=(0.0, 10.0))}

    def setup(self):
        self.out = self.advertise("camera/bright", Image)
        self.subscribe("camera/image", Image, self.on_image)

    def on_image(self, msg):
        bright = np.clip(msg.image * self.params.gain, 0, 255).astype(np.uint8)
        self.out.publish(Image(stamp=msg.stamp, image=bright, K=msg.K))


if __name__ == "__main__":
    Brightness.main()
