"""Ground-truth realism benchmark (issue 15): how close an edited frame of ``facesculpt process``
is to the same edit filmed, on synthetic videos with exact ground truth, and how sharp and
seamless the re-rendered region is on real videos.

1. Synthetic set (code of the benchmark's own, ``benchmarks/realism/``; no project renderer or
   deformer): the Surrey Face Model with a random identity, textured from a real face (the
   first frame of ../shared/data/video/s18.mp4, fitted once with the project's landmarks and
   SFM fitter), over a real background (a face-free region of that frame), turning smoothly
   (yaw ±25°, pitch ±10°, 640x480, 25 fps), drawn by a numpy reference rasteriser
   (perspective, z-buffer, perspective-correct interpolation, 3x3 supersampling, soft border).
2. Per edit (nose pulled out, chin down, cheeks pushed in, jaw narrowed): the same sequence with
   the edit applied in model space (a smooth radial falloff around the handle vertices, mm), and
   the same edit as a deformer preset (``OUT/presets/EDIT.json``).
3. ``facesculpt process SYNTH.mkv -o FRAMES/%05d.png --edits PRESET --model M`` (a subprocess,
   as a user runs it, on a lossless FFV1 input) for each model, scored over the frames after the
   neutral is learned (``--neutral-frames``) against the ground truth, next to "do nothing" (the
   input) and a 2D liquify (the input warped by the true displacement projected into the image,
   densified smoothly, ``cv2.remap``):
   edit-region PSNR (dB) and SSIM (region: where the truth differs from the input, dilated);
   sharpness (variance of the Laplacian over the edit region, result / truth); seam (mean
   gradient magnitude on the boundary of the region the result changed, result / truth); handle
   landing (how far the face around each handle moved along the handle's true image
   displacement, by patch matching over the face from the input, over the same measurement on
   the ground truth: the median of that reach and of its error |1 - reach| in %), per yaw bin.
   The "ground truth (measurement check)" row is the truth's measurement over the true
   projected displacement: the patch moves less than its centre where the edit falls off.
   ``--oracle`` (default on) adds two rows with no fit (``realism/oracle.py``): the project's
   compositor drawing the true head with the true edit (the renderer alone), and with the preset
   as the project's deformer solves it on the true head (renderer + deformer). A model's row
   below them is what registration costs. ``--landmark-oracle KEEP`` (``--models sfm``) runs
   process with the detector's inner landmarks moved toward the true head's in every synthetic
   frame, keeping KEEP of their error (``realism/landmark_oracle.py``): what the landmarks cost.
   Issue 16: the edits of ``--atlas-edits`` (default: ``nose_far``, the nose pulled far out,
   which shows surface the turned head hides or foreshortens) run a second time with
   ``process --atlas on`` (the face's texture memory): the row "MODEL + atlas", and crops
   ``crops_atlas_EDIT_MODEL.png`` (input | without the atlas | with it | ground truth).
   Issue 49: ``--depth`` runs every model once more on an RGB-D recording of the same input (a
   folder of the same colour frames beside the depth a structured-light camera measures of them,
   ``realism/depth.py``), so each fit is refined on the depth: the row "MODEL + depth".
4. Real videos (../shared/data/video/d3.mp4, d12.mp4; no ground truth): sharpness of the
   re-rendered region (where the result differs from the input) against the input's, and the
   seam against the input's gradients on the same band.

Writes ``results.md``, ``results.json``, ``crops_EDIT_MODEL.png`` (rows: the most turned-left,
frontal and most turned-right scored frames; columns: input | result | ground truth | 2D
liquify, enlarged 2x without smoothing) and the presets to ``--out`` (default: a new temporary
folder), and prints the tables.

The ground truth's edit (``--truth-edit``): ``falloff`` (default), ``arap`` (gripping handles,
``realism/arap_truth.py``) or ``paper`` (the paper's ARAP, each handle a single vertex, solved by
libigl: ``realism/paper_arap.py``); several, comma-separated, score each process run against each
(tables per truth, crops ``crops_EDIT_MODEL_TRUTH.png``). ``--variants LABEL=DIR,...`` runs process
once more from each DIR (as ``--pythonpath``), as rows ``MODEL [LABEL]`` of the same run. Every row
also gives how far the lower lip (iBUG 58) moved along the edit's image displacement (median px).

Run: ``python -m benchmarks.bench_realism [--out DIR] [--frames 90] [--models facemesh,sfm]
[--edits nose,chin,cheeks,jaw] [--real-videos d3,d12] [--real-frames 90] [--no-oracle] [--pythonpath DIR]
[--process-args "--inpaint drag"] [--landmark-oracle KEEP] [--truth-edit falloff,arap,paper]
[--variants old=DIR,...]``
(``--pythonpath``: process runs the facesculpt found there first, e.g. a copy of an older
revision, to compare compositors on the same ground truth). Needs the shared data
(../shared/data or FACESCULPT_DATA) and ``facesculpt setup``.
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np

from benchmarks.realism.depth import write_rgbd_input
from benchmarks.realism.edits import ATLAS_EDITS, EDITS, TRUTH_EDITS, write_preset
from benchmarks.realism.landmark_oracle import MODULE as LANDMARK_ORACLE
from benchmarks.realism.landmark_oracle import process_environment, true_landmarks, write_true_landmarks
from benchmarks.realism.metrics import Pooled, liquify, shift_along
from benchmarks.realism.oracle import deformer_displacement, oracle_frames
from benchmarks.realism.report import crop_boxes, landing_table, real_table, side_by_side, synthetic_table
from benchmarks.realism.scene import make_scene
from benchmarks.realism.scoring import landing, landing_by_yaw, score_frame, score_real_frame, summarise
from benchmarks.realism.sequences import Sequences, read_video, render_sequences, run_process, write_lossless
from facesculpt.paths import shared_data_dir

REPO = Path(__file__).resolve().parent.parent
#: The rows that take the fit away (``--oracle``): the true head through the project's compositor.
ORACLE_RENDERER = "true mesh + true edit (renderer alone)"
ORACLE_DEFORMER = "true mesh + preset (renderer + deformer)"


def parse_args(argv=None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--out", type=Path, default=None, help="output folder (default: a new temporary folder)")
    p.add_argument("--frames", type=int, default=90, help="synthetic frames, 25 fps (default 90)")
    p.add_argument("--models", default="facemesh,sfm", help="models to run process with, names or .npz files (default facemesh,sfm)")
    p.add_argument("--edits", default=",".join(EDITS), help=f"edits (default {','.join(EDITS)})")
    p.add_argument("--real-videos", default="d3,d12", help="shared videos to score without ground truth ('' for none)")
    p.add_argument("--real-frames", type=int, default=90, help="frames of each real video (default 90)")
    p.add_argument("--neutral-frames", type=int, default=30, help="process --neutral-frames; scoring starts after them")
    p.add_argument("--atlas-edits", default=",".join(ATLAS_EDITS),
                   help=f"edits also run with process --atlas on (default {','.join(ATLAS_EDITS)}; '' for none)")
    p.add_argument("--depth", action="store_true",
                   help="also run every model on an RGB-D recording of the input (rows 'MODEL + depth', issue 49)")
    p.add_argument("--process-args", default="", type=str.split, metavar="ARGS",
                   help="more options for every process run, e.g. '--inpaint drag' (compare settings on one truth)")
    p.add_argument("--workers", type=int, default=0, help="processes rendering the synthetic set (0: one per core)")
    p.add_argument("--oracle", action=argparse.BooleanOptionalAction, default=True,
                   help="also score the project's compositor on the true head (the true edit, and the preset as the "
                        "deformer solves it): what rendering and the deformer cost without a fit (default on)")
    p.add_argument("--truth-edit", default="falloff", metavar="TRUTH[,TRUTH...]",
                   help="the ground truth's edit: falloff, the raised-cosine falloff around each handle (default); "
                        "arap, the as-rigid-as-possible deformation the preset stands for (the benchmark's own "
                        "solver, handles gripping a fifth of the ROI, as the deformer's grip 0.2 does); paper, the paper's ARAP (libigl, "
                        "each handle a single vertex). Several, comma-separated: each process run is scored "
                        "against each")
    p.add_argument("--keep-frames", action="store_true", help="keep process' output frames under OUT/frames")
    p.add_argument("--pythonpath", default="", help="run process with this folder first on PYTHONPATH (a copy of "
                   "another revision of facesculpt, to compare compositors); default: the installed one")
    p.add_argument("--variants", default="", metavar="LABEL=DIR[,LABEL=DIR...]",
                   help="also run process with each DIR first on PYTHONPATH (as --pythonpath), scored in the "
                        "same run as rows 'MODEL [LABEL]', e.g. old=../wt-old,grip0=/tmp/grip0")
    p.add_argument("--landmark-oracle", type=float, default=None, metavar="KEEP",
                   help="move the detector's inner landmarks (iBUG 18-68) toward the true head's in every synthetic "
                        "frame, keeping KEEP of their error (0: the true points, 1: the detector's): what the "
                        "landmarks cost (realism/landmark_oracle.py; --models sfm only)")
    a = p.parse_args(argv)
    a.models = [m for m in a.models.split(",") if m]
    a.edits = [e for e in a.edits.split(",") if e]
    a.real_videos = [v for v in a.real_videos.split(",") if v]
    a.atlas_edits = [e for e in a.atlas_edits.split(",") if e]
    a.variants = [tuple(v.split("=", 1)) for v in a.variants.split(",") if v]
    if any(len(v) != 2 or not v[0] or not v[1] for v in a.variants):
        p.error("--variants takes LABEL=DIR pairs, comma-separated")
    a.truth_edit = list(dict.fromkeys(t for t in a.truth_edit.split(",") if t))
    wrong = [t for t in a.truth_edit if t not in TRUTH_EDITS] or ([] if a.truth_edit else [""])
    if wrong:
        p.error(f"unknown truth edit {wrong[0]!r} (choose from {', '.join(TRUTH_EDITS)})")
    bad = [e for e in a.edits if e not in EDITS]
    if bad:
        p.error(f"unknown edit {bad[0]!r} (choose from {', '.join(EDITS)})")
    if a.landmark_oracle is not None and (a.models != ["sfm"] or not 0.0 <= a.landmark_oracle <= 1.0):
        p.error("--landmark-oracle takes a share in [0, 1] and --models sfm (the face mesh's fit takes all 468 "
                "network points)")
    if a.frames <= a.neutral_frames:
        p.error(f"--frames {a.frames} leaves no frame after --neutral-frames {a.neutral_frames}")
    return a


def liquified(seq: Sequences, edit: str, i: int) -> np.ndarray:
    """Frame ``i`` of the 2D liquify baseline of ``edit``."""
    vis = seq.visible[edit][i]
    return liquify(seq.inputs[i], seq.p0[i][vis], seq.p1[edit][i][vis])


def handle_shifts(seq: Sequences, edit: str, frames: list, scored: list[int]) -> dict:
    """(frame, handle vertex) -> how far (px) the face around the handle moved in ``frames``
    along the handle's true image displacement (:func:`shift_along`), for every handle seen."""
    out = {}
    for i in scored:
        for h in seq.handles[edit]:
            d = seq.p1[edit][i][h] - seq.p0[i][h]
            n = float(np.linalg.norm(d))
            if seq.visible[edit][i][h] and n > 0:
                out[i, h] = shift_along(seq.inputs[i], frames[i], seq.p0[i][h], d, seq.face[i], reach=2 * n + 3)
    return out


def landing_samples(seq: Sequences, edit: str, shifts: dict, reference: dict | None) -> list:
    """(yaw, error %, reach) per handle and frame: ``shifts`` against the same measurement on
    the truth (``reference``), or against the true displacement when ``reference`` is None."""
    samples = []
    for (i, h), m in shifts.items():
        true = float(np.linalg.norm(seq.p1[edit][i][h] - seq.p0[i][h]))
        ref = true if reference is None else reference.get((i, h))
        if m is None or ref is None:
            continue
        got = landing(m, ref, true)
        if got is not None:
            samples.append((seq.yaw[i], *got))
    return samples


def lip_shift(seq: Sequences, edit: str, frames: list, scored: list[int]) -> float:
    """The median (px, over ``scored``) of how far the face around the lower lip's centre (iBUG
    58) moved in ``frames`` along the first handle's true image displacement (:func:`shift_along`;
    nan when never measured)."""
    lip, h = seq.lip, seq.handles[edit][0]
    got = []
    for i in scored:
        d = seq.p1[edit][i][h] - seq.p0[i][h]
        if lip is not None and frames[i] is not None and np.linalg.norm(d) > 0 and seq.visible[edit][i][lip]:
            m = shift_along(seq.inputs[i], frames[i], seq.p0[i][lip], d, seq.face[i], reach=12.0)
            if m is not None:
                got.append(abs(m))
    return float(np.median(got)) if got else float("nan")


def score_sequence(seq: Sequences, edit: str, frames: list, scored: list[int], truth_shifts: dict) -> dict:
    """PSNR, SSIM, sharpness, seam, handle landing and the lower lip's shift of ``frames`` (a
    method's output) against the truth of ``edit`` over the frame indices ``scored``."""
    pool = Pooled()
    for i in scored:
        score_frame(pool, frames[i], seq.truth[edit][i], seq.inputs[i])
    out = summarise(pool)
    shifts = handle_shifts(seq, edit, frames, scored)
    out["landing"] = landing_by_yaw(landing_samples(seq, edit, shifts, truth_shifts))
    out["lips_px"] = lip_shift(seq, edit, frames, scored)
    return out


def crop_frames(seq: Sequences, scored: list[int]) -> list[int]:
    """The most turned-left, the most frontal and the most turned-right scored frames."""
    yaw = seq.yaw[scored]
    return [scored[int(np.argmin(yaw))], scored[int(np.argmin(np.abs(yaw)))], scored[int(np.argmax(yaw))]]


def save_crops(seq: Sequences, edit: str, label: str, frames: list, liq: dict, rows: list[int], path: Path) -> None:
    H, W = seq.inputs[0].shape[:2]
    boxes = crop_boxes([seq.truth[edit][i] for i in rows], [seq.inputs[i] for i in rows], (W, H))
    panels = [[(f"input yaw {seq.yaw[i]:+.0f}", seq.inputs[i]), (label, frames[i]),
               ("ground truth", seq.truth[edit][i]), ("2D liquify", liq[i])] for i in rows]
    cv2.imwrite(str(path), side_by_side(panels, boxes))


def save_atlas_crops(seq: Sequences, edit: str, without: list, with_atlas: list, rows: list[int], path: Path) -> None:
    H, W = seq.inputs[0].shape[:2]
    boxes = crop_boxes([seq.truth[edit][i] for i in rows], [seq.inputs[i] for i in rows], (W, H))
    panels = [[(f"input yaw {seq.yaw[i]:+.0f}", seq.inputs[i]), ("without atlas", without[i]),
               ("with atlas", with_atlas[i]), ("ground truth", seq.truth[edit][i])] for i in rows]
    cv2.imwrite(str(path), side_by_side(panels, boxes))


def _run_once_more(args, seqs, source, folder: Path, preset, m, key: str, timings, **options) -> tuple[list, dict]:
    """``process`` of ``source`` with model ``m`` once more (``options``: run_process's): (the frames, {})
    or ([], truth -> {"error": why}); its time under ``timings[key]``."""
    try:
        got, took = run_process(source, folder, preset, m, neutral_frames=args.neutral_frames, **options)
    except RuntimeError as exc:
        print(exc, file=sys.stderr)
        return [], {t: {"error": str(exc)} for t in seqs}
    timings[key] = took
    if len(got) < args.frames:
        return [], {t: {"error": f"process wrote {len(got)} of {args.frames} frames"} for t in seqs}
    return got, {}


def run_with_atlas(args, data, seqs, video, preset, e, m, frames, scored, truth_shifts, rows, out, timings,
                   oracle: dict) -> dict:
    """Edit ``e`` with model ``m`` once more with ``process --atlas on``: its scores per truth (and
    the crops against ``frames``, the run without the atlas, and the first truth); ``oracle``:
    run_process's landmark oracle, if any."""
    folder = out / "frames" / f"synthetic_{e}_{model_tag(m)}_atlas"
    got, failed = _run_once_more(args, seqs, video, folder, preset, m, f"process_{e}_{model_tag(m)}_atlas_s",
                                 timings, pythonpath=args.pythonpath, data=data,
                                 extra_args=(*args.process_args, "--atlas", "on"), **oracle)
    if failed:
        return failed
    first = next(iter(seqs))
    save_atlas_crops(seqs[first], e, frames, got, rows, out / f"crops_atlas_{e}_{model_tag(m)}.png")
    if not args.keep_frames:
        shutil.rmtree(folder)
    return {t: score_sequence(seq, e, got, scored, truth_shifts[t]) for t, seq in seqs.items()}


def model_tag(model: str) -> str:
    """A model's name in rows and file names: a ``.npz`` model file's stem, else the name itself."""
    return Path(model).stem if model.endswith(".npz") else model


def run_with_depth(args, data, seqs, rgbd, preset, e, m, scored, truth_shifts, liq, rows, out, timings) -> dict:
    """Edit ``e`` with model ``m`` on the RGB-D recording ``rgbd`` of the same input (each fit refined
    on its depth): its scores per truth, and its crops (``crops_EDIT_MODEL_depth.png``)."""
    folder = out / "frames" / f"synthetic_{e}_{model_tag(m)}_depth"
    got, failed = _run_once_more(args, seqs, rgbd, folder, preset, m, f"process_{e}_{model_tag(m)}_depth_s", timings, data=data,
                                 extra_args=args.process_args)
    if failed:
        return failed
    for t, seq in seqs.items():
        save_crops(seq, e, f"result ({model_tag(m)} + depth)", got, liq[t], rows,
                   out / crops_name(e, model_tag(m) + "_depth", t, args.truth_edit))
    if not args.keep_frames:
        shutil.rmtree(folder)
    return {t: score_sequence(seq, e, got, scored, truth_shifts[t]) for t, seq in seqs.items()}


def crops_name(edit: str, model: str, truth: str, truths: list[str]) -> str:
    """``crops_EDIT_MODEL.png``, with ``_TRUTH`` when several truths are scored."""
    return f"crops_{edit}_{model}" + (f"_{truth}" if len(truths) > 1 else "") + ".png"


def synthetic(args, data: Path, out: Path) -> dict:
    """Parts 1–3: render (the input once per truth, the same frames), run process per model and
    edit, score against every truth of ``args.truth_edit``, crop."""
    t0 = time.perf_counter()
    scene = make_scene(data, args.frames)
    specs = [EDITS[e] for e in args.edits]
    seqs = {t: render_sequences(scene, specs, args.workers or None, t) for t in args.truth_edit}
    first = seqs[args.truth_edit[0]]
    render_s = time.perf_counter() - t0
    video = write_lossless(first.inputs, out / "synthetic.mkv")
    rgbd = write_rgbd_input(scene, first.inputs, out / "synthetic_rgbd") if args.depth else None
    (out / "presets").mkdir(exist_ok=True)
    model_rest = scene.rest[: scene.model_vertices]
    presets = {sp.name: write_preset(sp, model_rest, scene.landmarks, scene.model_triangles, out / "presets")
               for sp in specs}
    scored = list(range(args.neutral_frames, args.frames))
    rows = crop_frames(first, scored)
    results, timings = {t: {} for t in seqs}, {"render_s": render_s}
    oracle = {}
    if args.landmark_oracle is not None:
        H, W = first.inputs[0].shape[:2]
        found = write_true_landmarks(out / "true_landmarks.npz", true_landmarks(scene), (W, H))
        oracle = {"module": LANDMARK_ORACLE, "environment": process_environment(found, args.landmark_oracle)}
    for sp in specs:
        e = sp.name
        liq, truth_shifts = {}, {}
        for t, seq in seqs.items():
            liq[t] = {i: liquified(seq, e, i) for i in scored}
            truth_shifts[t] = handle_shifts(seq, e, seq.truth[e], scored)
            results[t][e] = {"do nothing": score_sequence(seq, e, seq.inputs, scored, truth_shifts[t]),
                             "2D liquify": score_sequence(seq, e, [liq[t].get(i) for i in range(args.frames)],
                                                          scored, truth_shifts[t])}
        if args.oracle:
            solved = oracle_frames(scene, first.inputs, deformer_displacement(sp, scene), list(range(args.frames)))
            for t, seq in seqs.items():
                true = oracle_frames(scene, seq.inputs, seq.displacements[e], list(range(args.frames)))
                for label, frames in ((ORACLE_RENDERER, true), (ORACLE_DEFORMER, solved)):
                    results[t][e][label] = score_sequence(seq, e, frames, scored, truth_shifts[t])
        for m, label, pythonpath in [(m, *v) for m in args.models for v in [("", args.pythonpath), *args.variants]]:
            tag = model_tag(m)
            row = tag if not label else f"{tag} [{label}]"
            folder = out / "frames" / f"synthetic_{e}_{tag}{label and '_' + label}"
            try:
                frames, took = run_process(video, folder, presets[e], m, neutral_frames=args.neutral_frames,
                                           pythonpath=pythonpath, data=data, extra_args=args.process_args, **oracle)
            except RuntimeError as exc:
                print(exc, file=sys.stderr)
                for t in seqs:
                    results[t][e][row] = {"error": str(exc)}
                continue
            timings[f"process_{e}_{tag}{label and '_' + label}_s"] = took
            if len(frames) < args.frames:
                for t in seqs:
                    results[t][e][row] = {"error": f"process wrote {len(frames)} of {args.frames} frames"}
                continue
            for t, seq in seqs.items():
                results[t][e][row] = score_sequence(seq, e, frames, scored, truth_shifts[t])
                save_crops(seq, e, f"result ({row})", frames, liq[t], rows,
                           out / crops_name(e, tag + (label and "_" + label), t, args.truth_edit))
            if rgbd is not None and not label:
                for t, got in run_with_depth(args, data, seqs, rgbd, presets[e], e, m, scored, truth_shifts, liq,
                                             rows, out, timings).items():
                    results[t][e][f"{tag} + depth"] = got
            if e in args.atlas_edits and not label:
                for t, got in run_with_atlas(args, data, seqs, video, presets[e], e, m, frames, scored, truth_shifts,
                                             rows, out, timings, oracle).items():
                    results[t][e][f"{tag} + atlas"] = got
            if not args.keep_frames:
                shutil.rmtree(folder)
        for t, seq in seqs.items():
            results[t][e]["ground truth (measurement check)"] = {
                "landing": landing_by_yaw(landing_samples(seq, e, truth_shifts[t], None)),
                "lips_px": lip_shift(seq, e, seq.truth[e], scored)}
    return {"results": results[args.truth_edit[0]], "results_by_truth": results,
            "presets": {k: str(v) for k, v in presets.items()}, "timings": timings,
            "yaw_range": [float(first.yaw[scored].min()), float(first.yaw[scored].max())]}


def real_videos(args, data: Path, out: Path, presets: dict) -> list[dict]:
    """Part 4: each real video through process with each model and edit, against its input."""
    rows = []
    for name in args.real_videos:
        video = data / "video" / f"{name}.mp4"
        if not video.is_file():
            rows.append({"video": name, "model": "–", "edit": "–", "error": f"{video} not found",
                         "sharpness": float("nan"), "seam": float("nan"), "area": float("nan"), "frames": 0})
            continue
        inputs = read_video(video, args.real_frames)
        for m in args.models:
            for e, preset in presets.items():
                folder = out / "frames" / f"{name}_{e}_{model_tag(m)}"
                row = {"video": name, "model": model_tag(m), "edit": e}
                try:
                    frames, took = run_process(video, folder, Path(preset), m, args.real_frames, args.neutral_frames,
                                               args.pythonpath, data, args.process_args)
                except RuntimeError as exc:
                    print(exc, file=sys.stderr)
                    rows.append({**row, "error": str(exc), "sharpness": float("nan"), "seam": float("nan"),
                                 "area": float("nan"), "frames": 0})
                    continue
                pool = Pooled()
                for i in range(args.neutral_frames, min(len(frames), len(inputs))):
                    score_real_frame(pool, frames[i], inputs[i])
                s = summarise(pool)
                rows.append({**row, "sharpness": s["sharpness"], "seam": s["seam"], "area": pool.mean("area"),
                             "frames": int(pool.count.get("area", 0)), "process_s": took})
                if not args.keep_frames:
                    shutil.rmtree(folder)
    return rows


def git_revision(pythonpath: str = "") -> str:
    """The revision of the facesculpt that process runs: the checkout's (``git describe``), or
    the folder given by ``--pythonpath``."""
    if pythonpath:
        return f"facesculpt from {pythonpath}"
    try:
        return subprocess.run(["git", "-C", str(REPO), "describe", "--always", "--dirty"], capture_output=True,
                              text=True, timeout=10).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        return "unknown"


def markdown(report: dict) -> str:
    truths = report.get("truth_edit", ["falloff"])
    truths = [truths] if isinstance(truths, str) else truths
    by_truth = report.get("results_by_truth", {truths[0]: report["results"]})
    parts = [
        f"# bench_realism ({report['revision']}, {report['frames']} frames, scored "
        f"{report['frames'] - report['neutral_frames']}, yaw {report['yaw_range'][0]:+.0f}..{report['yaw_range'][1]:+.0f}, "
        f"truth edit {', '.join(truths)}"
        + ("" if report.get("landmark_oracle_keep") is None else
           f", inner landmarks: {report['landmark_oracle_keep']:g} of the detector's error kept") + ")"]
    for t in truths:
        said = "" if len(truths) == 1 else f" (truth edit {t})"
        parts += [f"## Synthetic set against ground truth (edit region){said}", synthetic_table(by_truth[t]),
                  f"## Handle landing by yaw: median error % of the true image displacement (reach){said}",
                  landing_table(by_truth[t])]
    parts += ["## Real videos (no ground truth): re-rendered region against the input", real_table(report["real"])]
    return "\n\n".join(parts) + "\n"


def _clean(x):
    if isinstance(x, dict):
        return {k: _clean(v) for k, v in x.items()}
    if isinstance(x, list):
        return [_clean(v) for v in x]
    if isinstance(x, float) and not np.isfinite(x):
        return None if np.isnan(x) else ("inf" if x > 0 else "-inf")
    return x


def main(argv=None) -> int:
    args = parse_args(argv)
    data = shared_data_dir()
    if data is None or not (data / "sfm").is_dir() or not (data / "video" / "s18.mp4").is_file():
        print("bench_realism needs the shared data (../shared/data or FACESCULPT_DATA: sfm/, video/s18.mp4)",
              file=sys.stderr)
        return 2
    out = args.out or Path(tempfile.mkdtemp(prefix="bench_realism_"))
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    syn = synthetic(args, data, out)
    real = real_videos(args, data, out, syn["presets"])
    report = {"revision": git_revision(args.pythonpath), "frames": args.frames, "neutral_frames": args.neutral_frames,
              "models": args.models, "edits": args.edits, "truth_edit": args.truth_edit,
              "landmark_oracle_keep": args.landmark_oracle, **syn, "real": real,
              "total_s": time.perf_counter() - t0}
    (out / "results.json").write_text(json.dumps(_clean(report), indent=1))
    text = markdown(report)
    (out / "results.md").write_text(text)
    print(text)
    print(f"results, crops and presets in {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
