"""Landmark accuracy: normalised mean error (NME, outer eye corners) of the iBUG-68 mapping on
the 43 annotated faces of the shared photos, detector run on whole images; largest-face
selection; mesh orientation on real faces; the mapping's table."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from facesculpt.geometry import IBUG68_FROM_MESH, normalised_mean_error, to_ibug68
from facesculpt.geometry.ibug68 import dlib_annotations
from facesculpt.nodes.landmarks import LandmarkDetector

# The photos' faces are as small as 37 pixels in 500-pixel images: look for faces down to 5 %
# of the short side.
MIN_FACE = 0.05


@pytest.fixture(scope="module")
def results(models_dir, data_dir):
    """(split, annotated box, truth (68, 2), matched face or None) for every annotated face."""
    detector = LandmarkDetector(models_dir, max_faces=50, min_face=MIN_FACE)
    cache, out = {}, []
    for split in ("training", "testing"):
        for file, box, truth in dlib_annotations(data_dir / "faces" / f"{split}_with_face_landmarks.xml"):
            if file not in cache:
                cache[file] = detector.detect(cv2.imread(str(data_dir / "faces" / file)))
            centre = box[:2] + box[2:] / 2
            # The nearest detection (mesh centroid) within half the annotated box's size.
            candidates = [(np.linalg.norm(f.points[:, :2].mean(0) - centre), i) for i, f in enumerate(cache[file])]
            candidates = [c for c in candidates if c[0] < box[2] / 2]
            face = cache[file][min(candidates)[1]] if candidates else None
            out.append((split, box, truth, face))
    return out


@pytest.mark.slow
def test_every_annotated_face_is_found(results):
    assert len(results) == 43
    missed = [box.tolist() for _, box, _, face in results if face is None]
    assert not missed


def test_ibug68_nme_is_within_target(results):
    errors = np.array([normalised_mean_error(to_ibug68(face.points), truth) for _, _, truth, face in results])
    held_out = np.array([normalised_mean_error(to_ibug68(face.points), truth)
                         for split, _, truth, face in results if split == "testing"])
    worst = np.sort(errors)[::-1][:5]
    print(f"NME over {len(errors)} faces: mean {errors.mean():.4f}, median {np.median(errors):.4f}, "
          f"worst five {np.round(worst, 4).tolist()}; held-out testing split ({len(held_out)}): "
          f"mean {held_out.mean():.4f}")
    assert errors.mean() <= 0.08
    assert held_out.mean() <= 0.08
    assert worst[0] < 0.2  # no face is a gross failure


def test_the_face_meshs_named_nose_tip_is_the_hand_marked_nose_tip(results):
    """The face mesh's ``nose_tip`` (a preset's handle) is the point people mark as the nose tip
    (iBUG 31), as the Surrey model's is: on average within 6 % of the eye-corner distance of it
    (vertex 1, which it named before, lies below it and fails this)."""
    from facesculpt.nodes.fitter.facemesh_model import FACEMESH_SEMANTIC

    v = FACEMESH_SEMANTIC["nose_tip"]
    errors = [np.linalg.norm(face.points[v, :2] - truth[30]) / np.linalg.norm(truth[36] - truth[45])
              for _, _, truth, face in results if face is not None]
    assert len(errors) >= 40 and np.mean(errors) < 0.06, np.mean(errors)


def test_max_faces_one_returns_the_largest(models_dir, data_dir):
    image = cv2.imread(str(data_dir / "faces" / "2008_002506.jpg"))  # three faces
    all_faces = LandmarkDetector(models_dir, max_faces=10, min_face=MIN_FACE).detect(image)
    assert len(all_faces) >= 3
    one = LandmarkDetector(models_dir, max_faces=1, min_face=MIN_FACE).detect(image)
    assert len(one) == 1
    largest = max(all_faces, key=lambda f: np.ptp(f.points[:, 0]))
    np.testing.assert_allclose(one[0].points, largest.points, atol=1e-3)


def test_mesh_triangles_face_the_camera_on_real_faces(models_dir, results):
    """Triangles from `facesculpt setup` are counter-clockwise on screen for faces seen from the
    front (their 2-D cross product in y-down pixels is negative), except near the silhouette."""
    triangles = np.load(models_dir / "facemesh_triangles.npy")
    fractions = []
    for _, _, _, face in results:
        p = face.points[:, :2].astype(np.float64)
        a, b = p[triangles[:, 1]] - p[triangles[:, 0]], p[triangles[:, 2]] - p[triangles[:, 0]]
        fractions.append(np.mean(a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0] < 0))
    assert np.median(fractions) > 0.9


def test_mapping_is_a_fixed_table_of_distinct_mesh_points():
    assert IBUG68_FROM_MESH.shape == (68,) and len(set(IBUG68_FROM_MESH.tolist())) == 68
    points = np.random.default_rng(0).normal(size=(468, 3)).astype(np.float32)
    np.testing.assert_array_equal(to_ibug68(points), points[IBUG68_FROM_MESH, :2])
    assert to_ibug68(np.stack([points, points])).shape == (2, 68, 2)
    with pytest.raises(ValueError, match="468"):
        to_ibug68(np.zeros((68, 2)))
