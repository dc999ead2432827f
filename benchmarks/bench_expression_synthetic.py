"""Expression parameters against ground truth on the synthetic SFM set (issue 19).

    python benchmarks/bench_expression_synthetic.py [--frames 120] [--neutral-frames 30] [--strip FILE.png]

The realism benchmark's scene (:mod:`benchmarks.realism.scene`: the Surrey Face Model with a random
identity, textured from a real face, turning yaw ±25°, pitch ±10° over a real background), with
the model's six expression blendshapes (anger, disgust, fear, happiness, sadness, surprise) each
following its own smooth activation in [0, 0.8] (periods 23..47 frames, so they are not
correlated with each other). The frames after the first ``--neutral-frames`` (whose activation is
held at 0, the neutral the fitter learns its identity from) go through the project's landmarks and
SFM fit (`Pipeline("sfm")`). Measured per named expression component: the correlation over the
frames between the fitted parameter and the same component computed on the true mesh against the
true neutral, for the components the truth moves (std over 1 %IOD, 0.05 for eye closure); and the
correlation of the fitted blendshape coefficients (beta) with the true weights; and the
seed-002 SNR of the fitted model-space shape against the true one (10 log10 of the true shape's
variance over the squared error, both centred, the fitted one aligned by a similarity).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))

PERIODS = (23, 29, 31, 37, 41, 47)
PEAK = 0.8


def activation(i: int, start: int) -> np.ndarray:
    """(6,) blendshape weights of frame ``i``: 0 before ``start``, then each its own raised cosine."""
    if i < start:
        return np.zeros(len(PERIODS))
    k = np.arange(len(PERIODS))
    return PEAK * (0.5 - 0.5 * np.cos(2 * np.pi * (i - start) / np.array(PERIODS) + 0.0 * k))


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--frames", type=int, default=120)
    p.add_argument("--neutral-frames", type=int, default=30)
    p.add_argument("--strip", default="", metavar="FILE.png")
    p.add_argument("--model", default="sfm", choices=("sfm", "facemesh"),
                   help="the model fitted to the frames (default sfm, whose blendshapes made them)")
    args = p.parse_args()
    import cv2

    from benchmarks.realism.raster import render_textured
    from benchmarks.realism.scene import make_scene
    from facesculpt.app.pipeline import Pipeline
    from facesculpt.nodes.fitter import load_model
    from facesculpt.nodes.fitter.expression import NAMES, expression_parameters, expression_points
    from facesculpt.nodes.fitter.pose import similarity_procrustes
    from facesculpt.paths import shared_data_dir
    from facesculpt.runtime.process_limits import limit_threads

    limit_threads(1)
    data = shared_data_dir()
    if data is None:
        raise SystemExit("shared data not found: set FACESCULPT_DATA")
    model = load_model("sfm")
    scene = make_scene(data, frames=args.frames)
    Vm = model.num_vertices
    basis = np.asarray(model.expression_basis, np.float64)  # (V, 3, 6)
    names, lv = model.landmark_names, model.landmark_vertices
    rest_pts = expression_points(scene.rest[:Vm], False, names, lv)
    truth, fitted, snr, frames_out, weights, betas = [], [], [], [], [], []
    with Pipeline(args.model, neutral_frames=args.neutral_frames) as pipe:
        for i in range(args.frames):
            w = activation(i, args.neutral_frames)
            shape = scene.rest.copy()
            shape[:Vm] += basis @ w
            X = scene.to_camera(shape, i)
            frame = np.clip(np.rint(render_textured(scene.K, X, scene.triangles, scene.texcoords, scene.alpha,
                                                    scene.texture, scene.background)), 0, 255).astype(np.uint8)
            fit = pipe.fit_frame(frame, i / 25.0)
            if i < args.neutral_frames:
                continue
            truth.append(expression_parameters(expression_points(shape[:Vm], False, names, lv), rest_pts))
            fitted.append(np.full(len(NAMES), np.nan) if fit is None else fit.expression)
            weights.append(w)
            betas.append(np.full(len(w), np.nan) if fit is None or args.model != "sfm"
                         else np.asarray(fit.beta, np.float64))
            if fit is not None and args.model == "sfm":
                a = shape[:Vm] - shape[:Vm].mean(0)
                b = np.asarray(fit.model_vertices, np.float64)
                s, R, t = similarity_procrustes(b, a)
                err = ((s * b @ R.T + t - a) ** 2).sum()
                snr.append(10 * np.log10((a ** 2).sum() / err))
            if args.strip and i in (args.neutral_frames + 10, args.neutral_frames + 40, args.frames - 1):
                frames_out.append(frame)
    truth, fitted = np.array(truth), np.array(fitted)
    ok = np.isfinite(fitted).all(1)
    print(f"{ok.sum()} of {len(ok)} frames fitted with {args.model} (after {args.neutral_frames} neutral frames)")
    if snr:
        print(f"shape SNR median {np.median(snr):.1f} dB (min {np.min(snr):.1f})")
    rows = []
    for k, name in enumerate(NAMES):
        t = truth[ok, k]
        if not np.isfinite(t).all() or np.std(t) <= (0.05 if name.startswith("eye_close") else 1.0):
            continue
        r = np.corrcoef(t, fitted[ok, k])[0, 1]
        rows.append((name, r, np.std(t)))
        print(f"  {name:22s} truth std {np.std(t):6.2f}  r = {r:.3f}")
    r = np.array([x[1] for x in rows])
    print(f"{len(rows)} components the truth moves: mean r {r.mean():.3f}, {int((r >= 0.9).sum())} >= 0.9")
    weights, betas = np.array(weights), np.array(betas)
    if args.model != "sfm":
        return
    blend = [np.corrcoef(weights[ok, k], betas[ok, k])[0, 1] for k in range(weights.shape[1])]
    print("blendshape weights (anger, disgust, fear, happiness, sadness, surprise): fitted beta vs truth r = "
          + " ".join(f"{r:.2f}" for r in blend))
    if args.strip and frames_out:
        cv2.imwrite(args.strip, np.hstack(frames_out))


if __name__ == "__main__":
    main()
