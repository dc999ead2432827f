"""Pinch input at the library level (:class:`PinchTracker`) with synthetic hand landmarks: pinch,
move, push, release produce the right InputEvents; hysteresis; two hands, two handles; a still
hand holds a still point; a lost hand releases."""

from __future__ import annotations

import numpy as np
import pytest

from facesculpt.nodes.input.pinch_gesture import PinchConfig, PinchTracker

# A right hand, fingers up, in hand-size units (wrist to middle knuckle = 1).
_HAND = np.array([
    [0.0, 1.0], [-0.3, 0.8], [-0.5, 0.55], [-0.6, 0.3], [-0.65, 0.1],            # wrist, thumb
    [-0.35, 0.0], [-0.4, -0.35], [-0.42, -0.6], [-0.44, -0.8],                  # index
    [0.0, 0.0], [0.0, -0.4], [0.0, -0.65], [0.0, -0.85],                        # middle
    [0.25, 0.05], [0.27, -0.3], [0.28, -0.55], [0.29, -0.72],                   # ring
    [0.45, 0.15], [0.5, -0.1], [0.52, -0.28], [0.54, -0.42],                    # little
])
FPS = 30.0


def hand(centre=(300.0, 200.0), size=100.0, pinched=False) -> np.ndarray:
    """(21, 3) pixels; pinched: thumb and index tips meet at (-0.55, -0.1) hand units."""
    p = _HAND.copy()
    if pinched:
        p[4], p[8] = (-0.56, -0.1), (-0.54, -0.1)
    xy = np.asarray(centre) + p * size
    return np.column_stack([xy, np.zeros(21)])


def pinch_point(centre=(300.0, 200.0), size=100.0):
    return np.asarray(centre) + np.array([-0.55, -0.1]) * size


def run(tracker, frames, start=0):
    """frames: list of lists of (track_id, (21, 3) points); returns the events per frame."""
    out = []
    for i, hands in enumerate(frames):
        ids = [t for t, _ in hands]
        pts = np.stack([p for _, p in hands]) if hands else np.zeros((0, 21, 3))
        out.append(tracker.update(pts, ids, (start + i) / FPS))
    return out


def test_pinch_move_push_release():
    tracker = PinchTracker()
    frames = [[(7, hand())]] * 5 + [[(7, hand(pinched=True))]]
    moves = [[(7, hand((300.0 + 2 * k, 200.0 - k), pinched=True))] for k in range(1, 21)]
    settle = [[(7, hand((340.0, 180.0), pinched=True))]] * 20
    closer = [[(7, hand((340.0, 180.0), 100.0 * 1.5 ** (k / 10), pinched=True))] for k in range(1, 11)]
    settle2 = [[(7, hand((340.0, 180.0), 150.0, pinched=True))]] * 30
    opened = [[(7, hand((340.0, 180.0), 150.0))]]
    events = run(tracker, frames + moves + settle + closer + settle2 + opened)
    assert all(not e for e in events[:5])  # an open hand sends nothing
    (press,) = events[5]
    assert press.kind == "press" and press.handle == 0 and press.source == "pinch"
    assert np.allclose([press.x, press.y], pinch_point(), atol=0.01)
    assert press.stamp == int(round(5 / FPS * 1e9))
    drags = [e for frame in events[6:6 + 40] for e in frame if e.kind == "drag"]
    assert len(drags) >= 10 and all(e.handle == 0 for e in drags)
    xs = [e.x for e in drags]
    assert xs == sorted(xs)  # follows the hand, no overshoot back
    assert np.allclose([drags[-1].x, drags[-1].y], pinch_point((340.0, 180.0)), atol=0.6)
    depth = [e for frame in events for e in frame if e.kind == "depth"]
    assert depth and all(e.depth > 0 for e in depth)  # the hand came closer: toward the camera
    # the pinch point scales with the hand, so it drags too; the depth sums to 60 mm * ln 1.5
    assert sum(e.depth for e in depth) == pytest.approx(60.0 * np.log(1.5), abs=0.6)
    (release,) = events[-1]
    assert release.kind == "release" and release.handle == 0


def test_hysteresis_between_the_two_ratios_changes_nothing():
    tracker = PinchTracker(PinchConfig(close_ratio=0.25, open_ratio=0.40))
    half_open = hand(pinched=True)
    half_open[4, :2] = half_open[8, :2] + (30.0, 0.0)  # ratio 0.30: between close and open
    events = run(tracker, [[(1, hand())], [(1, half_open)], [(1, hand(pinched=True))], [(1, half_open)],
                           [(1, half_open)], [(1, hand())]])
    kinds = [[e.kind for e in frame if e.kind != "drag"] for frame in events]  # the pinch point moves with the thumb
    assert kinds == [[], [], ["press"], [], [], ["release"]]


def test_a_still_hand_holds_a_still_point():
    tracker = PinchTracker()
    rng = np.random.default_rng(0)
    frames = [[(3, hand(pinched=True))]]
    for _ in range(90):  # three seconds of a still hand with a pixel of landmark jitter
        noisy = hand(pinched=True)
        noisy[:, :2] += rng.uniform(-1.0, 1.0, (21, 2))
        frames.append([(3, noisy)])
    events = [e for frame in run(tracker, frames) for e in frame]
    assert events[0].kind == "press"
    drags = [e for e in events if e.kind == "drag"]
    points = np.array([[e.x, e.y] for e in drags]).reshape(-1, 2)
    assert len(drags) < 30
    assert np.abs(points - pinch_point()).max(initial=0.0) < 1.0
    assert not [e for e in events if e.kind in ("depth", "release")]


def test_two_hands_hold_two_handles_and_a_lost_hand_releases():
    tracker = PinchTracker(PinchConfig(max_missing=2))
    a, b = hand((200.0, 200.0), pinched=True), hand((450.0, 220.0), pinched=True)
    events = run(tracker, [[(0, a), (1, b)], [(0, a), (1, b)], [(1, b)], [(1, b)], [(1, b)]])
    presses = events[0]
    assert sorted((e.kind, e.handle) for e in presses) == [("press", 0), ("press", 1)]
    assert [e.kind for e in events[2] + events[3]] == []  # hand 0 missing, still within max_missing
    (release,) = events[4]
    assert (release.kind, release.handle) == ("release", 0)
    assert np.allclose([release.x, release.y], pinch_point((200.0, 200.0)), atol=0.01)
    # A third hand pinching takes the freed handle 0; hand 1 keeps handle 1.
    (press,) = run(tracker, [[(1, b), (5, hand((100.0, 100.0), pinched=True))]], start=5)[0]
    assert (press.kind, press.handle) == ("press", 0)
    assert [(e.kind, e.handle) for e in tracker.release_all(1.0)] == [("release", 1), ("release", 0)]


def test_first_handle_and_a_bad_configuration():
    tracker = PinchTracker(PinchConfig(first_handle=3))
    (press,) = run(tracker, [[(0, hand(pinched=True))]])[0]
    assert press.handle == 3
    with pytest.raises(ValueError, match="close_ratio"):
        PinchTracker(PinchConfig(close_ratio=0.5, open_ratio=0.4))
