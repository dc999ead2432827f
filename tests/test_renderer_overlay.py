"""The window's overlay as a pure function (no window, no OpenGL): every text line fits inside
frames 480 px wide and up, its letters stand out from the frame on white, black and a real video
frame, long paths keep their end, and pins, handles and ROI get their own markers."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from facesculpt.nodes.renderer.overlay import (
    ELLIPSIS,
    FONT,
    HANDLE_BGR,
    MARGIN_PX,
    PIN_BGR,
    draw_overlay,
    fit_lines,
    layout_text,
)
from facesculpt.nodes.renderer.window import keys_help

# What the renderer shows: fps, the stage times of a frame, a saved preset's absolute path.
LINES = ["31 fps  render 12.4 ms",
         "camera 0.2  texture 0.4  draw 0.6  readback 0.5  masks 0.3  inpaint 12.1  composite 0.4",
         "saved preset /home/someone/projects/faces/presets/facesculpt-edits-20250101-120000.json"]


def letter_mask(placed, width: int, height: int) -> np.ndarray:
    """(height, width) uint8: 255 where the laid-out letters' strokes are, anti-aliasing aside."""
    mask = np.zeros((height, width), np.uint8)
    for t in placed:
        cv2.putText(mask, t.text, (t.org[0] + 1, t.org[1]), FONT, t.scale, 255, t.thickness, cv2.LINE_AA)
    return mask


def luminance(image: np.ndarray) -> np.ndarray:
    return cv2.cvtColor(image, cv2.COLOR_BGR2GRAY).astype(np.float64)


@pytest.mark.parametrize("size", [(480, 480), (512, 512), (480, 854), (1280, 720)])
def test_every_line_fits_inside_the_frame(size):
    W, H = size
    placed = layout_text(LINES + [keys_help()], W, H)
    texts = [t.text for t in placed]
    assert len(placed) >= 4                                 # nothing left out at these sizes
    # Wrapped, not lost: every word is there, a path too long for a line keeps its file name.
    words = " ".join(texts).split()
    for word in " ".join(LINES + [keys_help()]).split():
        assert word in words or any(w.startswith(ELLIPSIS) and word.endswith(w[len(ELLIPSIS):]) for w in words)
    assert any(t.endswith("facesculpt-edits-20250101-120000.json") for t in texts)
    for t in placed:
        (w, h), base = cv2.getTextSize(t.text, FONT, t.scale, t.thickness)
        assert t.org[0] >= MARGIN_PX and t.org[0] + w + 2 <= W - MARGIN_PX, (t.text, t.org, w, W)
        assert t.org[1] - h >= 0 and t.org[1] + base <= H
    # Drawn on a canvas twice the frame's width, no stroke reaches past the frame's right edge.
    mask = letter_mask(placed, 2 * W, H)
    assert mask[:, :W].max() == 255 and mask[:, W - MARGIN_PX:].max() == 0
    # The font follows the frame: larger on a larger frame, never below 0.4.
    assert placed[0].scale >= 0.4
    if W >= 1280:
        assert placed[0].scale > layout_text(LINES, 480, 480)[0].scale


@pytest.mark.parametrize("value", [255, 0])
def test_text_contrasts_with_a_white_or_black_frame_at_480_px(value):
    W, H = 480, 480
    frame = np.full((H, W, 3), value, np.uint8)
    out = draw_overlay(frame, LINES, help_lines=[keys_help()])
    placed = layout_text(LINES, W, H)
    lum = luminance(out)
    letters = letter_mask(placed, W, H)
    core = letters >= 192
    near = cv2.dilate(letters, np.ones((9, 9), np.uint8)) > 0
    for t in placed:  # line by line: its letters against the pixels around them
        rows = slice(t.org[1] - t.height, t.org[1] + t.baseline)
        cols = slice(t.org[0], t.org[0] + t.width)
        text = lum[rows, cols][core[rows, cols]]
        around = lum[rows, cols][near[rows, cols] & ~(letters[rows, cols] > 0)]
        assert text.size >= 10 and around.size > 100
        assert text.mean() > 200 and around.mean() < 120, (t.text, text.mean(), around.mean())
    # Outside the panels the frame is untouched.
    changed = np.any(out != frame, axis=2)
    top, bottom = placed, layout_text([keys_help()], W, H, bottom=True)
    panel = np.zeros((H, W), bool)
    for block in (top, bottom):
        y0 = min(t.org[1] - t.height for t in block) - MARGIN_PX
        y1 = max(t.org[1] + t.baseline for t in block) + MARGIN_PX
        x1 = max(t.org[0] + t.width for t in block) + MARGIN_PX
        panel[max(0, y0):y1, MARGIN_PX:x1] = True
    assert changed.any() and not (changed & ~panel).any()


def test_text_reads_on_a_real_video_frame(data_dir):
    cap = cv2.VideoCapture(str(data_dir / "video" / "d3.mp4"))
    ok, frame = cap.read()
    cap.release()
    assert ok and frame.shape == (512, 512, 3)
    out = draw_overlay(frame, LINES)
    placed = layout_text(LINES, 512, 512)
    lum = luminance(out)
    letters = letter_mask(placed, 512, 512)
    core = letters >= 192
    rim = (cv2.dilate(letters, np.ones((3, 3), np.uint8)) > 0) & (letters == 0)
    assert lum[core].mean() - lum[rim].mean() > 150


def test_a_long_path_keeps_its_end_and_words_wrap():
    room = 200
    lines = fit_lines(["saved preset /a/very/long/directory/name/facesculpt-edits-20250101-120000.json"], room, 0.5)
    assert lines[0] == "saved preset"
    assert lines[-1].startswith(ELLIPSIS) and lines[-1].endswith("120000.json")
    for line in lines:
        assert cv2.getTextSize(line, FONT, 0.5, 1)[0][0] + 2 <= room
    # Groups apart by two spaces stay whole when they fit.
    wrapped = fit_lines([keys_help()], 300, 0.5)
    assert len(wrapped) > 1 and "right-click: pin" in " | ".join(wrapped)


def test_help_is_left_out_rather_than_drawn_over_the_text():
    W, H = 160, 120
    frame = np.full((H, W, 3), 255, np.uint8)
    with_help = draw_overlay(frame, LINES, help_lines=[keys_help()])
    assert np.array_equal(with_help, draw_overlay(frame, LINES))
    # With room, the help is drawn at the bottom.
    frame = np.full((480, 480, 3), 255, np.uint8)
    out = draw_overlay(frame, ["31 fps"], help_lines=[keys_help()])
    assert (out[-60:] != 255).any()


def test_pins_handles_and_roi_have_their_own_markers():
    frame = np.full((200, 200, 3), 128, np.uint8)
    pins = np.array([[50.0, 60.0], [np.nan, 3.0]])
    out = draw_overlay(frame, points=np.array([[150.0, 60.0]]), roi=np.array([[100.0, 150.0]]), pins=pins)
    # A pin: a filled yellow square around its pixel, a dark border around that.
    assert (out[57:64, 47:54] == PIN_BGR).all()
    assert (out[60, 45] == 0).all() and (out[60, 46] == PIN_BGR).all() and (out[60, 44] == 128).all()
    # A handle: a red ring, its centre not filled.
    ring = out[53:68, 143:158].reshape(-1, 3).astype(int)
    assert ((ring[:, 2] > 180) & (ring[:, 1] < 80)).sum() > 10 and (out[60, 150] == 128).all()
    assert not (out[55:66, 145:156] == PIN_BGR).all(axis=2).any()
    # An ROI dot: blue-ish, small.
    assert out[150, 100, 0] > 200 and (np.any(out != 128, axis=2)[140:161, 90:111]).sum() <= 25
    # Nothing else changed (the NaN pin is skipped).
    changed = np.any(out != frame, axis=2)
    changed[40:80, 40:60] = changed[50:70, 140:160] = changed[145:156, 95:106] = False
    assert not changed.any()
    assert HANDLE_BGR != PIN_BGR
