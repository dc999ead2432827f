"""Built-in nodes: one folder per room of the graph (docs/architecture.md "Rooms").

BUILTIN_NODES maps the short names used by `facesculpt run NAME` and by launch
files (``node: camera``) to ``module:Class``.
"""

BUILTIN_NODES = {
    "camera": "facesculpt.nodes.camera.node:CameraNode",
    "landmarks": "facesculpt.nodes.landmarks.node:LandmarksNode",
    "fitter": "facesculpt.nodes.fitter.node:FitterNode",
    "deformer": "facesculpt.nodes.deformer.node:DeformerNode",
    "renderer": "facesculpt.nodes.renderer.node:RendererNode",
    "joystick": "facesculpt.nodes.input.joystick:JoystickNode",
    "script": "facesculpt.nodes.input.script:ScriptNode",
    "hands": "facesculpt.nodes.hands.node:HandsNode",
    "pinch": "facesculpt.nodes.input.pinch:PinchNode",
    "foxglove": "facesculpt.nodes.foxglove.node:FoxgloveNode",
    "reenact": "facesculpt.nodes.reenact.node:ReenactNode",
    "encoder": "facesculpt.nodes.reenact.encoder_node:EncoderNode",
    "decoder": "facesculpt.nodes.renderer.decoder_node:DecoderNode",
}


def node_class(name: str):
    """The Node subclass a launch file or `facesculpt run` names: a built-in name above,
    ``module:Class`` or ``path/file.py:Class`` (:func:`facesculpt.runtime.node.load_node_class`)."""
    from facesculpt.runtime.node import load_node_class

    return load_node_class(name, BUILTIN_NODES)
