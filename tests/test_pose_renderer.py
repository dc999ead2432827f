"""Pose edits in the renderer node (issue 18), as a real process in a graph: the Deformation's pose
turns the head (the face and the head region around it change, pixels far from the head stay the
input's bit for bit), and ``face_camera`` turns a face that looks away toward the camera."""

from __future__ import annotations

import numpy as np
import pytest
from test_renderer_node import MS, Feeder

from benchmarks.renderer_scene import place_marked, rasterize_region, read_frames
from facesculpt.geometry.pose_offset import PoseOffset, apply_pose_offset, face_camera_offset, head_pivot
from facesculpt.msgs import Deformation, FaceModel, FaceState, Image
from facesculpt.nodes.renderer import Compositor
from facesculpt.nodes.renderer.motion_extension import head_box


def render_once(graph, model, pose, frame, t, deformation: Deformation | None, *params) -> np.ndarray:
    """One frame through `facesculpt run renderer PARAMS` with the placement ``pose`` (translation
    ``t``) as its face state and ``deformation`` latched before it; the rendered frame."""
    H, W = frame.shape[:2]
    renderer = graph.spawn("run", "renderer", "pairing=sync", *params)
    feeder = graph.node(Feeder())
    try:
        for pub in (feeder.image_pub, feeder.state_pub, feeder.deformation_pub):
            assert pub.wait_for_subscribers(1, 30.0), f"the renderer never subscribed to {pub.topic}"
        feeder.model_pub.publish(FaceModel(stamp=1, model_id=model.model_id, vertices=model.mean.astype(np.float32),
                                           triangles=model.triangles.astype(np.int32)))
        if deformation is not None:
            feeder.deformation_pub.publish(deformation)
        graph.spin_until(feeder, lambda: False, 1.0)  # let model and edit arrive before the frame
        stamp = 40 * MS
        feeder.image_pub.publish(Image(stamp=stamp, seq=0, image=frame, K=pose.K))
        feeder.state_pub.publish(FaceState(stamp=stamp, model_id=model.model_id, R=pose.R, t=t, scale=1.0, K=pose.K,
                                           vertices=pose.fitted.astype(np.float32),
                                           projected=pose.projected.astype(np.float32), image_size=[W, H],
                                           projection="perspective"))
        assert graph.spin_until(feeder, lambda: stamp in feeder.rendered, 30.0), "the frame was not rendered"
        return feeder.rendered[stamp]
    finally:
        renderer.terminate()
        renderer.wait(10)


def expected_render(model, pose, frame, t, offset: PoseOffset) -> tuple[np.ndarray, np.ndarray]:
    """The frame composited by the library with the head turned by ``offset`` (head motion on),
    and the deformed face's pixels (V, 2)."""
    H, W = frame.shape[:2]
    turned = apply_pose_offset(pose.fitted, pose.R, t, 1.0, head_pivot(model.mean), offset)
    comp = Compositor(W, H)
    try:
        out = comp.render(frame, pose.fitted.astype(np.float32), pose.projected.astype(np.float32), model.triangles,
                          turned.astype(np.float32), head_motion=True)
    finally:
        comp.release()
    return out, pose.project(turned)


def placed(data_dir):
    from facesculpt.nodes.fitter import load_model

    model = load_model("sfm")
    pose = place_marked(model, "s18")
    t = (pose.fitted - pose.rest @ pose.R.T).mean(axis=0)  # fitted = R · mean + t
    return model, pose, t, read_frames(data_dir, "s18", count=1)[0]


@pytest.mark.slow
def test_the_deformations_pose_turns_the_head_and_leaves_the_rest_of_the_frame(graph, data_dir):
    model, pose, t, frame = placed(data_dir)
    offset = PoseOffset(yaw=12.0, pitch=-4.0)
    deformation = Deformation(stamp=1, model_id=model.model_id, displacement=np.zeros_like(model.mean, np.float32),
                              version=1, pose=np.array(offset.as_list(), np.float32))
    out = render_once(graph, model, pose, frame, t, deformation)
    expected, turned_px = expected_render(model, pose, frame, t, offset)
    assert np.abs(out.astype(int) - expected).max() <= 1  # as the library turns it (Pipeline's way)

    H, W = frame.shape[:2]
    changed = np.any(out != frame, axis=2)
    face = rasterize_region(pose.projected, model.triangles, (H, W)) | rasterize_region(turned_px, model.triangles,
                                                                                        (H, W))
    x0, y0, x1, y1 = head_box(np.concatenate([pose.projected, turned_px]), W, H)
    head = np.zeros((H, W), bool)
    head[y0:y1, x0:x1] = True
    assert changed[face].mean() > 0.5  # the face turned
    assert (changed & head & ~face).sum() > 2000  # the head around it (hair, ears, neck) went with it
    assert not changed[~head].any()  # far from the head: the input's pixels


@pytest.mark.slow
def test_face_camera_turns_a_face_that_looks_away_toward_the_camera(graph, data_dir):
    model, pose, t, frame = placed(data_dir)
    target = face_camera_offset(pose.R, t, 1.0, head_pivot(model.mean), 1.0, 5.0)
    assert target.yaw == -5.0 and target.pitch == -5.0  # s18's face looks about 11 degrees away: clamped
    out = render_once(graph, model, pose, frame, t, None, "face_camera=1", "face_camera_limit=5")
    expected, _ = expected_render(model, pose, frame, t, target)
    assert not np.array_equal(out, frame)
    assert np.abs(out.astype(int) - expected).max() <= 1


def test_window_keys_turn_the_head_and_the_other_keys_keep_their_commands():
    """The window's key handler on a stand-in window (no display needed): arrows, comma and period
    send pose events of POSE_STEP_DEG (held keys repeat), 0 reset_pose; the older keys unchanged."""
    import glfw

    from facesculpt.msgs import InputEvent
    from facesculpt.nodes.renderer.window import POSE_STEP_DEG, Window, keys_help

    class StandIn:
        _events: list = []
        _dragging = correcting = closed = False

    def press(key, action=glfw.PRESS, mods=0):
        win = StandIn()
        win._events = []
        Window._on_key(win, None, key, 0, action, mods)
        return win._events, win.closed

    s = POSE_STEP_DEG
    for key, want in [(glfw.KEY_RIGHT, [s, 0, 0]), (glfw.KEY_LEFT, [-s, 0, 0]), (glfw.KEY_UP, [0, -s, 0]),
                      (glfw.KEY_DOWN, [0, s, 0]), (glfw.KEY_COMMA, [0, 0, s]), (glfw.KEY_PERIOD, [0, 0, -s])]:
        for action in (glfw.PRESS, glfw.REPEAT):
            (event,), _ = press(key, action)
            msg = InputEvent(**event)
            msg.validate()
            assert msg.kind == "pose" and np.array_equal(msg.pose, want + [0, 0, 0])
        assert press(key, glfw.RELEASE)[0] == []
    assert press(glfw.KEY_0)[0] == [{"kind": "command", "command": "reset_pose"}]
    assert press(glfw.KEY_R)[0] == [{"kind": "command", "command": "reset"}]
    assert press(glfw.KEY_U)[0] == [{"kind": "command", "command": "undo"}]
    assert press(glfw.KEY_Z, mods=glfw.MOD_CONTROL)[0] == [{"kind": "command", "command": "undo"}]
    assert press(glfw.KEY_C)[0] == [{"kind": "command", "command": "clear_corrections"}]
    assert press(glfw.KEY_S)[0][0]["command"] == "save_preset"
    assert press(glfw.KEY_Q) == ([], True) and press(glfw.KEY_ESCAPE) == ([], True)
    assert press(glfw.KEY_R, glfw.REPEAT)[0] == []  # only pose keys repeat
    assert "arrows , . shift/ctrl+wheel: turn head" in keys_help() and "0 head straight" in keys_help()


def test_shift_and_ctrl_wheel_turn_the_head_and_the_plain_wheel_still_sets_depth():
    from facesculpt.nodes.renderer.window import POSE_STEP_DEG, WHEEL_MM_PER_NOTCH, scroll_event

    assert scroll_event(0, 2, False, False, 10, 20) == {"kind": "depth", "depth": 2 * WHEEL_MM_PER_NOTCH,
                                                          "x": 10, "y": 20, "handle": 0}
    for args, want in (((0, 1, True, False), [POSE_STEP_DEG, 0, 0]), ((0, -2, False, True), [0, -2 * POSE_STEP_DEG, 0]),
                       ((-1, 0, False, False), [-POSE_STEP_DEG, 0, 0])):
        event = scroll_event(*args, 10, 20)
        assert event["kind"] == "pose" and event["pose"].tolist() == want + [0, 0, 0]
