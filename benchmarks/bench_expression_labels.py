"""Expressions recognised against ground truth on synthetic faces (issue 48, item 4).

    python -m benchmarks.bench_expression_labels [--identities 3] [--neutral-frames 30] [--low 0.3]
        [--strip FILE.png]

Per identity (a seed of the realism benchmark's scene, :mod:`benchmarks.realism.scene`: the Surrey
Face Model with a random identity, textured from a real face, over a real background, drawn by
the benchmark's own rasteriser), a sequence: ``--neutral-frames`` neutral frames turning slowly
(the fitters learn the person), then segments in a random order: each of the six SFM expression
blendshapes (anger, disgust, fear, happiness, sadness, surprise) at a random intensity in
[``--low``, 1] and two neutral ones, each at a random head pose (yaw ±20°, pitch ±10°): the
weight rises over RAMP frames (the pose moving to the segment's), holds for HOLD frames, and falls.
The same frames go through the project's landmarks and both fits (``Pipeline("sfm")`` and
``Pipeline("facemesh")``), and each fit's expression parameters (and the SFM's coefficients)
through :class:`ExpressionRecogniser`; the held frames are scored: accuracy over the expression
segments (the blendshape's name is the truth), neutral recognised over the neutral segments,
per source (SFM: learned, facs, blendshapes, rules; face mesh: learned, facs), with confusion
matrices. The rules (the FACS table, the blendshapes' names) are not trained on anything; the
learned classifier was trained on renders of other identities, textures, backgrounds, poses
and weights (:mod:`benchmarks.train_expression_classifier`), none of these frames.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from facesculpt.nodes.fitter.expression import NAMES
from facesculpt.nodes.fitter.expression_labels import EXPRESSIONS, LABELS, ExpressionRecogniser

RAMP, HOLD = 5, 8
YAW_DEG, PITCH_DEG = 20.0, 10.0


def segments(rng: np.random.Generator, low: float) -> list[tuple[str, float, float, float]]:
    """(label, intensity, yaw, pitch) of one identity's segments, in a random order."""
    labels = ["anger", "disgust", "fear", "happiness", "sadness", "surprise", "neutral", "neutral"]
    rng.shuffle(labels)
    return [(lab, 0.0 if lab == "neutral" else float(rng.uniform(low, 1.0)),
             float(rng.uniform(-YAW_DEG, YAW_DEG)), float(rng.uniform(-PITCH_DEG, PITCH_DEG))) for lab in labels]


def schedule(segs, neutral_frames: int):
    """Per frame: (blendshape weights (6,), yaw, pitch, the segment's label or None for frames not
    scored, the segment's number or -1, the frame's number in its segment)."""
    out = []
    for i in range(neutral_frames):   # the person learned: a small slow turn, no expression
        out.append((np.zeros(6), 8.0 * np.sin(2 * np.pi * i / neutral_frames), 0.0, None, -1, i))
    yaw0, pitch0 = out[-1][1], out[-1][2]
    for k, (label, w, yaw, pitch) in enumerate(segs):
        e = EXPRESSIONS.index(label) if label != "neutral" else None
        for j in range(RAMP + HOLD + RAMP):
            s = min(1.0, (j + 1) / RAMP) if j < RAMP + HOLD else max(0.0, 1.0 - (j - RAMP - HOLD + 1) / RAMP)
            weights = np.zeros(6)
            if e is not None:
                weights[e] = w * s
            a = min(1.0, (j + 1) / RAMP)
            scored = label if RAMP <= j < RAMP + HOLD else None
            out.append((weights, yaw0 + a * (yaw - yaw0), pitch0 + a * (pitch - pitch0), scored, k, j))
        yaw0, pitch0 = yaw, pitch
    return out


#: The recognisers scored: (name, model, source). "exact": the true mesh's parameters and the
#: true weights, no detector and no fit (what the recogniser reaches with exact parameters).
RUNS = (("sfm, learned", "sfm", "learned"), ("facemesh, learned", "facemesh", "learned"),
        ("sfm, facs", "sfm", "facs"), ("sfm, blendshapes", "sfm", "blendshapes"), ("sfm, rules", "sfm", "rules"),
        ("facemesh, facs", "facemesh", "facs"), ("exact parameters, facs", "exact", "facs"))
#: The two runs the contact sheet shows (each model's default source).
SHOWN = ("sfm, learned", "facemesh, facs")


def add_exact(records: list[dict], args, model, data) -> None:
    """Give every record the true parameters of its frame (key "exact"): the expression
    parameters of the true mesh against the true rest mesh, and the true weights as coefficients."""
    from benchmarks.realism.scene import random_identity
    from facesculpt.nodes.fitter.expression import expression_parameters, expression_points

    basis = np.asarray(model.expression_basis, np.float64)
    names, lv = model.landmark_names, model.landmark_vertices
    for seed in sorted({r["seed"] for r in records}):
        rest = np.asarray(random_identity(model, seed), np.float64).reshape(-1, 3)
        rest_pts = expression_points(rest, False, names, lv)
        plan = schedule(segments(np.random.default_rng(1000 + seed), args.low), args.neutral_frames)
        mine = [r for r in records if r["seed"] == seed]
        for r, (weights, *_rest) in zip(mine, plan):
            pts = expression_points(rest + basis @ weights, False, names, lv)
            r["exact"] = (expression_parameters(pts, rest_pts), weights)


def camera_vertices(scene, V: np.ndarray, yaw: float, pitch: float) -> np.ndarray:
    """Model-space vertices (V, 3) mm into camera space at head ``yaw``, ``pitch`` (degrees)."""
    from benchmarks.realism.scene import DISTANCE_MM, FACING, PIVOT, rotation

    R = rotation(yaw, pitch) @ FACING
    return (np.asarray(V, np.float64) - PIVOT) @ R.T + np.array([0.0, 6.0, DISTANCE_MM])


def render(scene, basis: np.ndarray, weights: np.ndarray, yaw: float, pitch: float) -> np.ndarray:
    """(H, W, 3) uint8 BGR: the scene's head with blendshape ``weights`` (6,) (``basis`` (V, 3, 6)
    mm) at head ``yaw``, ``pitch`` (degrees), drawn by the benchmark's rasteriser."""
    from benchmarks.realism.raster import render_textured

    shape = scene.rest.copy()
    shape[:basis.shape[0]] += basis @ weights
    X = camera_vertices(scene, shape, yaw, pitch)
    return np.clip(np.rint(render_textured(scene.K, X, scene.triangles, scene.texcoords, scene.alpha,
                                           scene.texture, scene.background)), 0, 255).astype(np.uint8)


def run_identity(data, seed: int, args, detectors: dict, model, strip: list) -> list[dict]:
    """Render one identity's sequence and fit it with both models: one record per frame (its time,
    truth or None when not scored, the true weight, and per model the expression parameters and
    coefficients, None when not fitted)."""
    from benchmarks.realism.scene import make_scene

    scene = make_scene(data, frames=1, seed=seed)
    plan = schedule(segments(np.random.default_rng(1000 + seed), args.low), args.neutral_frames)
    return fit_sequence(scene, plan, seed, args.neutral_frames, detectors, model, strip)


def fit_sequence(scene, plan, seed: int, neutral_frames: int, detectors: dict, model, strip: list) -> list[dict]:
    """:func:`run_identity` for a given scene and :func:`schedule` ``plan`` (``seed`` names the
    identity in the records; up to 24 tiles of the held frames are added to ``strip``)."""
    from facesculpt.app.pipeline import Pipeline
    from facesculpt.nodes.fitter.config import FitterConfig
    from facesculpt.nodes.fitter.expression import head_pose

    basis = np.asarray(model.expression_basis, np.float64)
    # a new person: new fitters (they learn afresh), the detectors reused (reset by the pipeline)
    fit = FitterConfig(neutral_frames=neutral_frames)
    pipes = {m: Pipeline(m, fit=fit, detector=d) for m, d in detectors.items()}
    records = []
    for i, (weights, yaw, pitch, truth, _, j) in enumerate(plan):
        frame = render(scene, basis, weights, yaw, pitch)
        fits = {m: pipes[m].fit_frame(frame, i / 25.0) for m in pipes}
        rec = {"seed": seed, "t": i / 25.0, "truth": truth, "weight": float(weights.max())}
        for m, fit in fits.items():
            ok = fit is not None and fit.expression is not None
            rec[m] = (np.asarray(fit.expression), np.asarray(fit.beta), head_pose(fit)) if ok else None
        records.append(rec)
        if truth is not None and j == RAMP + HOLD - 1 and len(strip) < 24:
            strip.append((i, seed, frame, truth, float(weights.max())))
    for pipe in pipes.values():
        pipe.close()
    return records


def label_records(records: list[dict], model_name: str, expression_names, **options) -> list:
    """Each record's recognised label (None: not fitted) with a recogniser per identity."""
    out, rec_of = [], {}
    for r in records:
        recogniser = rec_of.setdefault(r["seed"], ExpressionRecogniser(**options))
        fit = r[model_name]
        pose = fit[2][:2] if fit is not None and len(fit) > 2 else None   # the fit's (yaw, pitch); None: exact
        out.append(None if fit is None else recogniser.update(r["t"], fit[0], NAMES, fit[1], expression_names, pose))
    return out


def report(records: list[dict], names: dict, thresholds=(0.1, 0.15, 0.2, 0.25)) -> dict:
    """Print accuracy, neutral recognition and the confusion matrix per run (at the default
    options), and both figures at other ``neutral_below`` thresholds; returns run -> labels."""
    from facesculpt.nodes.fitter.expression_labels import ExpressionLabelOptions

    default = ExpressionLabelOptions().neutral_below
    shown = {}
    for name, m, src in RUNS:
        for th in sorted({default, *(() if src == "learned" else thresholds)}):
            labels = label_records(records, m, names[m], source=src, neutral_below=th)
            r = [(x, "none" if lab is None else lab.label) for x, lab in zip(records, labels) if x["truth"]]
            expr = [(x, lab) for x, lab in r if x["truth"] != "neutral"]
            neut = [(x, lab) for x, lab in r if x["truth"] == "neutral"]
            acc = np.mean([lab == x["truth"] for x, lab in expr])
            nacc = np.mean([lab == "neutral" for _, lab in neut])
            print(f"{name}, neutral_below {th:.2f}{' (default)' if th == default else ''}: expressions "
                  f"{100 * acc:.1f} % of {len(expr)} frames, neutral {100 * nacc:.1f} % of {len(neut)}")
            if th != default:
                continue
            shown[name] = labels
            cols = (*LABELS, "none")
            print("  truth \\ label " + " ".join(f"{c[:5]:>6s}" for c in cols))
            for t in LABELS:
                counts = [sum(1 for x, lab in r if x["truth"] == t and lab == c) for c in cols]
                if sum(counts):
                    print(f"  {t:13s} " + " ".join(f"{c:6d}" for c in counts))
            for lo, hi in ((0.0, 0.5), (0.5, 0.75), (0.75, 1.01)):
                b = [lab == x["truth"] for x, lab in expr if lo <= x["weight"] < hi]
                if b:
                    print(f"  weight {lo:.2f}-{min(hi, 1):.2f}: {100 * np.mean(b):.1f} % of {len(b)}")
    return shown


def captioned(tile: np.ndarray, lines) -> np.ndarray:
    """``tile`` with ``lines`` of white text on a dark band along its top."""
    import cv2

    out = tile.copy()
    band = 16 * len(lines) + 6
    out[:band] = (out[:band] * 0.35).astype(np.uint8)
    for j, text in enumerate(lines):
        cv2.putText(out, text, (4, 15 + 16 * j), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (255, 255, 255), 1, cv2.LINE_AA)
    return out


def strip_frames(data, records: list[dict], args, model) -> list:
    """The contact sheet's frames re-rendered (for ``--load``): each segment's last held frame."""
    from benchmarks.realism.scene import make_scene

    basis = np.asarray(model.expression_basis, np.float64)
    out = []
    for seed in sorted({r["seed"] for r in records}):
        scene = make_scene(data, frames=1, seed=seed)
        plan = schedule(segments(np.random.default_rng(1000 + seed), args.low), args.neutral_frames)
        for i, (weights, yaw, pitch, truth, _, j) in enumerate(plan):
            if truth is None or j != RAMP + HOLD - 1:
                continue
            frame = render(scene, basis, weights, yaw, pitch)
            out.append((i, seed, frame, truth, float(weights.max())))
    return out


def write_strip(path: str, strip: list, records: list[dict], shown: dict) -> None:
    """A contact sheet of each segment's last held frame with its truth and two runs' labels."""
    import cv2

    index = {(r["seed"], round(r["t"] * 25)): k for k, r in enumerate(records)}
    tiles = []
    for i, seed, frame, truth, w in strip:
        k = index[(seed, i)]
        labels = {n: (shown[n][k].label if shown[n][k] else "none") for n in SHOWN}
        tile = cv2.resize(frame[40:440, 120:520], (240, 240), interpolation=cv2.INTER_AREA)
        tiles.append(captioned(tile, (f"truth {truth} {w:.2f}", f"sfm {labels[SHOWN[0]]}",
                                      f"mesh {labels[SHOWN[1]]}")))
    while len(tiles) % 8:
        tiles.append(np.zeros_like(tiles[0]))
    rows = [np.hstack(tiles[k:k + 8]) for k in range(0, len(tiles), 8)]
    cv2.imwrite(path, np.vstack(rows))


VIDEOS = ("d0.mp4", "d3.mp4", "d12.mp4")


def real_videos(data, args) -> tuple[list, dict]:
    """Each shared video through both models' fits and the recogniser (default options): tiles
    of frames sampled evenly after the neutral frames with both labels, and the CPU times
    (process_time, s) of the analysis (landmarks + fit), the fit's share of it, the expression
    parameters and the recogniser, summed over the frames."""
    import cv2

    from facesculpt.app.pipeline import Pipeline
    from facesculpt.nodes.fitter.config import FitterConfig
    from facesculpt.nodes.fitter.expression import face_expression

    tiles, cpu = [], {"analysis": 0.0, "fit": 0.0, "parameters": 0.0, "recognise": 0.0, "frames": 0}
    for video in VIDEOS:
        cap = cv2.VideoCapture(str(data / "video" / video))
        fps = cap.get(cv2.CAP_PROP_FPS) or 25.0
        frames = []
        while True:
            ok, frame = cap.read()
            if not ok:
                break
            frames.append(frame)
        cap.release()
        sample = set(np.linspace(args.neutral_frames + 5, len(frames) - 1, args.per_video).astype(int).tolist())
        labels = {}
        for m in ("facemesh", "sfm"):
            recogniser = ExpressionRecogniser(baseline_frames=args.neutral_frames)
            with Pipeline(m, fit=FitterConfig(neutral_frames=args.neutral_frames), expression=False) as pipe:
                for i, frame in enumerate(frames):
                    timings = {}
                    t0 = time.process_time()
                    fit = pipe.fit_frame(frame, i / fps, timings)
                    t1 = time.process_time()
                    if fit is None:
                        labels[(m, i)] = "no face"
                        continue
                    values = face_expression(fit, pipe.fitter.model, pipe.fitter.neutral,
                                             pipe.detector.results()[0].points)
                    t2 = time.process_time()
                    lab = recogniser.update(i / fps, values, NAMES, fit.beta, pipe.model.expression_names,
                                            fit.yaw_pitch_roll[:2])
                    t3 = time.process_time()
                    share = timings["fit"] / max(timings["fit"] + timings["landmarks"], 1e-9)
                    cpu["analysis"] += t1 - t0
                    cpu["fit"] += (t1 - t0) * share
                    cpu["parameters"] += t2 - t1
                    cpu["recognise"] += t3 - t2
                    cpu["frames"] += 1
                    labels[(m, i)] = lab.label if lab.label == "neutral" else f"{lab.label} {100 * lab.intensity:.0f}%"
        for i in sorted(sample):
            tile = cv2.resize(frames[i], (240, 240), interpolation=cv2.INTER_AREA)
            tiles.append(captioned(tile, (f"{video} #{i}", f"mesh {labels[('facemesh', i)]}",
                                          f"sfm {labels[('sfm', i)]}")))
        print(f"{video}: {len(frames)} frames; labels (face mesh): "
              + ", ".join(f"{k} {v}" for k, v in _counts([labels[("facemesh", i)] for i in range(len(frames))
                                                          if ("facemesh", i) in labels]).items()), flush=True)
    return tiles, cpu


def _counts(labels: list[str]) -> dict[str, int]:
    out: dict[str, int] = {}
    for lab in labels:
        key = lab.split(" ")[0]
        out[key] = out.get(key, 0) + 1
    return dict(sorted(out.items(), key=lambda kv: -kv[1]))


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--identities", type=int, default=3, help="random identities (scene seeds 11, 12, ...)")
    p.add_argument("--neutral-frames", type=int, default=30)
    p.add_argument("--low", type=float, default=0.3, help="least blendshape intensity (the most is 1)")
    p.add_argument("--strip", default="", metavar="FILE.png", help="write a contact sheet of the held frames")
    p.add_argument("--save", default="", metavar="FILE.pkl", help="keep the fitted parameters of every frame")
    p.add_argument("--load", default="", metavar="FILE.pkl", help="score the frames a --save kept (no rendering)")
    p.add_argument("--real", default="", metavar="FILE.png",
                   help="instead: the shared real videos' contact sheet (frames with both models' labels) and "
                        "the recogniser's CPU time against the fit's")
    p.add_argument("--per-video", type=int, default=8, help="--real: frames shown per video")
    args = p.parse_args()
    from facesculpt.nodes.fitter import load_model
    from facesculpt.nodes.landmarks.detector import LandmarkDetector
    from facesculpt.paths import shared_data_dir
    from facesculpt.runtime.process_limits import limit_threads

    limit_threads(1)
    data = shared_data_dir()
    if data is None:
        raise SystemExit("shared data not found: set FACESCULPT_DATA")
    if args.real:
        import cv2

        tiles, cpu = real_videos(data, args)
        cv2.imwrite(args.real, np.vstack([np.hstack(tiles[k:k + args.per_video])
                                          for k in range(0, len(tiles), args.per_video)]))
        n = cpu["frames"]
        print(f"CPU per fitted frame (both models, {n} frames): analysis {1e3 * cpu['analysis'] / n:.1f} ms "
              f"(fit's share {1e3 * cpu['fit'] / n:.1f} ms), expression parameters {1e3 * cpu['parameters'] / n:.2f} ms, "
              f"recogniser {1e3 * cpu['recognise'] / n:.3f} ms: recogniser / fit = {cpu['recognise'] / cpu['fit']:.4f}, "
              f"recogniser / analysis = {cpu['recognise'] / cpu['analysis']:.4f}")
        return
    model = load_model("sfm")
    detectors = {} if args.load else {m: LandmarkDetector() for m in ("sfm", "facemesh")}
    records, strip = [], []
    t0 = time.process_time()
    if args.load:
        import pickle

        with open(args.load, "rb") as f:
            records = pickle.load(f)
    for k in range(0 if args.load else args.identities):
        records += run_identity(data, 11 + k, args, detectors, model, strip)
        print(f"identity {k + 1} of {args.identities} done ({time.process_time() - t0:.0f} s CPU)", flush=True)
    if args.save:
        import pickle

        with open(args.save, "wb") as f:
            pickle.dump(records, f)
    add_exact(records, args, model, data)
    names = {"sfm": model.expression_names, "facemesh": [], "exact": model.expression_names}
    shown = report(records, names)
    if args.strip and args.load:
        strip = strip_frames(data, records, args, model)
    if args.strip and strip:
        write_strip(args.strip, strip, records, shown)


if __name__ == "__main__":
    main()
