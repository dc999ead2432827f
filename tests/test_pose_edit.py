"""Pose edits (issue 18): the offset's geometry, the compositor carrying the face's motion over
the head, and `facesculpt process --pose` turning a real head by about the angle asked for."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from facesculpt.geometry.head_angles import euler_from_rotation, rotation_from_euler
from facesculpt.geometry.pose_offset import (
    PoseOffset,
    apply_pose_offset,
    face_camera_offset,
    head_pivot,
    parse_pose_offset,
    posed_rotation,
    smooth_offset,
)

REPO = Path(__file__).resolve().parent.parent


# -- the offset ------------------------------------------------------------------------------------
def test_parse_reads_every_field_and_refuses_in_one_sentence():
    assert parse_pose_offset("yaw=10, pitch=-5,z=20") == PoseOffset(yaw=10, pitch=-5, z=20)
    assert parse_pose_offset("").is_zero
    for bad, says in (("yaw10", "NAME=VALUE"), ("tilt=3", "NAME=VALUE"), ("yaw=x", "must be a number"),
                      ("yaw=60", "±45 degrees"), ("x=900", "±200 mm")):
        with pytest.raises(ValueError, match=says) as err:
            parse_pose_offset(bad)
        assert "\n" not in str(err.value)


def test_the_offset_adds_to_the_heads_own_angles_about_its_pivot():
    rng = np.random.default_rng(3)
    model = rng.normal(0, 40, (50, 3))
    pivot = np.array([0.0, 5.0, -90.0])
    R, t = rotation_from_euler(18, -7, 4), np.array([20.0, -10.0, 520.0])
    cam = model @ R.T + t
    offset = PoseOffset(yaw=10, pitch=5, roll=-3, x=4, y=-2, z=30)
    moved = apply_pose_offset(cam, R, t, 1.0, pivot, offset)
    R2 = posed_rotation(R, offset)
    assert euler_from_rotation(R2) == pytest.approx((28, -2, 1))
    # the same head posed at the new angles, turned about the pivot, then moved
    expected = (model - pivot) @ R2.T + R @ pivot + t + [4, -2, 30]
    assert np.abs(moved - expected).max() < 1e-9
    assert np.array_equal(apply_pose_offset(cam, R, t, 1.0, pivot, PoseOffset()), cam)


def test_head_pivot_lies_behind_the_foremost_point():
    V = np.array([[-70.0, -80, -100], [70, 100, 5], [0, 10, -20]])
    assert head_pivot(V) == pytest.approx([0.0, 10.0, 5 - 95.0])


def test_face_camera_turns_a_face_onto_the_ray_to_the_camera_and_smooths():
    pivot = np.array([0.0, 0.0, -90.0])
    R, t = rotation_from_euler(20, -8, 5), np.array([60.0, -30.0, 500.0])
    full = face_camera_offset(R, t, 1.0, pivot, 1.0, 45.0)
    facing = posed_rotation(R, full)[:, 2]
    centre = R @ pivot + t
    assert np.dot(facing, -centre / np.linalg.norm(centre)) > 0.9999
    assert euler_from_rotation(posed_rotation(R, full))[2] == pytest.approx(5.0)  # roll kept
    half = face_camera_offset(R, t, 1.0, pivot, 0.5, 45.0)
    assert half.yaw == pytest.approx(0.5 * full.yaw) and half.pitch == pytest.approx(0.5 * full.pitch)
    clamped = face_camera_offset(R, t, 1.0, pivot, 1.0, 5.0)
    assert abs(clamped.yaw) == pytest.approx(5.0) and abs(clamped.pitch) <= 5.0
    step = smooth_offset(PoseOffset(), PoseOffset(yaw=10), 0.1, 0.3)
    assert 0 < step.yaw < 10
    assert smooth_offset(step, PoseOffset(yaw=10), 5.0, 0.3).yaw == pytest.approx(10, abs=1e-5)


# -- the compositor ----------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def turned(data_dir):
    """Frame 0 of d0 with the SFM mean posed on it, rendered with the head turned 12° of yaw,
    with and without head_motion."""
    from benchmarks.renderer_scene import place_marked, read_frames
    from facesculpt.nodes.fitter import load_model
    from facesculpt.nodes.renderer import Compositor

    frame = read_frames(data_dir, "d0")[0]
    p = place_marked(load_model("sfm"), "d0")
    t = p.fitted.mean(axis=0) - p.R @ p.rest.mean(axis=0)
    deformed = apply_pose_offset(p.fitted, p.R, t, 1.0, head_pivot(p.rest), PoseOffset(yaw=12))
    out = {}
    with Compositor(frame.shape[1], frame.shape[0]) as comp:
        for head in (False, True):
            out[head] = comp.render(frame, p.fitted, p.projected, p.triangles, deformed, head_motion=head)
            out[head, "regions"] = comp.full_frame_regions()
        out["band"] = comp.band_px(p.projected)
    return frame, p, out


def test_head_motion_moves_the_head_around_the_face_and_nothing_far_away(turned):
    frame, p, out = turned
    lo, hi = p.projected.min(axis=0), p.projected.max(axis=0)
    face = out[False, "regions"]["original"] | out[False, "regions"]["deformed"]
    # without head motion the face's motion still reaches the outline band past it (outline_band)
    side = 2 * (out["band"] + 4) + 1
    grown = cv2.dilate(face.astype(np.uint8), np.ones((side, side), np.uint8)).astype(bool)
    # the band above the face (forehead, hair) that neither face region touches
    band = np.zeros(face.shape, bool)
    band[max(0, int(lo[1] - 0.3 * (hi[1] - lo[1]))):int(lo[1]), int(lo[0]):int(hi[0])] = True
    band &= ~grown
    diff = {h: np.abs(out[h].astype(int) - frame.astype(int)).max(axis=2) for h in (False, True)}
    assert band.sum() > 500
    assert (diff[False][band] == 0).all()          # without it the hair stays where it was
    assert (diff[True][band] > 8).mean() > 0.05     # with it the hair turns with the face
    far = np.ones(face.shape, bool)
    far[max(0, int(lo[1] - 0.7 * (hi[1] - lo[1]))):int(hi[1] + 0.5 * (hi[1] - lo[1])),
        max(0, int(lo[0] - 0.4 * (hi[0] - lo[0]))):int(hi[0] + 0.4 * (hi[0] - lo[0]))] = False
    assert far.sum() > 1000 and (diff[True][far] == 0).all()


def test_the_extended_motion_continues_the_faces_offsets_across_its_outline():
    from facesculpt.nodes.renderer.motion_extension import extend_motion
    from facesculpt.nodes.renderer.source_map import UNCOVERED

    h, w = 120, 160
    ys, xs = np.mgrid[:h, :w]
    covered = (xs - 80) ** 2 / 30 ** 2 + (ys - 60) ** 2 / 40 ** 2 <= 1
    offsets = np.full((h, w, 2), UNCOVERED, np.float32)
    offsets[covered] = np.stack([3.0 + 0.02 * xs, -2.0 + 0.01 * ys], -1)[covered]
    head = ((xs - 80) ** 2 / 70 ** 2 + (ys - 55) ** 2 / 58 ** 2 <= 1).astype(np.uint8)
    ext = extend_motion(offsets, head)
    assert np.array_equal(ext[covered], offsets[covered])
    ring = cv2.dilate(covered.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool) & ~covered
    inner = cv2.dilate(ring.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool) & covered
    assert np.abs(np.linalg.norm(ext[ring], axis=1).mean() - np.linalg.norm(offsets[inner], axis=1).mean()) < 0.3
    edge = head.astype(bool) & ~cv2.erode(head, np.ones((3, 3), np.uint8)).astype(bool)
    assert np.abs(ext[edge]).max() < 0.3           # faded out at the head region's border
    assert (ext[~head.astype(bool) & ~covered] == UNCOVERED).all()


def _folded_face(h: int = 120, w: int = 160):
    """A face ellipse whose left rim (x < 58) spans 4 input pixels an output pixel (the mesh folding
    away from the camera), the head region around it."""
    from facesculpt.nodes.renderer.source_map import UNCOVERED

    ys, xs = np.mgrid[:h, :w]
    covered = (xs - 80) ** 2 / 30 ** 2 + (ys - 60) ** 2 / 40 ** 2 <= 1
    offsets = np.full((h, w, 2), UNCOVERED, np.float32)
    offsets[covered] = np.stack([3.0 - 3.0 * np.maximum(0, 58 - xs), -2.0 + 0.01 * ys], -1)[covered]
    head = ((xs - 80) ** 2 / 70 ** 2 + (ys - 55) ** 2 / 58 ** 2 <= 1).astype(np.uint8)
    return offsets, covered, head, xs


def test_a_folded_outline_is_not_stretched_over_the_head_and_a_plain_one_is_continued():
    from facesculpt.nodes.renderer.motion_extension import extend_behind_outline, extend_motion, source_compression
    from facesculpt.nodes.renderer.source_map import UNCOVERED

    offsets, covered, head, xs = _folded_face()
    assert source_compression(offsets, covered)[60, 52] > 3.9 and abs(source_compression(offsets, covered)[60, 80] - 1) < 0.1
    before = extend_motion(offsets, head)
    after, behind = extend_behind_outline(offsets, head, 4.0)
    assert np.array_equal(after[covered], offsets[covered])      # the face's own offsets (its silhouette) kept
    # the 12 px left of the folded outline: before, they sampled a strip of the input a few pixels wide
    # (the source running back and forth: the streak); now about a pixel of input a pixel
    left = np.arange(37, 49)
    span = {name: np.ptp(left + e[60, left, 0]) for name, e in (("before", before), ("after", after))}
    assert span["before"] < 4 and span["after"] > 9, span
    band = behind[..., 0] < 0.5 * UNCOVERED
    assert band.any() and (band <= covered).all() and xs[band].max() < 64   # only the folded rim has a soft edge
    ring = cv2.dilate(covered.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool) & ~covered
    assert np.abs(after[ring & (xs > 90)] - before[ring & (xs > 90)]).max() < 0.3   # the plain outline: continued
    assert extend_behind_outline(offsets, head, 0.0)[1] is None
    nowhere = np.zeros(covered.shape, bool)       # where the head does not go on past the model, a fold is continued
    assert extend_behind_outline(offsets, head, 4.0, nowhere)[1] is None


def test_the_head_goes_on_past_the_upper_half_of_the_faces_outline():
    from facesculpt.nodes.renderer.motion_extension import HEAD_GOES_ON, head_goes_on

    pixels = np.array([[30.0, 20.0], [90.0, 20.0], [60.0, 120.0]])
    rows = head_goes_on((100, 80), (10, 10), pixels).any(axis=1)
    assert rows.sum() == int(20 + HEAD_GOES_ON * 100) - 10


def test_the_face_is_blended_over_what_lies_behind_its_folded_soft_edge_only():
    from facesculpt.nodes.renderer.motion_extension import over_behind
    from facesculpt.nodes.renderer.source_map import UNCOVERED

    frame = np.zeros((40, 60, 3), np.uint8)
    frame[:, :, 1] = np.arange(60, dtype=np.uint8)[None, :] * 4   # green: 4 x column
    warped = np.full((20, 20, 3), 200, np.uint8)
    behind = np.full((20, 20, 2), UNCOVERED, np.float32)
    behind[:, :5] = (10.0, 0.0)                   # the soft edge's pixels read the frame 10 px to the right
    alpha = np.ones((20, 20), np.float32)
    alpha[:, :5] = np.linspace(0.0, 0.8, 5)[None, :]
    out = warped.copy()
    over_behind(out, frame, behind, alpha, (20, 10), "cubic")
    assert (out[:, 5:] == 200).all()              # no soft edge there: the face's own colour
    assert np.abs(out[:, 0, 1].astype(int) - 4 * 30).max() <= 1   # alpha 0: what lies behind
    mixed = 0.6 * 200 + 0.4 * 4 * 33
    assert np.abs(out[:, 3, 1].astype(int) - mixed).max() <= 2


def test_a_face_stretched_from_the_inputs_outline_is_mended_from_the_face_beside_it():
    from facesculpt.nodes.renderer.silhouette_source import mend, unseen_by_silhouette
    from facesculpt.nodes.renderer.source_map import UNCOVERED

    h, w = 60, 80
    ys, xs = np.mgrid[:h, :w]
    face = (xs >= 10) & (xs < 70) & (ys >= 10) & (ys < 50)
    region = ((xs >= 20) & (xs < 70) & (ys >= 10) & (ys < 50)).astype(np.uint8)   # the input's face: from x = 20
    offsets = np.full((h, w, 2), UNCOVERED, np.float32)
    offsets[face, 0] = 10.0                                   # the inside: read 10 px to the right
    left = face & (xs < 20)
    offsets[left, 0] = (20.0 + 0.2 * (xs[left] - 10)) - xs[left]   # the near side: 10 px read from 2 at x = 20..22
    offsets[face, 1] = 0.0
    unseen = unseen_by_silhouette(offsets, face, region)
    assert unseen[20:40, 11:18].all() and not unseen[:, 25:].any()
    warped = np.zeros((h, w, 3), np.uint8)
    warped[face] = (60, 90, 160)                              # skin
    warped[left] = (220, 220, 220)                            # the outline's mix with a pale wall
    before = warped.copy()
    mend(warped, unseen, face)
    assert np.abs(warped[25:35, 12:17].astype(int) - (60, 90, 160)).max() < 25   # skin, not the pale arc
    assert np.array_equal(warped[:, 25:], before[:, 25:]) and np.array_equal(warped[~face], before[~face])


# -- process --pose --------------------------------------------------------------------------------
def _yaws(frames: list, detector, model) -> list[float]:
    from facesculpt.nodes.fitter import FitterConfig, make_fitter

    out = []
    for frame in frames:
        fitter = make_fitter(model, FitterConfig(), (frame.shape[1], frame.shape[0]))
        detector.reset()
        faces = detector.detect(frame)
        out.append(fitter.fit(faces[0].points).yaw_pitch_roll[0])
    return out


@pytest.mark.slow
def test_process_pose_turns_a_real_head_by_about_the_angle_asked(data_dir, models_dir, tmp_path):
    from facesculpt.nodes.fitter import load_model
    from facesculpt.nodes.landmarks import LandmarkDetector

    video = data_dir / "video" / "d0.mp4"
    done = subprocess.run([sys.executable, "-m", "facesculpt.cli", "process", str(video), "-o",
                           str(tmp_path / "%05d.png"), "--pose", "yaw=12", "--max-frames", "12", "--quiet"],
                          cwd=REPO, capture_output=True, text=True, timeout=180)
    assert done.returncode == 0, done.stderr
    cap = cv2.VideoCapture(str(video))
    inputs = [cap.read()[1] for _ in range(12)]
    cap.release()
    outputs = [cv2.imread(str(tmp_path / f"{i:05d}.png")) for i in (3, 7, 11)]
    detector, model = LandmarkDetector(), load_model("facemesh")
    turn = np.subtract(_yaws(outputs, detector, model), _yaws([inputs[i] for i in (3, 7, 11)], detector, model))
    assert 8.0 < turn.mean() < 16.0, turn  # the refit sees the turned head
    corner = (slice(0, 40), slice(0, 40))
    assert all(np.array_equal(o[corner], inputs[i][corner]) for o, i in zip(outputs, (3, 7, 11)))


@pytest.mark.slow
def test_process_refuses_a_bad_pose_before_writing_anything(data_dir, tmp_path):
    for args, says in ((["--pose", "yaw=90"], "±45 degrees"), (["--face-camera", "2"], "0 to 1")):
        done = subprocess.run([sys.executable, "-m", "facesculpt.cli", "process", str(data_dir / "video" / "d0.mp4"),
                               "-o", str(tmp_path / "out.mp4"), *args], cwd=REPO, capture_output=True, text=True,
                              timeout=60)
        assert done.returncode != 0 and says in done.stderr, done.stderr
        assert not list(tmp_path.iterdir())


@pytest.mark.slow
def test_a_presets_pose_turns_the_head_in_process_as_pose_does(data_dir, models_dir, tmp_path):
    preset = tmp_path / "turn.json"
    preset.write_text('{"format": "facesculpt-deformer-preset", "version": 1, "units": "mm", "static": [], '
                      '"edits": [], "pose": {"yaw": 12}}')
    video = data_dir / "video" / "d0.mp4"
    outs = {}
    for name, args in (("preset", ["--edits", str(preset)]), ("pose", ["--pose", "yaw=12"])):
        done = subprocess.run([sys.executable, "-m", "facesculpt.cli", "process", str(video), "-o",
                               str(tmp_path / name / "%05d.png"), "--max-frames", "6", "--quiet", *args],
                              cwd=REPO, capture_output=True, text=True, timeout=180)
        assert done.returncode == 0, done.stderr
        outs[name] = cv2.imread(str(tmp_path / name / "00005.png")).astype(int)
    cap = cv2.VideoCapture(str(video))
    frame = [cap.read()[1] for _ in range(6)][-1].astype(int)
    cap.release()
    turned = np.abs(outs["pose"] - frame).max(axis=2) > 8
    assert turned.mean() > 0.05
    # the same turn (the pivot comes from a neutral learned over more frames with the preset)
    assert np.abs(outs["preset"] - outs["pose"])[turned].mean() < 0.25 * np.abs(outs["pose"] - frame)[turned].mean()


# -- keyframes (image-based rendering) -------------------------------------------------------------
def test_keyframe_views_keep_distinct_poses_and_choose_the_closest_better_view():
    from facesculpt.nodes.renderer.keyframe_views import KeyframeViews, rotation_angle_deg

    rng = np.random.default_rng(5)
    head = rng.normal(0, 50, (80, 3))
    at = {yaw: head @ rotation_from_euler(yaw, 0, 0).T + [0, 0, 500] for yaw in (-20, -12, -10, 0, 2, 9)}
    assert rotation_angle_deg(at[0], at[-12]) == pytest.approx(12, abs=1e-6)
    image = np.zeros((200, 300, 3), np.uint8)
    px = rng.uniform(50, 150, (80, 2))
    views = KeyframeViews(spacing_deg=5, max_keyframes=3, refresh_frames=100)
    stored = [views.offer(image, at[y], px, np.ones(80, np.float32)) for y in (0, 2, -12, -10, 9, -20)]
    assert stored == [True, False, True, False, True, True]   # within 5 degrees of one kept: not kept
    assert len(views.keyframes) == 3 and views.keyframes[0].frame == 3   # the oldest (yaw 0) made room
    assert views.keyframes[0].image.shape[:2] != image.shape[:2]          # a crop around the face is kept
    # rendering the head at yaw -11 from a frame at yaw 0: the view at -12 is the closest
    assert views.choose(at[0], at[-10]).frame == 3
    assert views.choose(at[-10], at[-10]) is None                       # no turn: the frame itself


def test_a_keyframe_is_sampled_at_its_own_pixels_and_blended_where_the_frame_sees_badly(data_dir):
    """A keyframe that is the frame itself seen from the rendered view changes nothing; one whose
    colours are shifted shows the shift on the turned face's sides, never elsewhere."""
    from benchmarks.renderer_scene import place_marked, read_frames
    from facesculpt.nodes.fitter import load_model
    from facesculpt.nodes.renderer import Compositor
    from facesculpt.nodes.renderer.keyframe_views import Keyframe, KeyframeViews

    frame = read_frames(data_dir, "d0")[0]
    p = place_marked(load_model("sfm"), "d0")
    t = p.fitted.mean(axis=0) - p.R @ p.rest.mean(axis=0)
    deformed = apply_pose_offset(p.fitted, p.R, t, 1.0, head_pivot(p.rest), PoseOffset(yaw=15))
    with Compositor(frame.shape[1], frame.shape[0]) as plain:
        base = plain.render(frame, p.fitted, p.projected, p.triangles, deformed, head_motion=True)
    out = {}
    for shift in (0, 40):
        with Compositor(frame.shape[1], frame.shape[0], keyframes=True) as comp:
            shifted = frame.astype(int)
            shifted[..., 0] = np.minimum(shifted[..., 0] + shift, 255)
            views = comp.views[0] = KeyframeViews()
            views.keyframes.append(Keyframe(shifted.astype(np.uint8)[10:, 20:], (20, 10), deformed.copy(),
                                            p.projected.copy(), np.ones(len(deformed), np.float32), 0))
            out[shift] = comp.render(frame, p.fitted, p.projected, p.triangles, deformed, head_motion=True)
            assert comp.keyframe_used == 0
            changed = comp.full_frame_regions()["changed"]
    assert np.abs(out[0].astype(int) - base.astype(int)).max() <= 1
    blue = out[40][..., 0].astype(int) - base[..., 0].astype(int)
    green = np.abs(out[40][..., 1].astype(int) - base[..., 1].astype(int))
    assert (blue[~changed] == 0).all() and green.max() <= 1
    assert (blue[changed] >= 30).sum() > 500     # where the frame sees the turned surface badly
    assert (blue[changed] <= 1).sum() > 500      # the front of the face, seen well, stays the frame's
