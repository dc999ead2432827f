"""New views that know their limits (issue 51, facesculpt/nodes/renderer/pose_limit.py): the share of a turn a
frame takes falls as the turn reveals surface nobody saw, smoothly, and stored views raise it;
`process` says so in one line."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

from facesculpt.nodes.renderer.pose_limit import PoseLimiter, bounded_share, frontality, unknown_share


def _half_cylinder():
    """A half cylinder (radius 80 mm, 160 mm high) facing a camera 500 mm away: (V, 3), (T, 3)."""
    a, y = np.meshgrid(np.linspace(-np.pi / 2, np.pi / 2, 25), np.linspace(-80, 80, 9))
    X = np.column_stack([80 * np.sin(a).ravel(), y.ravel(), 500 - 80 * np.cos(a).ravel()])
    idx = np.arange(X.shape[0]).reshape(a.shape)
    q = np.stack([idx[:-1, :-1], idx[:-1, 1:], idx[1:, 1:], idx[1:, :-1]], -1).reshape(-1, 4)
    return X, np.concatenate([q[:, [0, 1, 2]], q[:, [0, 2, 3]]])


def _yaw(X, deg):
    c, s = np.cos(np.radians(deg)), np.sin(np.radians(deg))
    centre = np.array([0.0, 0.0, 500.0])
    return (X - centre) @ np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]]).T + centre


def test_frontality_faces_the_camera_and_the_unknown_share_grows_with_the_turn():
    X, T = _half_cylinder()
    front, sign = frontality(X, T, True)
    assert front[X[:, 0].argmin()] < 0.2 < 0.9 < front[np.abs(X[:, 0]).argmin()]
    areas = np.ones(len(X))
    shares = [unknown_share(frontality(_yaw(X, d), T, True, sign)[0], front, areas) for d in (0, 10, 20, 40)]
    assert shares[0] < 1e-9 and shares[1] < shares[2] < shares[3]
    assert unknown_share(frontality(_yaw(X, 40), T, True, sign)[0], np.ones(len(X)), areas) == 0.0  # all seen


def test_bounded_share_interpolates_and_is_continuous():
    s = np.linspace(0, 1, 5)
    assert bounded_share(np.array([0, 0.01, 0.02, 0.03, 0.04]), s, 0.05) == 1.0
    assert bounded_share(np.array([0, 0.01, 0.02, 0.03, 0.04]), s, 0.025) == pytest.approx(0.625)
    assert bounded_share(np.array([0.1, 0.2, 0.3, 0.4, 0.5]), s, 0.05) == 0.0
    values = [bounded_share(np.array([0, 0.01, 0.02, 0.03, 0.04]), s, b) for b in np.linspace(0.0, 0.05, 51)]
    assert np.all(np.diff(values) >= 0) and np.abs(np.diff(values)).max() < 0.1   # no step


def test_the_limiter_reduces_a_large_turn_smoothly_and_stored_views_lift_it():
    X, T = _half_cylinder()
    lim = PoseLimiter()
    small = lim.bound(X, T, lambda s: _yaw(X, 5 * s), True)
    large = lim.bound(X, T, lambda s: _yaw(X, 40 * s), True)
    assert small == 1.0 and 0.0 < large < 1.0
    seen = lim.bound(X, T, lambda s: _yaw(X, 40 * s), True, known=np.ones(len(X)))
    assert seen == 1.0
    shares = [lim.share(0, t / 25, X, T, lambda s: _yaw(X, 40 * s), True) for t in range(3)]
    assert shares[0] == pytest.approx(large) and lim.reduced == 3 and lim.lowest == pytest.approx(large)
    up = [lim.share(0, 3 / 25 + t / 25, X, T, lambda s: _yaw(X, 5 * s), True) for t in range(1, 4)]
    assert large < up[0] < up[1] < up[2] < 1.0       # it rises back gradually, no jump


@pytest.mark.slow
def test_process_warns_in_one_line_when_the_turn_is_reduced(data_dir, models_dir, tmp_path):
    out = tmp_path / "o.mp4"
    r = subprocess.run([sys.executable, "-m", "facesculpt.cli", "process", str(data_dir / "video" / "d3.mp4"),
                        "-o", str(out), "--pose", "yaw=25", "--max-frames", "4", "--quiet"],
                       capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr
    warnings = [line for line in r.stderr.splitlines() if "warning: the turn was reduced" in line]
    assert len(warnings) == 1 and "--pose-limit off" in warnings[0]
    r = subprocess.run([sys.executable, "-m", "facesculpt.cli", "process", str(data_dir / "video" / "d3.mp4"),
                        "-o", str(out), "--pose", "yaw=25", "--max-frames", "4", "--quiet", "--pose-limit", "off"],
                       capture_output=True, text=True, timeout=600)
    assert r.returncode == 0 and "reduced" not in r.stderr
