"""Input nodes (docs/architecture.md "An input event's path"): they publish ``input/events``
(facesculpt.msgs.InputEvent).

* ``joystick`` (:mod:`.joystick`): a serial joystick speaking the ``X Y Z BUTTONS`` line protocol;
* ``script`` (:mod:`.script`): plays a YAML gesture script;
* the mouse lives in the renderer's window; any custom node may publish InputEvents too
  (examples/custom_input_node.py).

Their pure parts: :mod:`.joystick_protocol` (the line parser and the joystick mapping),
:mod:`.gesture_script` (the gesture-script compiler and player) and :mod:`.face_targets`
(the landmark an input acts on, and :class:`InputError`).
"""

from .face_targets import InputError, nearest_landmark, roi_centre
from .gesture_script import GestureScript, ScriptError, ScriptPlayer, load_script, parse_script
from .joystick_protocol import JoystickMapper, LineSplitter, ProtocolError, Sample, parse_line

__all__ = [
    "GestureScript",
    "InputError",
    "JoystickMapper",
    "LineSplitter",
    "ProtocolError",
    "Sample",
    "ScriptError",
    "ScriptPlayer",
    "load_script",
    "nearest_landmark",
    "parse_line",
    "parse_script",
    "roi_centre",
]
