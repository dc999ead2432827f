"""Biharmonic interpolation from control vertices (the coded expression basis, issue 19): exact at
the controls, constants kept, a smooth field over a real face mesh recovered from a fifth of its
vertices, and bad controls refused."""

from __future__ import annotations

import numpy as np
import pytest

from facesculpt.geometry.biharmonic import biharmonic_interpolation, control_values, farthest_point_samples


def _grid(n: int = 12):
    """An n x n vertex grid of triangles over [0, 1]^2: (V, 2) points, (T, 3) triangles."""
    xs, ys = np.meshgrid(np.linspace(0, 1, n), np.linspace(0, 1, n))
    points = np.column_stack([xs.ravel(), ys.ravel()])
    tris = []
    for r in range(n - 1):
        for c in range(n - 1):
            i = r * n + c
            tris += [[i, i + 1, i + n], [i + 1, i + n + 1, i + n]]
    return points, np.array(tris)


def test_farthest_points_are_distinct_and_spread():
    points, _ = _grid()
    ids = farthest_point_samples(points, 20)
    assert ids[0] == 0 and len(set(ids.tolist())) == 20
    gaps = np.linalg.norm(points[ids][:, None] - points[ids][None], axis=2) + np.eye(20) * 9
    assert gaps.min() > 0.15  # 20 points on a unit square: none bunched up
    assert len(farthest_point_samples(points, 10_000)) == len(points)


def test_interpolation_is_exact_at_controls_keeps_constants_and_is_smooth():
    points, tris = _grid()
    ids = farthest_point_samples(points, 30)
    H = biharmonic_interpolation(tris, len(points), ids)
    np.testing.assert_allclose(H[ids], np.eye(len(ids)), atol=1e-12)
    np.testing.assert_allclose(H.sum(axis=1), 1.0, atol=1e-6)  # a constant field stays constant
    field = np.sin(2 * points[:, 0]) + points[:, 1] ** 2     # smooth: recovered from 30 of 144 vertices
    back = H @ control_values(H, field)
    assert np.sqrt(((back - field) ** 2).mean()) < 0.02 * np.ptp(field)  # (the border, less held, a little more)
    assert np.abs(back - field).max() < 0.06 * np.ptp(field)


def test_a_face_expression_is_recovered_from_a_hundred_vertices(models_dir):
    from facesculpt.app.pipeline import load_face_model

    model = load_face_model("facemesh")
    pts = np.asarray(model.mean, np.float64)
    # a smooth "smile": the lower face pulled up and out, more at the sides (mm)
    lower = np.clip((pts[:, 1].max() - pts[:, 1]) / np.ptp(pts[:, 1]), 0, 1)
    field = np.column_stack([0.2 * pts[:, 0] * lower, 3.0 * lower ** 2, np.zeros(len(pts))])
    ids = farthest_point_samples(pts, 100)
    H = biharmonic_interpolation(model.triangles, len(pts), ids)
    err = np.linalg.norm(H @ control_values(H, field) - field, axis=1)
    assert np.sqrt((err ** 2).mean()) < 0.05 * np.sqrt((field ** 2).sum(1).mean()), err.max()


def test_bad_controls_are_refused():
    points, tris = _grid(4)
    for ids in ([], [0, 0], [-1], [16]):
        with pytest.raises(ValueError, match="distinct indices"):
            biharmonic_interpolation(tris, 16, np.array(ids, np.int64))
