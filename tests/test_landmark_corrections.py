"""Landmark correction (seed 002): a few landmarks placed by hand re-fit the whole face (the
other points of the worst-fitted annotated faces get closer to their annotation), and a
correction kept in model space follows the head over a video."""

from __future__ import annotations

import numpy as np
import pytest
from test_landmarks_accuracy import MIN_FACE, _annotations

from facesculpt.geometry import to_ibug68
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
        for file, box, truth in _annotations(data_dir / "faces" / f"{split}_with_face_landmarks.xml"):
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


@pytest.mark.parametrize("model_name", ["sfm", "facemesh"])
def test_a_correction_follows_the_head(model_name, data_dir, models_dir):
    """Landmark 34 (nose base, centre) is dragged onto the left nostril where the network sees
    iBUG 33; while the head turns, the corrected point stays near that nostril (the fit's own
    landmark 33 against the network's is printed beside it)."""
    import cv2

    from facesculpt.app.pipeline import Pipeline

    cap = cv2.VideoCapture(str(data_dir / "video" / "d3.mp4"))
    corrections = LandmarkCorrections()
    drift, fit_error, yaw = [], [], []
    with Pipeline(model_name) as pipeline:
        for i in range(120):
            ok, frame = cap.read()
            assert ok
            fits = pipeline.fit_faces(frame, i / 30.0)
            seen = to_ibug68(pipeline.detector._faces()[0].points)
            model = pipeline.faces.fitters[0].model
            names = {str(n): int(v) for n, v in zip(model.landmark_names, model.landmark_vertices)}
            nose_base, nostril = fit_id(34, model.dense), fit_id(33, model.dense)
            iod = np.linalg.norm(seen[36] - seen[45])
            still = i == 30 or (i < 30 and np.linalg.norm(fits[0].projected[names[nostril]] - seen[32]) < 0.005 * iod)
            if not len(corrections) and still:  # a person corrects on a frame where the fit sits still
                corrections.set(nose_base, seen[32], fits[0], model)
            elif len(corrections):
                drift.append(np.linalg.norm(corrections.targets(fits[0])[nose_base] - seen[32]) / iod)
                fit_error.append(np.linalg.norm(fits[0].projected[names[nostril]] - seen[32]) / iod)
                yaw.append(fits[0].yaw_pitch_roll[0])
    cap.release()
    print(f"\n{model_name}: corrected point vs the nostril, % IOD: median {100 * np.median(drift):.2f}, "
          f"max {100 * np.max(drift):.2f}; the fit's own landmark: median {100 * np.median(fit_error):.2f}")
    assert np.ptp(yaw) > 5  # the head turned while the correction was kept
    # The head's frame carries the correction; what the face does within it (d3 is expressive)
    # and the fit's own lag add to the distance.
    assert np.median(drift) < 0.04 and np.max(drift) < 0.08


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
    states = []
    node.state_pub.publish = lambda m, _o=node.state_pub.publish: (states.append(m), _o(m))[1]
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
