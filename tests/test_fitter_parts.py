"""The fitter's pure parts: poses, least squares, barycentric outline points, One Euro filter."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import lsq_linear

from facesculpt.geometry.projection import project, project_orthographic
from facesculpt.nodes.fitter import fitting, pose
from facesculpt.nodes.fitter.outline import closest_point_barycentric
from facesculpt.nodes.fitter.smoothing import OneEuroFilter


def _points(n=40, seed=0):
    return np.random.default_rng(seed).normal(size=(n, 3)) * [60, 70, 30]


def test_scaled_orthographic_pose_is_recovered_exactly_and_from_a_warm_start():
    X = _points()
    R = pose.rotation_from_euler(-35, 12, 4)
    t = np.array([320.0, 240.0, 0.0])
    x = project_orthographic(X, R, t, 1.7)
    R2, t2, s2 = pose.scaled_orthographic(X, x)
    np.testing.assert_allclose(R2, R, atol=1e-9)
    np.testing.assert_allclose(t2, t, atol=1e-7)
    assert s2 == pytest.approx(1.7)
    R3, _, s3 = pose.scaled_orthographic(X, x, init=(pose.rotation_from_euler(-20, 0, 0), 1.0))
    np.testing.assert_allclose(R3, R, atol=1e-7)
    assert pose.euler_from_rotation(R) == pytest.approx((-35, 12, 4))


def test_perspective_pose_is_recovered_exactly():
    X = _points(seed=1)
    R = pose.rotation_from_euler(25, -10, -3)
    t = np.array([15.0, -20.0, 700.0])
    K = np.array([[900.0, 0, 330], [0, 880.0, 250], [0, 0, 1]])
    x = project(X @ R.T + t, K)
    R2, t2 = pose.perspective(X, x, K)
    np.testing.assert_allclose(R2, R, atol=1e-8)
    np.testing.assert_allclose(t2, t, atol=1e-5)
    J = pose.projection_jacobian((X @ R.T + t)[:2], K)
    eps = 1e-4
    for k in range(3):
        d = np.zeros(3)
        d[k] = eps
        num = (project((X @ R.T + t)[:2] + d, K) - project((X @ R.T + t)[:2] - d, K)) / (2 * eps)
        np.testing.assert_allclose(J[:, :, k], num, rtol=1e-6, atol=1e-8)


def test_similarity_procrustes_and_rotation_helpers():
    A = _points(seed=2)
    R = pose.rotation_from_euler(40, 20, 10)
    B = 2.5 * A @ R.T + [1, 2, 3]
    s, R2, t = pose.similarity_procrustes(A, B)
    assert s == pytest.approx(2.5)
    np.testing.assert_allclose(R2, R, atol=1e-10)
    w = np.array([0.1, 0.2, 3.0])
    for omega in (np.zeros(3), w, np.array([0.0, 3.1, 0.0])):
        np.testing.assert_allclose(pose.rotation_log(pose.rodrigues(omega)), omega, atol=1e-6)
    with pytest.raises(pose.PoseError, match="collinear"):
        line = np.outer(np.arange(10.0), [1, 2, 3])
        pose.scaled_orthographic(line, line[:, :2])


def test_joint_solution_is_the_bounded_least_squares_optimum():
    rng = np.random.default_rng(3)
    As, Ae = rng.normal(size=(60, 8)), rng.normal(size=(60, 4))
    b = rng.normal(size=60) * 3
    ls, le = 0.7, 1.3
    lower, upper = np.zeros(4), np.full(4, np.inf)
    alpha, beta = fitting.solve_joint(As, Ae, b, ls, le, lower=lower, upper=upper)
    # Reference: the stacked regularised system with bounds on beta only.
    M = np.block([[As, Ae], [np.sqrt(ls) * np.eye(8), np.zeros((8, 4))], [np.zeros((4, 8)), np.sqrt(le) * np.eye(4)]])
    ref = lsq_linear(M, np.r_[b, np.zeros(12)], bounds=(np.r_[np.full(8, -np.inf), lower], np.r_[np.full(8, np.inf), upper]),
                     tol=1e-12).x
    np.testing.assert_allclose(np.r_[alpha, beta], ref, atol=1e-6)
    assert (beta >= 0).all() and (beta == 0).any()  # a bound is active for this data
    # Alternating one block at a time converges to the same point.
    a, e = np.zeros(8), np.zeros(4)
    for _ in range(300):
        e = fitting.solve_regularised(Ae, b - As @ a, le, lower=lower, upper=upper)
        a = fitting.solve_regularised(As, b - Ae @ e, ls)
    np.testing.assert_allclose(np.r_[a, e], ref, atol=1e-5)


def test_identity_accumulator_weights_fade_and_cap():
    acc = fitting.IdentityAccumulator(2, decay=0.5, max_frames=1.5)
    A = np.eye(2)
    acc.add(A, np.ones(2))
    acc.add(A, np.ones(2))
    np.testing.assert_allclose(acc.H, 1.5 * np.eye(2))  # 0.5 * first + second
    acc.add(A, np.ones(2))  # 1.75 frames' worth, capped to 1.5
    assert acc.weight == pytest.approx(1.5)
    np.testing.assert_allclose(acc.H, 1.5 * np.eye(2))
    np.testing.assert_allclose(acc.g, 1.5 * np.ones(2))


def test_closest_point_barycentric_inside_outside_and_degenerate():
    a, b, c = np.array([[0.0, 0]]), np.array([[4.0, 0]]), np.array([[0.0, 4]])
    w = closest_point_barycentric(np.array([[1.0, 1.0]]), a, b, c)
    np.testing.assert_allclose(w @ np.r_[a, b, c], [[1.0, 1.0]])
    w = closest_point_barycentric(np.array([[2.0, -3.0]]), a, b, c)  # below edge ab
    np.testing.assert_allclose(w @ np.r_[a, b, c], [[2.0, 0.0]])
    c2 = np.array([[8.0, 0]])  # collinear triangle: falls back to its edges
    w = closest_point_barycentric(np.array([[6.0, 1.0]]), a, b, c2)
    np.testing.assert_allclose(w @ np.r_[a, b, c2], [[6.0, 0.0]])
    assert np.allclose(w.sum(1), 1) and (w >= 0).all()


def test_one_euro_filter_steadies_noise_and_follows_motion():
    rng = np.random.default_rng(0)
    f = OneEuroFilter(min_cutoff=1.0, beta=0.05)
    still = [f(np.array([5.0]) + rng.normal(0, 1, 1), i / 30)[0] for i in range(300)]
    assert np.std(still[60:]) < 0.45  # raw std is 1
    f.reset()
    ramp = [f(np.array([10.0 * i / 30]), i / 30)[0] for i in range(90)]
    assert abs(ramp[-1] - 10.0 * 89 / 30) < 1.0  # lag well under a tenth of a second of motion
    with pytest.raises(ValueError):
        OneEuroFilter(min_cutoff=0)


def test_pose_smoother_rotation_beta_cuts_the_lag_of_a_turn_and_leaves_the_expression_filter():
    from facesculpt.nodes.fitter.config import FitterConfig
    from facesculpt.nodes.fitter.pose_smoothing import PoseSmoother

    def lag_deg(smoother):
        for i in range(50):  # a nod at 0.5 rad/s for 2 s, 25 frames/s
            R = pose.rodrigues(np.array([0.5 * i / 25, 0.0, 0.0])) @ pose.FRONTAL
            Rs, _, _ = smoother.rigid(R, np.zeros(3), 1.0, i / 25)
        return float(np.degrees(np.linalg.norm(pose.rotation_log(Rs @ R.T))))

    shared = PoseSmoother(1.5, 0.5, 0.05, orthographic=False)
    shared_lag = lag_deg(shared)
    shared.reset()
    own = PoseSmoother(1.5, 0.5, 0.05, orthographic=False, beta_rotation=5.0)
    assert lag_deg(own) < 0.5 * shared_lag
    assert lag_deg(PoseSmoother(1.5, 0.5, 0.05, orthographic=False, predict_rotation=0.5)) < 0.5 * shared_lag
    step = [np.zeros(3), np.ones(3)]
    for i, beta in enumerate(step):
        a, b = shared.expression(beta, i / 25), own.expression(beta, i / 25)
    np.testing.assert_allclose(a, b)   # the expression's filter keeps smooth_beta
    with pytest.raises(ValueError, match="smooth_beta_rotation"):
        FitterConfig(smooth_beta_rotation=-1.0)


def test_one_euro_prediction_follows_a_nod_without_lag_and_leaves_a_still_signal_as_it_was():
    def run(predict):
        f = OneEuroFilter(min_cutoff=1.5, beta=0.5, predict_speed=predict)
        nod = [np.radians(16) * np.sin(2 * np.pi * i / 41) for i in range(100)]   # 1.07 rad/s at most
        err = [f(np.array([a]), i / 25)[0] - a for i, a in enumerate(nod)]
        f.reset()
        rng = np.random.default_rng(0)
        still = [f(rng.normal(0, 0.005, 1), i / 25)[0] for i in range(300)]
        return np.sqrt(np.mean(np.square(err[41:]))), np.std(still[25:])

    (lag, noise), (lag_p, noise_p) = run(0.0), run(0.5)
    assert lag_p < 0.5 * lag
    assert noise_p < 1.05 * noise
