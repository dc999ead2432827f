"""Expression parameters against ground truth on the synthetic SFM set (issue 19).

    python -m benchmarks.bench_expression_synthetic [--frames 120] [--neutral-frames 30] [--strip FILE.png]
        [--model sfm|facemesh] [--refine appearance] [--no-exact]

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

``--exact`` (default on) measures the same again with the SFM fitter given the scene's true
landmarks instead of the detected ones: what the fit and the parameters reach when the points
are exact, so the gap between the two runs is what the landmark detector costs.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parent.parent

PERIODS = (23, 29, 31, 37, 41, 47)
PEAK = 0.8


def activation(i: int, start: int) -> np.ndarray:
    """(6,) blendshape weights of frame ``i``: 0 before ``start``, then each its own raised cosine."""
    if i < start:
        return np.zeros(len(PERIODS))
    k = np.arange(len(PERIODS))
    return PEAK * (0.5 - 0.5 * np.cos(2 * np.pi * (i - start) / np.array(PERIODS) + 0.0 * k))


def exact_landmarks(scene, X: np.ndarray, names, lv) -> tuple[np.ndarray, list[int]]:
    """The scene's true iBUG landmarks of camera-space vertices ``X`` (V, 3) mm: (L, 2) px in the
    project's convention (pixel centres at integers) and their 1-based iBUG numbers."""
    from benchmarks.realism.raster import project_pixels

    px = project_pixels(scene.K, X)
    vertex = dict(zip(names, lv))
    ids = [k for k in range(1, 69) if str(k) in vertex]
    return np.array([px[vertex[str(k)]] for k in ids]), ids


def fit_sequence(args, scene, model, exact: bool) -> dict:
    """Render the frames and fit them: with the project's landmarks (``Pipeline(args.model)``), or
    (``exact``) the SFM fitter given the true landmarks. Returns the per-frame truth and fitted
    expression parameters, blendshape weights and fitted betas, shape SNRs and the strip's frames."""
    from contextlib import nullcontext

    from benchmarks.realism.raster import render_textured
    from facesculpt.app.pipeline import Pipeline
    from facesculpt.nodes.camera.intrinsics import intrinsics_from_fov
    from facesculpt.nodes.fitter import FitterConfig, make_fitter
    from facesculpt.nodes.fitter.expression import expression_parameters, expression_points, face_expression
    from facesculpt.nodes.fitter.pose import similarity_procrustes

    Vm = model.num_vertices
    basis = np.asarray(model.expression_basis, np.float64)  # (V, 3, 6)
    names, lv = model.landmark_names, model.landmark_vertices
    rest_pts = expression_points(scene.rest[:Vm], False, names, lv)
    size = (scene.background.shape[1], scene.background.shape[0])
    out = {k: [] for k in ("truth", "fitted", "weights", "betas", "snr", "frames")}
    fitter = make_fitter(model, FitterConfig(neutral_frames=args.neutral_frames), size,
                         intrinsics_from_fov(*size, 60.0)) if exact else None
    refine = getattr(args, "refine", None)   # a caller's Namespace may predate the option
    with nullcontext() if exact else Pipeline(args.model, fit=FitterConfig(neutral_frames=args.neutral_frames, refine=refine)) as pipe:
        for i in range(args.frames):
            w = activation(i, args.neutral_frames)
            shape = scene.rest.copy()
            shape[:Vm] += basis @ w
            X = scene.to_camera(shape, i)
            if exact:
                points, ids = exact_landmarks(scene, X, names, lv)
                fit = fitter.fit(points, ids, stamp=i / 25.0)
                observed = np.full((68, 2), np.nan)
                observed[np.array(ids) - 1] = points
                fit.expression = face_expression(fit, model, fitter.neutral, observed)
                frame = None
            else:
                frame = np.clip(np.rint(render_textured(scene.K, X, scene.triangles, scene.texcoords, scene.alpha,
                                                        scene.texture, scene.background)), 0, 255).astype(np.uint8)
                fit = pipe.fit_frame(frame, i / 25.0)
            if i < args.neutral_frames:
                continue
            out["truth"].append(expression_parameters(expression_points(shape[:Vm], False, names, lv), rest_pts))
            out["fitted"].append(np.full(len(out["truth"][-1]), np.nan) if fit is None
                                 else fit.expression)
            out["weights"].append(w)
            out["betas"].append(np.full(len(w), np.nan) if fit is None or (args.model != "sfm" and not exact)
                                else np.asarray(fit.beta, np.float64))
            if fit is not None and (args.model == "sfm" or exact):
                a = shape[:Vm] - shape[:Vm].mean(0)
                b = np.asarray(fit.model_vertices, np.float64)
                s, R, t = similarity_procrustes(b, a)
                out["snr"].append(10 * np.log10((a ** 2).sum() / ((s * b @ R.T + t - a) ** 2).sum()))
            if frame is not None and i in (args.neutral_frames + 10, args.neutral_frames + 40, args.frames - 1):
                out["frames"].append(frame)
    return out


def report(label: str, run: dict, with_betas: bool) -> None:
    """Print one run's figures: fitted frames, shape SNR, per-component correlation, blendshapes."""
    from facesculpt.nodes.fitter.expression import NAMES

    truth, fitted = np.array(run["truth"]), np.array(run["fitted"])
    ok = np.isfinite(fitted).all(1)
    print(f"{label}: {ok.sum()} of {len(ok)} frames fitted")
    if run["snr"]:
        print(f"  shape SNR median {np.median(run['snr']):.1f} dB (min {np.min(run['snr']):.1f})")
    rows = []
    for k, name in enumerate(NAMES):
        t = truth[ok, k]
        if not np.isfinite(t).all() or np.std(t) <= (0.05 if name.startswith("eye_close") else 1.0):
            continue
        r = np.corrcoef(t, fitted[ok, k])[0, 1]
        rows.append(r)
        print(f"  {name:22s} truth std {np.std(t):6.2f}  r = {r:.3f}")
    r = np.array(rows)
    print(f"  {len(rows)} components the truth moves: mean r {r.mean():.3f}, {int((r >= 0.9).sum())} >= 0.9")
    if with_betas:
        weights, betas = np.array(run["weights"]), np.array(run["betas"])
        blend = [np.corrcoef(weights[ok, k], betas[ok, k])[0, 1] for k in range(weights.shape[1])]
        print("  blendshape weights (anger, disgust, fear, happiness, sadness, surprise): fitted beta vs truth r = "
              + " ".join(f"{r:.2f}" for r in blend))


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--frames", type=int, default=120)
    p.add_argument("--neutral-frames", type=int, default=30)
    p.add_argument("--strip", default="", metavar="FILE.png")
    p.add_argument("--model", default="sfm", choices=("sfm", "facemesh"),
                   help="the model fitted to the frames (default sfm, whose blendshapes made them)")
    p.add_argument("--refine", default=None, choices=("appearance",),
                   help="refine the detected landmarks' fit by appearance (process --refine; default off)")
    p.add_argument("--exact", action=argparse.BooleanOptionalAction, default=True,
                   help="also fit the SFM to the true landmarks (no detector): what the fitter and the "
                        "parameters reach with exact points (default on)")
    args = p.parse_args()
    import cv2

    from benchmarks.realism.scene import make_scene
    from facesculpt.nodes.fitter import load_model
    from facesculpt.paths import shared_data_dir
    from facesculpt.runtime.process_limits import limit_threads

    limit_threads(1)
    data = shared_data_dir()
    if data is None:
        raise SystemExit("shared data not found: set FACESCULPT_DATA")
    model = load_model("sfm")
    scene = make_scene(data, frames=args.frames)
    detected = fit_sequence(args, scene, model, exact=False)
    refined = ", refined by appearance" if args.refine else ""
    report(f"{args.model}, the project's landmarks{refined} (after {args.neutral_frames} neutral frames)", detected,
           args.model == "sfm")
    if args.exact:
        report("sfm, the true landmarks (no detector)", fit_sequence(args, scene, model, exact=True), True)
    if args.strip and detected["frames"]:
        cv2.imwrite(args.strip, np.hstack(detected["frames"]))


if __name__ == "__main__":
    main()
