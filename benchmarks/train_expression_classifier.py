"""Train the expression classifier's weights (issue 48; :mod:`facesculpt.nodes.fitter.expression_classifier`).

    python -m benchmarks.train_expression_classifier [--identities 8] [--out FILE.npz]
        [--save FILE.pkl] [--load FILE.pkl ...]

Training renders of our own, none of the benchmark's (:mod:`benchmarks.bench_expression_labels`
uses the realism scene: scene seeds 11-13, the s18 texture over its room, yaw ±20°, pitch ±10°,
weights in [0.3, 1]): per identity a random SFM identity (seeds from 101), textured from one of
the shared data's still photos (``faces/*.jpg``, a different one per identity, none of the
videos), over a procedural background, ``--neutral-frames`` neutral frames turning slowly, then
each of the six SFM expression blendshapes twice at a random weight in [``--low``, 1] and three
neutral segments, in a random order, each at a random head pose (yaw ±25°, pitch ±12°),
rising, held and falling as the benchmark's (its :func:`schedule`). Both fits (SFM and face mesh)
run on the same frames; the features of a frame are its expression parameters (and the SFM's
coefficients) less the mean of the person's first ``--neutral-frames`` frames (the recogniser's
resting face). The held frames train a multinomial logistic regression per feature set:
"blendshapes" on the SFM's fits, "parameters" on both fits' parameters. Held-out figures: each
identity classified by weights trained on the others (its texture and identity unseen); the
written weights are trained on all of them.
"""

from __future__ import annotations

import argparse
import datetime
import json
import pickle
import subprocess
import time

import numpy as np

from benchmarks.bench_expression_labels import HOLD, RAMP, fit_sequence, schedule
from facesculpt.nodes.fitter.expression import NAMES
from facesculpt.nodes.fitter.expression_classifier import (
    WEIGHTS,
    ExpressionClassifier,
    fit_logistic,
    save_classifiers,
)
from facesculpt.nodes.fitter.expression_labels import EXPRESSIONS, LABELS

FIRST_SEED = 101
YAW_DEG, PITCH_DEG = 25.0, 12.0
BETA = tuple(f"beta:{e}" for e in EXPRESSIONS)
#: Feature set -> (its features, the fits whose records train it).
FEATURE_SETS = {"blendshapes": ((*NAMES, *BETA), ("sfm",)), "parameters": (NAMES, ("sfm", "facemesh"))}


def training_segments(rng: np.random.Generator, low: float) -> list[tuple[str, float, float, float]]:
    """(label, weight, yaw, pitch) of one training identity's segments, in a random order."""
    labels = [*EXPRESSIONS, *EXPRESSIONS, "neutral", "neutral", "neutral"]
    rng.shuffle(labels)
    return [(lab, 0.0 if lab == "neutral" else float(rng.uniform(low, 1.0)),
             float(rng.uniform(-YAW_DEG, YAW_DEG)), float(rng.uniform(-PITCH_DEG, PITCH_DEG))) for lab in labels]


def photos(data) -> list:
    """The shared still photos that show a face (sorted by name): the training textures."""
    return sorted((data / "faces").glob("*.jpg"))


def training_scene(data, seed: int, photo_path):
    """A scene (:class:`benchmarks.realism.scene.Scene`) of identity ``seed`` textured from the
    photo at ``photo_path`` over a procedural background; RuntimeError when the photo shows no face."""
    import cv2

    from benchmarks.realism.scene import SIZE, Scene, border_alpha, close_holes, fit_photo, intrinsics
    from facesculpt.app.synthetic_head import procedural_background, random_identity
    from facesculpt.nodes.fitter import load_model
    from facesculpt.nodes.fitter.calibration import uncalibrated

    model = uncalibrated(load_model("sfm"))
    photo = cv2.imread(str(photo_path))
    rest = np.asarray(random_identity(model, seed), np.float64).reshape(-1, 3)
    rest, tris, tex, outer = close_holes(rest, np.asarray(model.triangles, np.int64), fit_photo(model, photo))
    return Scene(rest=rest, triangles=tris, texcoords=tex, alpha=border_alpha(rest, outer), texture=photo,
                 background=procedural_background(seed, SIZE), K=intrinsics(),
                 landmarks={str(k): int(v) for k, v in zip(model.landmark_names, model.landmark_vertices)},
                 frames=1, model_triangles=np.asarray(model.triangles, np.int64))


def render_and_fit(data, args) -> list[dict]:
    """Every training identity's frames fitted by both models (records as the benchmark's, each
    with its texture's name)."""
    from facesculpt.nodes.fitter import load_model
    from facesculpt.nodes.landmarks.detector import LandmarkDetector

    model = load_model("sfm")
    detectors = {m: LandmarkDetector() for m in ("sfm", "facemesh")}
    records, t0, pool = [], time.process_time(), photos(data)
    seed, k = args.first_seed, 0
    while k < args.identities and seed < args.first_seed + 10 * args.identities:
        photo = pool[(seed - FIRST_SEED) % len(pool)]
        seed += 1
        try:
            scene = training_scene(data, seed - 1, photo)
        except RuntimeError:
            print(f"{photo.name}: no face found, skipped", flush=True)
            continue
        plan = schedule(training_segments(np.random.default_rng(seed - 1), args.low), args.neutral_frames)
        mine = fit_sequence(scene, plan, seed - 1, args.neutral_frames, detectors, model, [])
        for r in mine:
            r["texture"] = photo.name
        records += mine
        k += 1
        print(f"identity {k} of {args.identities} (seed {seed - 1}, {photo.name}) done "
              f"({time.process_time() - t0:.0f} s CPU)", flush=True)
        if args.save:
            with open(args.save, "wb") as f:
                pickle.dump(records, f)
    return records


def relative_features(records: list[dict], fit: str, features, neutral_frames: int):
    """(X (N, F), y (N,) label index, seeds (N,)) of the scored frames fitted by ``fit``: each
    frame's features less the mean of its person's first ``neutral_frames`` fitted frames."""
    from facesculpt.nodes.fitter.expression_classifier import feature_vector

    X, y, seeds, base = [], [], [], {}
    for r in records:
        if r[fit] is None:
            continue
        x = feature_vector(features, r[fit][0], NAMES, r[fit][1], EXPRESSIONS)
        b = base.setdefault(r["seed"], [])
        if len(b) < neutral_frames:
            b.append(x)
            continue
        if r["truth"] is not None:
            X.append(x - np.mean(b, axis=0))
            y.append(LABELS.index(r["truth"]))
            seeds.append(r["seed"])
    return np.array(X), np.array(y), np.array(seeds)


def train(X: np.ndarray, y: np.ndarray, features, l2: float) -> ExpressionClassifier:
    """A classifier of ``features`` trained on ``X`` (N, F), ``y`` (N,)."""
    mean, scale = X.mean(axis=0), X.std(axis=0)
    scale = np.where(scale > 1e-9, scale, 1.0)
    W, b = fit_logistic((X - mean) / scale, y, len(LABELS), l2=l2)
    return ExpressionClassifier(tuple(features), mean, scale, W, b, LABELS)


def held_out(training, test, features, l2: float) -> np.ndarray:
    """(7, 7) confusion counts (truth rows, label columns) of each identity of ``test`` (X, y,
    seeds) classified by weights trained on the other identities' frames of ``training`` (X, y, seeds)."""
    X, y, seeds = training
    confusion = np.zeros((len(LABELS), len(LABELS)), np.int64)
    for s in np.unique(test[2]):
        c = train(X[seeds != s], y[seeds != s], features, l2)
        mine = test[2] == s
        for t, p in zip(test[1][mine], c.probabilities(test[0][mine]).argmax(axis=1)):
            confusion[t, p] += 1
    return confusion


def print_confusion(name: str, confusion: np.ndarray) -> dict:
    """Print a confusion matrix and each label's share right; returns the figures."""
    right = np.diag(confusion) / np.maximum(confusion.sum(axis=1), 1)
    expr = confusion[:6].trace() / max(confusion[:6].sum(), 1)
    print(f"{name}: expressions {100 * expr:.1f} % right, neutral {100 * right[6]:.1f} % (held-out identities)")
    print("  truth \\ label " + " ".join(f"{c[:5]:>6s}" for c in LABELS))
    for t, row in zip(LABELS, confusion):
        print(f"  {t:13s} " + " ".join(f"{c:6d}" for c in row) + f"   {100 * right[LABELS.index(t)]:.0f} %")
    return {"expressions_right": round(float(expr), 4), "neutral_right": round(float(right[6]), 4),
            "per_label_right": {lab: round(float(v), 4) for lab, v in zip(LABELS, right)},
            "confusion": confusion.tolist()}


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--identities", type=int, default=8, help="training identities (one texture each)")
    p.add_argument("--first-seed", type=int, default=FIRST_SEED, help="the first identity's seed")
    p.add_argument("--neutral-frames", type=int, default=30)
    p.add_argument("--low", type=float, default=0.2, help="least blendshape weight (the most is 1)")
    p.add_argument("--l2", type=float, default=0.01, help="the weights' L2 penalty")
    p.add_argument("--out", default=str(WEIGHTS), metavar="FILE.npz", help="where the weights go")
    p.add_argument("--save", default="", metavar="FILE.pkl", help="keep the fitted training frames")
    p.add_argument("--load", nargs="*", default=[], metavar="FILE.pkl", help="train on kept frames (no rendering)")
    args = p.parse_args()
    from facesculpt.paths import shared_data_dir
    from facesculpt.runtime.process_limits import limit_threads

    limit_threads(1)
    data = shared_data_dir()
    if data is None:
        raise SystemExit("shared data not found: set FACESCULPT_DATA")
    records = []
    for path in args.load:
        with open(path, "rb") as f:
            records += pickle.load(f)
    if not args.load:
        records = render_and_fit(data, args)
    figures, classifiers = {}, {}
    for kind, (features, fits) in FEATURE_SETS.items():
        parts = [relative_features(records, fit, features, args.neutral_frames) for fit in fits]
        X, y, seeds = (np.concatenate(a) for a in zip(*parts))
        figures[kind] = {fit: print_confusion(f"{kind}, {fit}'s fits", held_out((X, y, seeds), part, features, args.l2))
                         for fit, part in zip(fits, parts)}
        classifiers[kind] = train(X, y, features, args.l2)
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True).stdout.strip()
    textures = sorted({r.get("texture", "?") for r in records})
    provenance = {
        "command": "python -m benchmarks.train_expression_classifier " + " ".join(
            f"--{k.replace('_', '-')} {v}" for k, v in (("identities", args.identities), ("low", args.low),
                                                        ("l2", args.l2), ("neutral_frames", args.neutral_frames))),
        "date": datetime.date.today().isoformat(), "commit": commit,
        "renders": f"{len({r['seed'] for r in records})} SFM identities (seeds {sorted({r['seed'] for r in records})}), "
                   f"textures {textures}, procedural backgrounds, yaw +-{YAW_DEG:g}, pitch +-{PITCH_DEG:g} deg, "
                   f"weights [{args.low}, 1], {RAMP} frames rising, {HOLD} held (trained on), {RAMP} falling",
        "frames": len(records), "held_out": figures,
    }
    save_classifiers(args.out, classifiers, provenance)
    print(f"weights written to {args.out}")
    print(json.dumps({k: provenance[k] for k in ("command", "renders", "frames")}, indent=1))


if __name__ == "__main__":
    main()
