"""An on-screen window (glfw) that shows the rendered frames and reports the user's input.

The window is the frame's size (it may be resized; the picture is stretched to
fit) and owns the OpenGL context the compositor then draws with. Mouse and key
events come back from :meth:`Window.poll` as plain dicts holding the fields of an
``InputEvent`` (facesculpt.msgs), with x, y in *frame* pixels:

* left button: ``press`` / ``drag`` (motion while held) / ``release``, handle 0;
* right button: ``command`` ``toggle_static`` at the pointer;
* wheel: ``depth``, +1 mm per notch toward the camera (handle 0); Shift+wheel (or a sideways
  wheel) turns the head (yaw), Ctrl+wheel nods it (pitch), ``POSE_STEP_DEG`` per notch;
* keys: R ``reset``, U or Ctrl+Z ``undo``, S ``save_preset`` (a timestamped JSON);
  Escape and Q close the window (the node decides what closing stops: its ``close`` param);
* pose edits (issue 18): the arrow keys send ``pose`` events turning the head ``POSE_STEP_DEG``
  (yaw: left / right, pitch: up / down, the nose going the arrow's way), comma and period roll it
  (counter-clockwise / clockwise on screen), held keys repeat; 0 sends ``reset_pose``;
* L toggles the landmark correction mode (:attr:`Window.correcting`): the left button's
  press / drag / release then carry ``"correct": True`` (the node turns them into
  ``correct_landmark`` commands, ``correction_mode.py``, never into edits), and the wheel and
  right button do nothing; C sends ``clear_corrections`` (in either mode).

What is drawn over the frame (text, handles, ROI, pins) is ``overlay.py``'s
:func:`draw_overlay`, applied to the frame before :meth:`Window.show`.

glfw wants its calls on the main thread: create, show and poll from the thread
that runs the node.
"""

from __future__ import annotations

import time

import glfw
import moderngl
import numpy as np

from .overlay import draw_overlay  # noqa: F401  (the window's overlay; kept importable from here)

WHEEL_MM_PER_NOTCH = 1.0
#: Degrees a pose key turns the head (yaw, pitch or roll).
POSE_STEP_DEG = 2.0
#: Pose keys -> (yaw, pitch, roll) sign of their step: + yaw turns the nose to the image's right,
#: + pitch down, + roll counter-clockwise on screen (facesculpt.geometry.pose_offset).
POSE_KEYS = {glfw.KEY_LEFT: (-1, 0, 0), glfw.KEY_RIGHT: (1, 0, 0), glfw.KEY_UP: (0, -1, 0),
             glfw.KEY_DOWN: (0, 1, 0), glfw.KEY_COMMA: (0, 0, 1), glfw.KEY_PERIOD: (0, 0, -1)}


def scroll_event(dx: float, dy: float, shift: bool, ctrl: bool, x: float, y: float) -> dict:
    """The input event of a wheel turn (``dy`` notches, ``dx`` of a sideways wheel) at frame pixel
    (x, y): ``depth`` (WHEEL_MM_PER_NOTCH per notch toward the camera); with Shift held, or on a
    sideways wheel, a ``pose`` turn of POSE_STEP_DEG yaw per notch; with Ctrl held, of pitch."""
    if shift or ctrl or (dx and not dy):
        notches = float(dy if dy else dx)
        turn = [notches * POSE_STEP_DEG, 0.0, 0.0] if not ctrl else [0.0, notches * POSE_STEP_DEG, 0.0]
        return {"kind": "pose", "pose": np.array(turn + [0.0, 0.0, 0.0], np.float32)}
    return {"kind": "depth", "depth": float(dy) * WHEEL_MM_PER_NOTCH, "x": x, "y": y, "handle": 0}


def keys_help(close: str = "graph", correcting: bool = False) -> str:
    """The window's mouse and keys in one line (groups apart by two spaces, where the overlay
    wraps it); ``close``: what Q does, "graph" (quit) or "node" (close this window);
    ``correcting``: the landmark correction mode's keys instead of the editing ones."""
    quit_key = "Q quit" if close == "graph" else "Q close"
    if correcting:
        return f"CORRECTION MODE  drag a landmark: put it there  C clear corrections  L back to editing  {quit_key}"
    return (f"drag: move  right-click: pin  wheel: depth  R reset  U undo  S save  L correct landmarks  "
            f"arrows , . shift/ctrl+wheel: turn head  0 head straight  {quit_key}")

_QUAD_VS = """
#version 330
in vec2 in_pos;
out vec2 v_uv;
void main() {
    gl_Position = vec4(in_pos, 0.0, 1.0);
    v_uv = vec2((in_pos.x + 1.0) * 0.5, (1.0 - in_pos.y) * 0.5);  // texture row 0 = top row
}
"""

_QUAD_FS = """
#version 330
uniform sampler2D u_image;
in vec2 v_uv;
out vec4 f_color;
void main() {
    f_color = vec4(texture(u_image, v_uv).bgr, 1.0);  // frames are BGR
}
"""


class Window:
    """A glfw window of ``width`` x ``height`` frame pixels with its own moderngl context.

    Raises RuntimeError when no window can be opened (no display, no GL 3.3).
    """

    def __init__(self, width: int, height: int, title: str = "facesculpt", visible: bool = True):
        self.width, self.height = int(width), int(height)
        # A display that has just started (a fresh Xvfb, a session coming up) can refuse the
        # first connection: a few tries over a second before giving up.
        for attempt in range(4):
            if glfw.init():
                break
            time.sleep(0.3 * (attempt + 1))
        else:
            desc = glfw.get_error()[1] if hasattr(glfw, "get_error") else None
            raise RuntimeError(f"cannot open a window: glfw could not initialise ({desc or 'no display?'}); "
                               f"use window=false for headless rendering")
        glfw.window_hint(glfw.CONTEXT_VERSION_MAJOR, 3)
        glfw.window_hint(glfw.CONTEXT_VERSION_MINOR, 3)
        glfw.window_hint(glfw.OPENGL_PROFILE, glfw.OPENGL_CORE_PROFILE)
        glfw.window_hint(glfw.OPENGL_FORWARD_COMPAT, True)
        glfw.window_hint(glfw.VISIBLE, bool(visible))
        # EGL first: Mesa refuses a GLX context (BadAccess in glXMakeCurrent) in a process that
        # already made an EGL one, e.g. a headless compositor; GLX when EGL windows fail.
        self.handle = None
        for api in (glfw.EGL_CONTEXT_API, glfw.NATIVE_CONTEXT_API):
            glfw.window_hint(glfw.CONTEXT_CREATION_API, api)
            self.handle = glfw.create_window(self.width, self.height, title, None, None)
            if self.handle:
                break
        if not self.handle:
            glfw.terminate()
            raise RuntimeError("cannot open a window: glfw could not create an OpenGL 3.3 window")
        glfw.make_context_current(self.handle)
        glfw.swap_interval(0)
        self.ctx = moderngl.create_context()
        self._texture = self.ctx.texture((self.width, self.height), 3, dtype="f1")
        self._prog = self.ctx.program(vertex_shader=_QUAD_VS, fragment_shader=_QUAD_FS)
        quad = np.array([-1, -1, 1, -1, -1, 1, 1, 1], np.float32)
        self._vbo = self.ctx.buffer(quad.tobytes())
        self._vao = self.ctx.vertex_array(self._prog, [(self._vbo, "2f", "in_pos")])
        self._events: list[dict] = []
        self._dragging = False
        self._drag_correct = False  # the drag under way began in correction mode
        self._pointer: tuple[float, float] | None = None
        self.correcting = False     # landmark correction mode (L)
        self.closed = False
        glfw.set_mouse_button_callback(self.handle, self._on_button)
        glfw.set_cursor_pos_callback(self.handle, self._on_cursor)
        glfw.set_scroll_callback(self.handle, self._on_scroll)
        glfw.set_key_callback(self.handle, self._on_key)

    # -- coordinates and events ---------------------------------------------------------------
    def to_frame(self, wx: float, wy: float) -> tuple[float, float]:
        """Window coordinates (the cursor's pixel) -> frame pixels (pixel centres at integers):
        the centre of the window pixel, scaled by frame size / window size."""
        ww, wh = glfw.get_window_size(self.handle)
        return ((wx + 0.5) * self.width / max(ww, 1) - 0.5, (wy + 0.5) * self.height / max(wh, 1) - 0.5)

    def _cursor(self) -> tuple[float, float]:
        # The position of the last motion event, not glfw.get_cursor_pos(): on X11 that
        # queries the pointer *now*, past the events still queued behind this one.
        if self._pointer is None:
            self._pointer = glfw.get_cursor_pos(self.handle)
        return self.to_frame(*self._pointer)

    @property
    def pointer(self) -> tuple[float, float] | None:
        """The cursor's last position in frame pixels; None before it moved over the window."""
        return None if self._pointer is None else self.to_frame(*self._pointer)

    def _pointer_event(self, kind: str, x: float, y: float) -> None:
        event = {"kind": kind, "x": x, "y": y, "handle": 0}
        if self._drag_correct:
            event["correct"] = True
        self._events.append(event)

    def _on_button(self, _win, button, action, mods) -> None:
        x, y = self._cursor()
        if button == glfw.MOUSE_BUTTON_LEFT:
            if action == glfw.PRESS:
                self._dragging, self._drag_correct = True, self.correcting
                self._pointer_event("press", x, y)
            elif action == glfw.RELEASE and self._dragging:
                self._pointer_event("release", x, y)
                self._dragging = False
        elif button == glfw.MOUSE_BUTTON_RIGHT and action == glfw.PRESS and not self.correcting:
            self._events.append({"kind": "command", "command": "toggle_static", "x": x, "y": y})

    def _on_cursor(self, _win, wx, wy) -> None:
        self._pointer = (wx, wy)
        if self._dragging:
            self._pointer_event("drag", *self.to_frame(wx, wy))

    def _on_scroll(self, _win, dx, dy) -> None:
        if self.correcting:
            return
        held = [glfw.get_key(self.handle, k) == glfw.PRESS for k in
                (glfw.KEY_LEFT_SHIFT, glfw.KEY_RIGHT_SHIFT, glfw.KEY_LEFT_CONTROL, glfw.KEY_RIGHT_CONTROL)]
        self._events.append(scroll_event(dx, dy, held[0] or held[1], held[2] or held[3], *self._cursor()))

    def _on_key(self, _win, key, _scancode, action, mods) -> None:
        if key in POSE_KEYS and action in (glfw.PRESS, glfw.REPEAT):
            step = POSE_STEP_DEG * np.array(POSE_KEYS[key] + (0, 0, 0), np.float32)
            self._events.append({"kind": "pose", "pose": step})
            return
        if action != glfw.PRESS:
            return
        if key == glfw.KEY_0:
            self._events.append({"kind": "command", "command": "reset_pose"})
        elif key in (glfw.KEY_ESCAPE, glfw.KEY_Q):
            self.closed = True
        elif key == glfw.KEY_R:
            self._events.append({"kind": "command", "command": "reset"})
        elif key == glfw.KEY_U or (key == glfw.KEY_Z and mods & glfw.MOD_CONTROL):
            self._events.append({"kind": "command", "command": "undo"})
        elif key == glfw.KEY_L:
            if self._dragging:  # a drag under way ends where it is, in the mode it began in
                self._pointer_event("release", *self._cursor())
                self._dragging = False
            self.correcting = not self.correcting
        elif key == glfw.KEY_C:
            self._events.append({"kind": "command", "command": "clear_corrections"})
        elif key == glfw.KEY_S:
            # The deformer writes the edits as a JSON preset (in its preset_dir), named by the time.
            self._events.append({"kind": "command", "command": "save_preset",
                                 "argument": time.strftime("facesculpt-edits-%Y%m%d-%H%M%S.json")})

    def poll(self) -> list[dict]:
        """Process pending window-system events; return the input events since the last poll."""
        glfw.poll_events()
        if glfw.window_should_close(self.handle):
            self.closed = True
        events, self._events = self._events, []
        return events

    # -- drawing ------------------------------------------------------------------------------
    def show(self, frame_bgr: np.ndarray) -> None:
        """Display a (height, width, 3) uint8 BGR frame (draw any overlay into it first)."""
        if frame_bgr.shape != (self.height, self.width, 3) or frame_bgr.dtype != np.uint8:
            raise ValueError(f"window shows ({self.height}, {self.width}, 3) uint8 frames, got "
                             f"{frame_bgr.shape} {frame_bgr.dtype}")
        glfw.make_context_current(self.handle)
        self._texture.write(np.ascontiguousarray(frame_bgr))
        fw, fh = glfw.get_framebuffer_size(self.handle)
        self.ctx.screen.use()
        self.ctx.viewport = (0, 0, fw, fh)
        self.ctx.disable(moderngl.DEPTH_TEST | moderngl.BLEND)
        self._texture.use(0)
        self._vao.render(moderngl.TRIANGLE_STRIP)
        glfw.swap_buffers(self.handle)

    def close(self) -> None:
        """Destroy the window and its GL objects (the context goes with the window)."""
        if self.handle is None:
            return
        for obj in (self._vao, self._vbo, self._prog, self._texture):
            obj.release()
        glfw.destroy_window(self.handle)
        self.handle = None
        glfw.terminate()
