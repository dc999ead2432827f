"""Train the expression classifier's weights (issue 48; :mod:`facesculpt.nodes.fitter.expression_classifier`).

    python -m benchmarks.train_expression_classifier [--identities 8] [--first-seed 101] [--out FILE.json]
        [--l2 0.1] [--neutral-recall 0.9] [--save FILE.pkl] [--load FILE.pkl ...]

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
resting face). Per feature set ("blendshapes" on the SFM's fits, "parameters" on both fits'
parameters): with ``--pose-drift``, the features' drift with the head's pose (the landmarks move
as the head turns, expression or not) is fitted on the resting and neutral frames (a ridge map
from the fit's yaw and pitch terms, :func:`~facesculpt.nodes.fitter.expression_classifier.pose_terms`)
and taken off; the held frames train a multinomial logistic regression (``--l2``); then neutral's
log-probability is raised until ``--neutral-recall`` of the held-out neutral frames are neutral.
Held-out figures: each identity classified by weights trained on the others (its texture and
identity unseen); the written weights are trained on all of them.
"""

from __future__ import annotations

import argparse
import dataclasses
import datetime
import json
import pickle
import subprocess
import sys
import time

import numpy as np

from benchmarks.bench_expression_labels import HOLD, RAMP, fit_sequence, schedule
from facesculpt.nodes.fitter.expression import NAMES
from facesculpt.nodes.fitter.expression_classifier import (
    WEIGHTS,
    ExpressionClassifier,
    fit_logistic,
    fit_pose_bias,
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


def fitted_poses(records: list[dict], fit: str, neutral_frames: int, low: float) -> list:
    """Each record's head (yaw, pitch) in degrees as ``fit`` found it (None: not fitted). Records
    kept before the fits' poses were (none stored) get their frame's true pose mapped onto the
    fit's by the per-axis line (slope and offset) fitted over the records that have both."""
    true = {}
    for seed in sorted({r["seed"] for r in records}):
        plan = schedule(training_segments(np.random.default_rng(seed), low), neutral_frames)
        mine = [k for k, r in enumerate(records) if r["seed"] == seed]
        true.update({k: (step[1], step[2]) for k, step in zip(mine, plan)})
    both = [(true[k], r[fit][2][:2]) for k, r in enumerate(records) if r[fit] is not None and len(r[fit]) > 2]
    lines = [(1.0, 0.0), (1.0, 0.0)]
    if len(both) > 10:
        t, f = np.array([b[0] for b in both]), np.array([b[1] for b in both])
        lines = [tuple(np.polyfit(t[:, a], f[:, a], 1)) for a in range(2)]
    out = []
    for k, r in enumerate(records):
        if r[fit] is None:
            out.append(None)
        elif len(r[fit]) > 2:
            out.append(tuple(float(v) for v in r[fit][2][:2]))
        else:
            out.append(tuple(lines[a][0] * true[k][a] + lines[a][1] for a in range(2)))
    return out


def relative_features(records: list[dict], fit: str, features, neutral_frames: int, low: float):
    """(X (N, F), pose change (N, 5), y (N,) label index or -1 for a resting frame, seeds (N,))
    of the frames fitted by ``fit`` that are scored or rest the face: each frame's features and
    pose terms less the mean of its person's first ``neutral_frames`` fitted frames."""
    from facesculpt.nodes.fitter.expression_classifier import feature_vector, pose_terms

    poses = fitted_poses(records, fit, neutral_frames, low)
    rows = {}
    for r, pose in zip(records, poses):
        if r[fit] is not None:
            x = feature_vector(features, r[fit][0], NAMES, r[fit][1], EXPRESSIONS)
            rows.setdefault(r["seed"], []).append((x, pose_terms(*pose), r["truth"]))
    X, P, y, seeds = [], [], [], []
    for seed, mine in rows.items():
        base_x = np.mean([x for x, _, _ in mine[:neutral_frames]], axis=0)
        base_p = np.mean([p for _, p, _ in mine[:neutral_frames]], axis=0)
        for k, (x, p, truth) in enumerate(mine):
            if k < neutral_frames or truth is not None:
                X.append(x - base_x)
                P.append(p - base_p)
                y.append(-1 if k < neutral_frames else LABELS.index(truth))
                seeds.append(seed)
    return np.array(X), np.array(P), np.array(y), np.array(seeds)


def train(X: np.ndarray, P: np.ndarray | None, y: np.ndarray, features, l2: float) -> ExpressionClassifier:
    """A classifier of ``features`` trained on relative features ``X`` (N, F), pose changes ``P``
    (N, 5) (None: no drift taken off) and labels ``y`` (N,) (-1: a resting frame, used for the
    pose's drift only): the drift fitted on the neutral and resting frames, then the logistic
    regression on the scored ones."""
    neutral = (y == -1) | (y == LABELS.index("neutral"))
    pose_bias = None if P is None else fit_pose_bias(P[neutral], X[neutral])
    scored = y >= 0
    Xc = X[scored] - (0.0 if pose_bias is None else P[scored] @ pose_bias)
    mean, scale = Xc.mean(axis=0), Xc.std(axis=0)
    scale = np.where(scale > 1e-9, scale, 1.0)
    W, b = fit_logistic((Xc - mean) / scale, y[scored], len(LABELS), l2=l2)
    return ExpressionClassifier(tuple(features), mean, scale, W, b, LABELS, pose_bias)


def held_out(training, test, features, l2: float) -> tuple[np.ndarray, np.ndarray]:
    """(truth (N,), log-probabilities (N, 7)) of each identity's scored frames in ``test`` (X, P,
    y, seeds) classified by weights trained on the other identities' frames of ``training``."""
    X, P, y, seeds = training
    truth, logp = [], []
    for s in np.unique(test[3]):
        c = train(X[seeds != s], None if P is None else P[seeds != s], y[seeds != s], features, l2)
        mine = (test[3] == s) & (test[2] >= 0)
        truth.append(test[2][mine])
        logp.append(np.log(np.maximum(c.probabilities(test[0][mine], None if P is None else test[1][mine]), 1e-300)))
    return np.concatenate(truth), np.concatenate(logp)


def confusion(truth: np.ndarray, logp: np.ndarray, neutral_offset: float = 0.0) -> np.ndarray:
    """(7, 7) counts (truth rows, label columns) with ``neutral_offset`` added to neutral's log-probability."""
    logp = logp.copy()
    logp[:, LABELS.index("neutral")] += neutral_offset
    out = np.zeros((len(LABELS), len(LABELS)), np.int64)
    np.add.at(out, (truth, logp.argmax(axis=1)), 1)
    return out


def neutral_offset_for(truth: np.ndarray, logp: np.ndarray, recall: float) -> float:
    """The least offset (>= 0) to neutral's log-probability that recognises ``recall`` of the
    held-out neutral frames as neutral."""
    n = LABELS.index("neutral")
    neutral = logp[truth == n]
    if not len(neutral):
        return 0.0
    need = np.sort(np.maximum(np.delete(neutral, n, axis=1).max(axis=1) - neutral[:, n], 0.0))
    return float(need[min(len(need) - 1, int(np.ceil(recall * len(need))) - 1)] + 1e-6)


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
    p.add_argument("--l2", type=float, default=0.1, help="the weights' L2 penalty")
    p.add_argument("--pose-drift", action="store_true",
                   help="take the features' drift with the head's pose off (needs frames kept with the fits' poses)")
    p.add_argument("--neutral-recall", type=float, default=0.9,
                   help="neutral's log-probability is raised until this share of the held-out neutral frames "
                        "is recognised")
    p.add_argument("--out", default=str(WEIGHTS), metavar="FILE.json", help="where the weights go (JSON)")
    p.add_argument("--note", default="", help="how the kept frames were made, for the provenance record")
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
        parts = [relative_features(records, fit, features, args.neutral_frames, args.low) for fit in fits]
        if not args.pose_drift:
            parts = [(X, None, y, seeds) for X, _, y, seeds in parts]
        pooled = tuple(None if a[0] is None else np.concatenate(a) for a in zip(*parts))
        outs = [held_out(pooled, part, features, args.l2) for part in parts]
        offset = neutral_offset_for(*(np.concatenate(a) for a in zip(*outs)), args.neutral_recall)
        figures[kind] = {"neutral_offset": round(offset, 4)}
        for fit, out in zip(fits, outs):
            print_confusion(f"{kind}, {fit}'s fits, no offset", confusion(*out))
            figures[kind][fit] = print_confusion(f"{kind}, {fit}'s fits, neutral offset {offset:.2f}",
                                                 confusion(*out, offset))
        c = train(*pooled[:3], features, args.l2)
        bias = c.bias.copy()
        bias[LABELS.index("neutral")] += offset
        classifiers[kind] = dataclasses.replace(c, bias=bias)
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True).stdout.strip()
    textures = sorted({r.get("texture", "?") for r in records})
    provenance = {
        "command": "python -m benchmarks.train_expression_classifier " + " ".join(sys.argv[1:]),
        "date": datetime.date.today().isoformat(), "commit": commit,
        "renders": f"{len({r['seed'] for r in records})} SFM identities (seeds {sorted({r['seed'] for r in records})}), "
                   f"textures {textures}, procedural backgrounds, yaw +-{YAW_DEG:g}, pitch +-{PITCH_DEG:g} deg, "
                   f"weights [{args.low}, 1], {RAMP} frames rising, {HOLD} held (trained on), {RAMP} falling",
        "frames": len(records), "held_out": figures,
        "made": args.note or ("trained on kept frames" if args.load else "rendered, fitted and trained in one run"),
    }
    save_classifiers(args.out, classifiers, provenance)
    print(f"weights written to {args.out}")
    print(json.dumps({k: provenance[k] for k in ("command", "renders", "frames")}, indent=1))


if __name__ == "__main__":
    main()
