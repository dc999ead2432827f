"""Landmark correction (seed 002): a few landmarks placed by hand re-fit the whole face (the
other points of the worst-fitted annotated faces get closer to their annotation), and a
correction kept in model space follows the head over a video."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import published_into
from test_landmarks_accuracy import MIN_FACE

from facesculpt.geometry import to_ibug68
from facesculpt.geometry.ibug68 import dlib_annotations
from facesculpt.nodes.fitter.corrections import LandmarkCorrections, fit_id

IBUG = [str(i) for i in range(1, 69)]


def fitted_landmarks(result) -> dict[str, np.ndarray]:
    """iBUG id -> the fitted model's point (pixels) each landmark was matched to."""
    verts, weights = result.correspondences
    points = (result.projected[verts] * weights[..., None]).sum(axis=1)
    return dict(zip(result.correspondence_ids, points))


@pytest.fixture(scope="module")
def annotated(data_dir, models_dir):
    import cv2

    from facesculpt.nodes.landmarks import LandmarkDetector

    detector = LandmarkDetector(max_faces=50, min_face=MIN_FACE)
    out, cache = [], {}
    for split in ("training", "testing"):
        for file, box, truth in dlib_annotations(data_dir / "faces" / f"{split}_with_face_landmarks.xml"):
            if file not in cache:
                image = cv2.imread(str(data_dir / "faces" / file))
                cache[file] = (image.shape, detector.detect(image))
            shape, faces = cache[file]
            centre = box[:2] + box[2:] / 2
            near = [(np.linalg.norm(f.points[:, :2].mean(0) - centre), i) for i, f in enumerate(faces)]
            near = [c for c in near if c[0] < box[2] / 2]
            if near:
                out.append((shape, truth, to_ibug68(faces[min(near)[1]].points).astype(np.float64)))
    return out


@pytest.mark.slow
def test_correcting_three_landmarks_improves_the_other_points(annotated):
    from facesculpt.nodes.fitter import FitterConfig, load_model, make_fitter

    model = load_model("sfm")

    def fit(shape, points, corrections=None):
        h, w = shape[:2]
        K = np.array([[w, 0, w / 2], [0, w, h / 2], [0, 0, 1.0]])
        return make_fitter(model, FitterConfig(), (w, h), K).fit(points, IBUG, corrections=corrections)

    def errors(result, truth):
        got = fitted_landmarks(result)
        iod = np.linalg.norm(truth[36] - truth[45])
        return {k: np.linalg.norm(got[str(k + 1)] - truth[k]) / iod for k in range(68) if str(k + 1) in got}

    scored = []
    for shape, truth, points in annotated:
        e = errors(fit(shape, points), truth)
        scored.append((np.mean(list(e.values())), shape, truth, points, e))
    scored.sort(key=lambda s: -s[0])
    before, after = [], []
    for _, shape, truth, points, e in scored[:5]:  # the five worst-fitted faces
        worst = sorted(e, key=e.get)[-3:]
        corrected = errors(fit(shape, points, {str(k + 1): truth[k] for k in worst}), truth)
        others = [k for k in e if k not in worst]
        before.append(np.mean([e[k] for k in others]))
        after.append(np.mean([corrected[k] for k in others]))
        assert corrected[worst[-1]] < e[worst[-1]] / 2  # the corrected point itself moved there
    print(f"\nNME of the other points, worst five faces: {np.round(before, 4)} -> {np.round(after, 4)}")
    assert all(a < b for a, b in zip(after, before))


@pytest.mark.parametrize("video", ["d3", "d0"])
@pytest.mark.parametrize("model_name", ["sfm", "facemesh"])
@pytest.mark.slow
def test_a_correction_follows_the_head(model_name, video, data_dir, models_dir):
    """Landmark 34 (nose base, centre) is dragged onto the left nostril where the network sees
    iBUG 33, and the fitter uses the correction in every later frame, as the fitter node does;
    while the head turns (d3: fast and expressive; d0: a calmer talking head), the correction's
    target stays near that nostril, within 2 % of the inter-ocular distance (median). Its head
    frame comes from the detected nose and eyes, not from the fit the correction pulls (with the
    fit's own pose the target ran away: the figures printed beside it)."""
    import cv2

    from facesculpt.nodes.camera.intrinsics import intrinsics_from_fov
    from facesculpt.nodes.fitter import FitterConfig, load_model, make_fitter
    from facesculpt.nodes.fitter.corrections import ibug68_points
    from facesculpt.nodes.fitter.stage import fit_landmarks
    from facesculpt.nodes.landmarks import LandmarkDetector

    cap = cv2.VideoCapture(str(data_dir / "video" / f"{video}.mp4"))
    fps = cap.get(cv2.CAP_PROP_FPS) or 30.0
    detector, model = LandmarkDetector(), load_model(model_name)
    frames = []
    while len(frames) < 120:
        ok, frame = cap.read()
        if not ok:
            break
        faces = detector.track(frame)
        frames.append(faces[0].points if faces else None)
        h, w = frame.shape[:2]
    cap.release()
    nose_base = fit_id(34, model.dense)
    figures = {}
    for head_frame in ("detected", "fit"):  # the head's pose: from the detected points, or the fit's own
        fitter = make_fitter(model, FitterConfig(), (w, h), intrinsics_from_fov(w, h, 60.0))
        corrections, last, drift, yaw = LandmarkCorrections(), None, [], []
        for i, points in enumerate(frames):
            if points is None:
                continue
            seen = to_ibug68(points)
            given = points if head_frame == "detected" else None
            targets = corrections.targets(last, given) if len(corrections) else None
            fit = fit_landmarks(fitter, points[None], [1.0], i / fps, 0.5, targets).fit
            iod = np.linalg.norm(seen[36] - seen[45])
            if len(corrections):
                drift.append(np.linalg.norm(targets[nose_base] - seen[32]) / iod)
                yaw.append(fit.yaw_pitch_roll[0])
            elif i == 30 or (i < 30 and np.linalg.norm(ibug68_points(fit, model.dense)[32] - seen[32]) < 0.005 * iod):
                corrections.set(nose_base, seen[32], fit, model, given)  # on a frame where the fit sits still
            last = fit
        figures[head_frame] = (np.median(drift), np.max(drift), np.ptp(yaw))
    (median, worst, turned), before = figures["detected"], figures["fit"]
    print(f"\n{video} {model_name}: corrected point vs the nostril, % IOD: median {100 * median:.2f}, max "
          f"{100 * worst:.2f} (head frame of the corrected fit: median {100 * before[0]:.2f}, max {100 * before[1]:.2f})")
    assert turned > 2  # the head turned while the correction was kept (degrees of yaw)
    assert median < 0.02 and worst < 0.05
    assert median < before[0]

def test_the_fitter_node_takes_a_correction_from_input_events(monkeypatch, tmp_path, data_dir, models_dir):
    import cv2

    from facesculpt.msgs import FaceLandmarks, InputEvent
    from facesculpt.nodes.fitter.node import FitterNode
    from facesculpt.nodes.landmarks import LandmarkDetector

    monkeypatch.setenv("FACESCULPT_RUN_DIR", str(tmp_path / "run"))
    detector = LandmarkDetector()
    cap = cv2.VideoCapture(str(data_dir / "video" / "d0.mp4"))
    msgs = []
    for i in range(8):
        frame = cap.read()[1]
        face = detector.track(frame)[0]
        h, w = frame.shape[:2]
        msgs.append(FaceLandmarks(stamp=10**9 + i * 40_000_000, points=face.points[None], scores=np.array([face.score], np.float32),
                                  rois=face.roi[None], track_ids=np.array([0], np.int32), image_size=[w, h],
                                  K=np.array([[w, 0, w / 2], [0, w, h / 2], [0, 0, 1.0]])))
    cap.release()
    node = FitterNode(params={"model": "sfm"})
    node.setup()
    states = published_into(node.state_pub, [])
    try:
        for m in msgs[:4]:
            node.on_landmarks(m)
        chin = node.last_fits[0]
        names = {str(n): int(v) for n, v in zip(node.model.landmark_names, node.model.landmark_vertices)}
        before = chin.projected[names["9"]].copy()
        target = before + np.array([0.0, 12.0])  # the chin 12 px lower
        node.on_event(InputEvent(kind="command", command="correct_landmark", argument="9",
                                 x=float(target[0]), y=float(target[1])))
        node.on_event(InputEvent(kind="command", command="correct_landmark", argument="99", x=1.0, y=1.0))
        for m in msgs[4:]:
            node.on_landmarks(m)
        after = states[-1].projected[names["9"]]
        assert node.counters["landmark_corrected"] == 1 and node.counters["bad_correction"] == 1
        assert np.linalg.norm(after - target) < np.linalg.norm(before - target) / 2
        # The state says which landmarks are corrected and where the fit put all 68 (the window's
        # correction mode draws them); the SFM has no inner mouth corners (61, 65).
        assert states[-1].corrected == [9] and states[3].corrected == []
        assert np.isnan(states[-1].landmarks[[60, 64]]).all() and np.isfinite(states[-1].landmarks[:60]).all()
        assert np.linalg.norm(states[-1].landmarks[8] - after) < 1.0
        node.on_event(InputEvent(kind="command", command="clear_corrections"))
        assert not node.corrections
    finally:
        node.close()


@pytest.mark.parametrize("projection", ["perspective", "orthographic"])
def test_the_head_frame_comes_from_the_detected_points(projection, data_dir, models_dir):
    """A correction set with the frame's detected points is found again at its pixel on that frame,
    moves with the detected points (shifted 12 px right and 5 px down, so does the target), and
    does not move when only the fit is pulled elsewhere (the fit's pose is not its head frame)."""
    import cv2

    from facesculpt.nodes.fitter import FitterConfig, load_model, make_fitter
    from facesculpt.nodes.landmarks import LandmarkDetector

    frame = cv2.VideoCapture(str(data_dir / "video" / "d0.mp4")).read()[1]
    h, w = frame.shape[:2]
    points = LandmarkDetector().detect(frame)[0].points.astype(np.float64)
    model = load_model("sfm")
    fitter = make_fitter(model, FitterConfig(projection=projection), (w, h),
                         np.array([[w, 0, w / 2], [0, w, h / 2], [0, 0, 1.0]]))
    fit = fitter.fit(to_ibug68(points), IBUG)
    corrections = LandmarkCorrections()
    xy = to_ibug68(points)[8] + [4.0, 9.0]  # the chin, a little off
    corrections.set("9", xy, fit, model, points)
    assert corrections.ibug(dense=False) == [9]
    assert np.linalg.norm(corrections.targets(fit, points)["9"] - xy) < 0.05
    moved = points.copy()
    moved[:, :2] += [12.0, 5.0]
    # (under perspective a shift of the picture is nearly a sideways move of the head: within 1 px)
    assert np.linalg.norm(corrections.targets(fit, moved)["9"] - (xy + [12.0, 5.0])) < 1.0
    pulled = fitter.fit(to_ibug68(moved), IBUG, corrections={"9": xy + [12.0, 40.0]})  # a fit pulled far off
    assert np.linalg.norm(corrections.targets(pulled, moved)["9"] - (xy + [12.0, 5.0])) < 1.0
    corrections.clear()
    assert not len(corrections) and corrections.reference is None
