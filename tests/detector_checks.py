"""What the landmarks and hands tests share: a detector node run in a real graph (camera process
-> detector process -> collector), and the TFLite reader checked against ai-edge-litert on a
detector's original networks."""

from __future__ import annotations

import cv2
import numpy as np
from conftest import load_scale

from facesculpt.msgs import Image
from facesculpt.nodes.landmarks.tflite_reader import read_tflite
from facesculpt.runtime.node import Node
from facesculpt.runtime.qos import EVERY_MESSAGE


def collect(graph, models_dir, source, frames: int, *, node: str, topic: str, msg_type, fps: int, timeout=60):
    """Run the ``node`` process (``facesculpt run NODE``) and a camera sending ``frames`` frames of
    ``source``; returns ({stamp: image shape} of every camera frame, [every ``topic`` message])
    once the camera has ended and the last frame's message arrived. The detector takes the newest
    frame (latest-only): on a loaded machine the camera sends ``fps`` over the load's
    :func:`~conftest.load_scale`, so that it does not skip most of them."""
    fps = max(2, round(fps / load_scale()))
    images, received = {}, []
    collector = graph.node(Node(name=f"{node}_collector"))
    collector.subscribe("camera/image", Image, lambda m: images.__setitem__(m.stamp, m.image.shape),
                        qos=EVERY_MESSAGE)
    collector.subscribe(topic, msg_type, received.append, qos=EVERY_MESSAGE)
    graph.spawn("run", node, f"models_dir={models_dir}")
    # The camera waits for both subscribers (collector and detector) before its first frame.
    cam = graph.spawn("run", "camera", f"source={source}", f"fps={fps}", f"max_frames={frames}", "wait_subscribers=2",
                      "pace_by=",  # no renderer: nothing acknowledges frames; do not wait for one
                      "wait_timeout_s=30")
    graph.spin_until(collector, lambda: cam.poll() is not None and received and received[-1].stamp == max(images),
                     timeout)
    collector.spin_once(0.5)
    return images, received


def empty_messages(graph, models_dir, tmp_path, frames: int, **run) -> list:
    """The messages :func:`collect` (``run``: its node, topic, msg_type and fps) gets for a grey
    320x240 image (no face, no hand), after checking that there are some, each with the stamp
    of a camera frame and that frame's size."""
    grey = tmp_path / "grey.png"
    cv2.imwrite(str(grey), np.full((240, 320, 3), 127, np.uint8))
    images, received = collect(graph, models_dir, grey, frames, **run)
    assert received
    for msg in received:
        assert msg.stamp in images and msg.image_size == [320, 240]
    return received


def reader_matches_litert(path, interpreter_class) -> list[str]:
    """The names of the operators the TFLite reader finds in the network at ``path``, after
    checking that its tensors (index, name, shape), inputs, outputs and operators (name, inputs)
    are those ai-edge-litert's ``interpreter_class`` sees."""
    graph = read_tflite(path.read_bytes())
    interpreter = interpreter_class(model_path=str(path))
    details = interpreter.get_tensor_details()
    assert len(details) == len(graph.tensors)
    for d in details:
        t = graph.tensors[d["index"]]
        assert (t.name, t.shape) == (d["name"], tuple(int(v) for v in d["shape"]))
    assert graph.inputs == [d["index"] for d in interpreter.get_input_details()]
    assert graph.outputs == [d["index"] for d in interpreter.get_output_details()]
    ops = interpreter._get_ops_details()  # the only way litert lists operators
    assert [op.name for op in graph.operators] == [o["op_name"] for o in ops]
    assert [op.inputs for op in graph.operators] == [list(o["inputs"]) for o in ops]
    return [op.name for op in graph.operators]
