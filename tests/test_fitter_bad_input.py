"""Bad input to the fitter is refused with FitError (a ValueError) saying what is wrong."""

from __future__ import annotations

import numpy as np
import pytest

from benchmarks.synthetic_faces import make_face
from facesculpt.nodes.fitter import FitError, FitterConfig, load_model, make_fitter


@pytest.fixture(scope="module")
def sfm(data_dir):
    return load_model("sfm")


@pytest.fixture(scope="module")
def face(sfm):
    return make_face(sfm, np.random.default_rng(4), yaw=10.0)


def test_nan_and_too_few_landmarks_are_refused(sfm, face):
    fitter = make_fitter(sfm, FitterConfig(), (640, 480))
    with pytest.raises(FitError, match="only 0 usable landmarks"):
        fitter.fit(np.full((68, 2), np.nan), face.ids)
    few = face.noisy.copy()
    few[np.arange(68) > 22] = np.nan  # outline + brows + part of the nose only
    with pytest.raises(FitError, match="at least 6"):
        fitter.fit(np.r_[few[:17], np.full((51, 2), np.nan)], face.ids)
    # Some NaN among many is fine: those points are ignored.
    partial = face.noisy.copy()
    partial[[30, 36, 45, 48]] = np.nan
    r = fitter.fit(partial, face.ids)
    assert np.isfinite(r.vertices).all() and r.residual_px < 3


def test_degenerate_configurations_are_refused(sfm, face):
    fitter = make_fitter(sfm, FitterConfig(), (640, 480))
    line = np.column_stack([np.linspace(100, 400, 68), np.full(68, 200.0)])
    with pytest.raises(FitError, match="collinear"):
        fitter.fit(line, face.ids)
    same = np.tile([[300.0, 200.0]], (68, 1))
    with pytest.raises(FitError, match="collinear|coincide"):
        fitter.fit(same, face.ids)


def test_bad_arguments_are_refused(sfm, face):
    for size in ((0, 480), (640, 0), (-1, 5), "big", None):
        with pytest.raises(FitError, match="image_size"):
            make_fitter(sfm, FitterConfig(), size)
    with pytest.raises(FitError, match="intrinsics"):
        make_fitter(sfm, FitterConfig(), (640, 480), K=np.zeros((3, 3)))
    with pytest.raises(FitError, match="needs the intrinsics"):
        make_fitter(sfm, FitterConfig(projection="perspective"), (640, 480))
    fitter = make_fitter(sfm, FitterConfig(), (640, 480))
    with pytest.raises(FitError, match=r"\(N, 2\)"):
        fitter.fit(np.zeros((68,)), face.ids)
    with pytest.raises(FitError, match="68 points but 3 ids"):
        fitter.fit(face.noisy, ["1", "2", "3"])
    with pytest.raises(FitError, match="ids are needed"):
        fitter.fit(face.noisy[:30])
    # Unknown ids are ignored, not guessed at.
    with pytest.raises(FitError, match="usable landmarks"):
        fitter.fit(face.noisy, [f"x{i}" for i in range(68)])
    assert issubclass(FitError, ValueError)
