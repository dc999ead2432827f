"""The input nodes' pure parts: the joystick line protocol, the joystick mapping, and the
gesture-script compiler and player."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from conftest import REPO_ROOT

from facesculpt.geometry import axes_velocity
from facesculpt.msgs import InputEvent
from facesculpt.nodes.input.face_targets import InputError, nearest_landmark, roi_centre
from facesculpt.nodes.input.gesture_script import ScriptError, ScriptPlayer, load_script, parse_script
from facesculpt.nodes.input.joystick_protocol import (
    JoystickMapper,
    LineSplitter,
    ProtocolError,
    Sample,
    axis_signs,
    parse_line,
)

GESTURES = REPO_ROOT / "examples" / "gestures"


# -- line protocol ------------------------------------------------------------------------------
def test_valid_lines_parse_to_axes_and_buttons():
    assert parse_line(b"1000 -1000 0 5") == Sample((1000, -1000, 0), 5)
    assert parse_line(b"  +12\t-7   3 0\r") == Sample((12, -7, 3), 0)  # any whitespace, CRLF
    s = parse_line(b"500 -250 1 2147483647\n")
    assert s.buttons == 2**31 - 1
    assert np.array_equal(s.normalized, np.array([0.5, -0.25, 0.001], np.float32))
    assert parse_line(b"") is None and parse_line(b"  \r") is None  # blank lines are not samples


@pytest.mark.parametrize("line, why", [
    (b"1 2 3", "got 3 fields"),
    (b"1 2 3 4 5", "got 5 fields"),
    (b"1.5 2 3 4", "not a decimal integer"),
    (b"1_000 0 0 0", "not a decimal integer"),
    (b"0x10 0 0 0", "not a decimal integer"),
    (b"1001 0 0 0", "axis X = 1001 is outside"),
    (b"0 0 -1001 0", "axis Z = -1001 is outside"),
    (b"0 0 0 -1", "not a bit mask"),
    (b"0 0 0 2147483648", "not a bit mask"),
    ("0 0 0 \u00b2".encode(), "not a decimal integer"),  # a unicode digit is not ASCII
    (b"\xff\xfe 0 0 0", "not a decimal integer"),
    (b"1 " * 100, "longer than"),
])
def test_malformed_lines_say_why(line, why):
    with pytest.raises(ProtocolError, match=why):
        parse_line(line)


def test_splitter_keeps_partial_lines_and_drops_overlong_ones_once():
    sp = LineSplitter()
    assert sp.feed(b"1 2 3 4\n5 6") == [b"1 2 3 4"]
    assert sp.feed(b" 7 8\n") == [b"5 6 7 8"]
    # 1000 bytes without a newline, in pieces: one None for the whole line, then the next line
    out = sp.feed(b"x" * 300) + sp.feed(b"y" * 700) + sp.feed(b"z\n9 9 9 9\n")
    assert out == [None, b"9 9 9 9"]
    sp.feed(b"half a li")
    sp.reset()  # the device went away mid-line
    assert sp.feed(b"1 1 1 1\n") == [b"1 1 1 1"]


# -- joystick mapping ----------------------------------------------------------------------------
def mapper(**kw):
    return JoystickMapper(velocity=lambda a: axes_velocity(a, 40.0, 0.1), **kw)


def test_buttons_grab_release_reset_and_moves_integrate_velocity():
    m = mapper()
    grab = lambda: "nose_tip"  # noqa: E731
    assert m.step(Sample((0, 0, 0), 0), 0.0, grab) == []
    ev = m.step(Sample((0, 0, 0), 1), 0.1, grab)  # grab button (bit 0) rises
    assert [e["kind"] for e in ev] == ["buttons", "press"]
    assert ev[1] == {"kind": "press", "landmark": "nose_tip", "handle": 1} and m.grabbed
    # full deflection along x for 0.2 s in two samples: 40 mm/s * 0.2 s = 8 mm
    ev = m.step(Sample((1000, 0, 0), 1), 0.2, grab) + m.step(Sample((1000, 0, 0), 1), 0.3, grab)
    assert [e["kind"] for e in ev] == ["move", "move"]
    total = sum(e["vector"] for e in ev)
    assert np.allclose(total, [8.0, 0.0, 0.0], atol=1e-5)
    assert np.array_equal(ev[0]["axes"], np.array([1.0, 0.0, 0.0], np.float32))
    # stick pushed forward (axis 1 negative) moves the point up (+y); inside the deadzone nothing moves
    ev = m.step(Sample((50, -1000, 80), 1), 0.35, grab)
    assert np.allclose(ev[0]["vector"], [0.0, 40.0 * 0.05, 0.0], atol=1e-5)
    assert m.step(Sample((99, -99, 60), 1), 0.4, grab) == []
    # a gap (device lost) never makes a jump: dt is capped, and restarts after interrupted()
    ev = m.step(Sample((0, 0, 1000), 1), 10.0, grab)
    assert np.allclose(ev[0]["vector"], [0, 0, 40.0 * 0.25], atol=1e-5)
    m.interrupted()
    assert m.step(Sample((0, 0, 1000), 1), 20.0, grab) == []
    ev = m.step(Sample((0, 0, 0), 3), 20.1, grab)  # release (bit 1) rises; grab still held: no new press
    assert [e["kind"] for e in ev] == ["buttons", "release"] and not m.grabbed
    ev = m.step(Sample((0, 0, 0), 4), 20.2, grab)  # reset (bit 2)
    assert [e["kind"] for e in ev] == ["buttons", "command"] and ev[1]["command"] == "reset"
    ev = m.step(Sample((1000, 0, 0), 4), 20.3, grab)  # not grabbed: no move
    assert ev == []
    for e in ev:
        InputEvent(**e).validate()


def test_grab_without_a_face_fails_clearly_but_keeps_the_buttons_event():
    m = mapper()

    def no_face():
        raise InputError("cannot grab: no fitted face seen yet")
    with pytest.raises(InputError, match="no fitted face") as info:
        m.step(Sample((0, 0, 0), 1), 0.0, no_face)
    assert [e["kind"] for e in info.value.events] == ["buttons"] and not m.grabbed


def test_inverted_axes_and_disabled_buttons():
    m = mapper(signs=axis_signs("x"), grab_button=-1, reset_button=-1)
    m.grabbed = True
    m.step(Sample((0, 0, 0), 0), 0.0, lambda: "x")
    ev = m.step(Sample((1000, 0, 0), 5), 0.1, lambda: "x")
    assert [e["kind"] for e in ev] == ["buttons", "move"]  # bits 0 and 2 are not mapped
    assert ev[1]["vector"][0] < 0 and ev[1]["axes"][0] == -1.0
    with pytest.raises(ValueError, match="x, y, z"):
        axis_signs("w")


def test_nearest_landmark_to_the_roi_centre():
    projected = np.array([[0, 0], [100, 0], [0, 200], [100, 200], [48, 110], [60, 60]], np.float32)
    centre = roi_centre(projected)
    assert np.allclose(centre, [50, 100])
    names, verts = ["chin", "31", "nose_tip", "forehead"], np.array([3, 4, 4, 5])
    assert nearest_landmark(projected, names, verts, centre) == "nose_tip"  # semantic name over "31"
    assert nearest_landmark(projected, names, verts, (60, 40)) == "forehead"
    with pytest.raises(InputError):
        nearest_landmark(projected, [], np.zeros(0), centre)


# -- gesture scripts ------------------------------------------------------------------------------
def test_example_scripts_compile_and_drags_add_up_exactly():
    nose = load_script(GESTURES / "nose_pull.yaml")
    assert nose.landmarks() == {"nose_tip": 8}
    moves = [a for a in nose.actions if a.kind == "move"]
    assert len(moves) == 30  # 30 Hz over 1 s
    assert np.allclose(np.sum([a.vector for a in moves], axis=0), [0, 0, 12], atol=1e-12)
    assert nose.duration == pytest.approx(2.0)
    chin = load_script(GESTURES / "chin.yaml")
    assert sum(a.depth for a in chin.actions if a.kind == "depth") == pytest.approx(2.0)
    cheeks = load_script(GESTURES / "cheeks.yaml")
    assert set(cheeks.landmarks()) == {"left_cheek", "right_cheek"}
    assert cheeks.duration == pytest.approx(3.0)  # the parallel drags take 1 s together


def test_player_plays_on_time_in_script_order():
    script = parse_script("""
rate_hz: 10
steps:
  - press: {pixel: [100, 50]}
  - drag: {px: [20, -10], duration_s: 0.5}
  - release
  - wait: 0.25
  - press: {landmark: chin, handle: 4}
  - drag: {px: [0, 8], duration_s: 0.2, handle: 4}
  - depth: {mm: -3, handle: 4}
  - load_preset: presets/smile.json
  - command: {name: select_edit, argument: 1}
""", source="t.yaml", base_dir="/tmp/g")
    player = ScriptPlayer(script)
    assert player.due(-1.0) == []
    first = player.due(0.0)
    assert first == [{"kind": "press", "x": 100.0, "y": 50.0, "handle": 2}]
    assert len(player.due(0.45)) == 4  # 10 Hz: at 0.1, 0.2, 0.3, 0.4 s
    drags = player.due(0.5)  # the last drag, then the release at the same time, in script order
    assert drags == [{"kind": "drag", "x": 120.0, "y": 40.0, "handle": 2}, {"kind": "release", "handle": 2}]
    assert player.due(0.74) == []  # the wait
    with pytest.raises(ScriptError, match="t.yaml line 9: .*needs the face's pixels"):
        player.due(0.9)  # a pixel drag from a landmark with nothing to locate it with
    player = ScriptPlayer(script)
    rest = player.due(10.0, locate=lambda name: {"chin": (300.0, 400.0)}[name])
    kinds = [e["kind"] for e in rest]
    assert kinds == ["press"] + ["drag"] * 5 + ["release", "press", "drag", "drag", "depth", "command", "command"]
    # A press at a landmark carries its pixel, and the drag starts from that same pixel.
    assert rest[7] == {"kind": "press", "landmark": "chin", "handle": 4, "x": 300.0, "y": 400.0}
    assert rest[9] == {"kind": "drag", "x": 300.0, "y": 408.0, "handle": 4}  # from the chin's pixel
    assert rest[10]["depth"] == -3.0
    assert rest[11]["argument"] == str(Path("/tmp/g/presets/smile.json"))  # relative to the script
    assert rest[12]["command"] == "select_edit" and rest[12]["argument"] == "1"
    assert player.finished(10.0) and not ScriptPlayer(script).finished(0.0)
    for e in rest:
        InputEvent(**e).validate()


@pytest.mark.parametrize("text, message", [
    ("steps:\n  - press: nose_tip\n  - drag: {mm: [0, 0, 5], duration_s: 1\n",
     r"bad.yaml line 3, column 11: not valid YAML \(while parsing a flow mapping: expected ',' or '}', "
     r"but got '<stream end>' at line 4, column 1\)"),
    ("steps:\n\t- release\n", r"bad.yaml line 2, column 1: not valid YAML \(found character '\\t'"),
    ("steps:\n  - press nose_tip\n", r"bad.yaml line 2: unknown step 'press nose_tip'"),
    ("steps:\n  - press: nose_tip\n  - drag: {mm: [0, 0], duration_s: 1}\n",
     r"bad.yaml line 3: drag: mm must be a list of 3 numbers"),
    ("steps:\n  - press: nose_tip\n  - drag: {mm: [0, 0, 1], px: [1, 2]}\n", r"line 3: drag: give exactly one of mm"),
    ("steps:\n  - drag: {px: [3, 4]}\n", r"line 2: drag: handle 2 is not pressed here"),
    ("steps:\n  - press: {pixel: [1, 2], landmark: chin}\n", r"line 2: press: give exactly one"),
    ("steps:\n  - wait: soon\n", r"line 2: wait: the time \(seconds\) must be a number"),
    ("steps:\n  - command: explode\n", r"line 2: command: 'explode' is not one of reset, undo"),
    ("steps:\n  - press: {landmark: chin, speed: 3}\n", r"line 2: press: unknown field\(s\) speed"),
    ("steps: []\n", r"bad.yaml: 'steps:' must be a non-empty list"),
    ("- 1\n- 2\n", r"bad.yaml line 1: a step is one of"),
    ("speed: 3\nsteps: [release]\n", r"unknown key\(s\) speed"),
    ("rate_hz: 0\nsteps: [release]\n", r"rate_hz must be a number in \(0, 1000\]"),
    ("just text\n", r"a gesture script is a mapping with 'steps:'"),
])
def test_script_errors_name_the_file_and_line(text, message):
    with pytest.raises(ScriptError, match=message):
        parse_script(text, source="bad.yaml")


def test_missing_script_file(tmp_path):
    with pytest.raises(ScriptError, match=r"gesture script .*nope.yaml not found"):
        load_script(tmp_path / "nope.yaml")
