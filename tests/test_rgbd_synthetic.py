"""The synthetic RGB-D set's structured-light noise model (benchmarks/realism/depth.py, issue 49):
noise that grows with depth, holes at grazing angles, on dark regions and in the projector's
shadow, disparity quantisation; and the shipped `rgbd` launch file."""

from __future__ import annotations

import numpy as np

from benchmarks.realism.depth import BASELINE_MM, SUBPIXEL, RGBDTruth, projector_shadow, structured_light
from facesculpt.nodes.fitter.node import FitterNode
from facesculpt.paths import launch_file
from facesculpt.runtime.launcher import load_launch

F = 554.0


def _truth(depth: np.ndarray, cos: np.ndarray | None = None) -> RGBDTruth:
    return RGBDTruth(depth, np.ones_like(depth) if cos is None else cos, np.ones(depth.shape, bool),
                     np.zeros((0, 3)), np.eye(3))


def test_noise_grows_with_depth_and_is_quantised_in_disparity():
    rng = np.random.default_rng(0)
    grey = np.full((200, 200), 128.0)
    spread = {}
    for z in (500.0, 1500.0):
        d = structured_light(_truth(np.full((200, 200), z)), grey, F, rng).astype(float)
        ok = d > 0
        assert 0.98 < ok.mean() < 1.0   # a few random dropouts, no more
        spread[z] = float(d[ok].std())
        assert abs(float(d[ok].mean()) - z) < 0.2 * spread[z] + 0.5   # unbiased
    assert 1.0 < spread[500.0] < 2.0 and spread[1500.0] > 2 * spread[500.0], spread
    # at 1.5 m the disparity's 1/8 px step is several mm: only a few depths occur
    d = structured_light(_truth(np.full((50, 50), 1500.0)), np.full((50, 50), 128.0), F, rng)
    values = np.unique(d[d > 0])
    step = 1500.0 ** 2 / (F * BASELINE_MM) * SUBPIXEL
    assert np.median(np.diff(values)) >= step - 1.0 and len(values) < 12


def test_holes_at_grazing_angles_on_dark_regions_and_in_the_projectors_shadow():
    rng = np.random.default_rng(1)
    z = np.full((100, 300), 600.0)
    cos = np.ones_like(z)
    cos[:, :100] = np.cos(np.radians(85.0))   # grazing
    grey = np.full(z.shape, 128.0)
    grey[:, 100:200] = 5.0                     # dark hair
    d = structured_light(_truth(z, cos), grey, F, rng)
    assert (d[:, :100] == 0).mean() > 0.99 and (d[:, 100:200] == 0).mean() > 0.85
    assert (d[:, 200:] == 0).mean() < 0.02
    # a head at 500 mm before a wall at 1400 mm: the wall just right of the head is in shadow
    scene = np.full((10, 400), 1400.0)
    scene[:, 100:200] = 500.0
    shadow = projector_shadow(scene, F)
    width = F * BASELINE_MM * (1 / 500.0 - 1 / 1400.0)
    assert not shadow[:, :200].any() and shadow[:, 200:200 + int(width) - 1].all()
    assert not shadow[:, 200 + int(width) + 2:].any()


def test_the_rgbd_launch_file_runs_the_fitter_on_depth():
    specs = {s.name: s for s in load_launch(launch_file("rgbd"), ["camera.source=/data/set"])}
    assert specs["camera"].params["source"] == "/data/set"
    assert specs["fitter"].params["depth"] == "on"
    assert "depth" in FitterNode.PARAMS and FitterNode.PARAMS["depth"].choices == ("off", "on")
