"""Input nodes (DESIGN.md "nodes/input"): they publish ``input/events`` (facesculpt.msgs.InputEvent).

* ``joystick`` (:mod:`.joystick`): a serial joystick speaking the ``X Y Z BUTTONS`` line protocol;
* ``script`` (:mod:`.script`): plays a YAML gesture script;
* the mouse lives in the renderer's window; any custom node may publish InputEvents too
  (examples/custom_input_node.py).

:mod:`.protocol` holds their pure parts: the line parser, the joystick mapping and the
gesture-script compiler and player.
"""

from .protocol import (
    GestureScript,
    InputError,
    JoystickMapper,
    LineSplitter,
    ProtocolError,
    Sample,
    ScriptError,
    ScriptPlayer,
    load_script,
    nearest_landmark,
    parse_line,
    parse_script,
    roi_centre,
)

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
