"""Background benchmark (issue 16): what an edit that shrinks the face uncovers, filled by each
fill and by the background plate, against the true background of the realism benchmark's
synthetic set, and the plate on a real video.

1. Synthetic set (benchmarks/realism/: the textured SFM head turning over a static background,
   640x480, 25 fps, rendered by the benchmark's own rasteriser; a still camera; the background is
   the realism set's (s18.mp4's out-of-focus room) with sharp clutter drawn over it, boxes, lines
   and words, unless ``--background s18``; the head turns as in the realism set and also sways
   sideways ``--sway`` mm, default 40, so that what it covers in one frame it shows in another) with the edits that uncover background: ``jaw10`` (both sides of the jaw 10 mm toward
   the midline) and ``slim8`` (both cheeks 8 mm toward the midline).
2. The same stages as ``facesculpt process`` in-process (facesculpt.app.pipeline.Pipeline:
   calibrate on the first ``--neutral-frames``, the preset solved once, then every frame analysed
   once) and each frame composited by one compositor per method (``pushpull``, ``telea``, ``ns``,
   ``patch``, ``drag`` (the background beside the face carried in by its motion), ``plate``
   (push-pull under the plate), ``patch+plate``, ``drag+plate``, and ``plate-face-only``: the plate
   learning everywhere outside the face, people included, as before the person segmentation): the fills differ only
   in the compositor, so the fits are shared; process --fill/--plate runs the same compositor.
   The model ``truth`` (in the default ``--models``) takes the fit away: the true head moved by
   the true edit through the same compositors, i.e. what the fills and the plate give when
   registration is perfect.
3. Scored over the frames after the neutral: fill-region PSNR (dB) and SSIM, the region being
   the pixels that were face in the input and are background in the ground truth; "do nothing"
   is the input itself; also PSNR over the part of that region push-pull's compositor filled
   (uncovered and not under the deformed face: the rest is face in every method). Flicker: the mean absolute frame-to-frame change (grey levels) of the
   result over the pixels the compositor filled (uncovered, not under the deformed face) in both
   frames, next to the input's over its background in both frames (a still camera: 0). Crops ``crops_EDIT_MODEL.png``: input | each method | ground truth
   at the most turned-left, frontal and most turned-right scored frames, enlarged 2x.
4. Real video (default d3.mp4; no ground truth) with the shipped ``cheeks`` preset (cheeks
   pushed 8 mm in toward the midline), model ``facemesh``, the drag fill (the default): the plate's
   share of the uncovered pixels per frame (pixels it gave at least half the colour), with people
   kept off it and learning everywhere outside the face, flicker in the uncovered region against the
   input's background (pixels away from the face), and ``real_VIDEO.png``: input | drag | drag +
   plate | drag + plate, face only, at the frame where the face-only plate gives the most pixels.

Writes ``results.md`` and ``results.json`` to ``--out`` (default: a new temporary folder).

Run: ``python -m benchmarks.bench_background [--out DIR] [--frames 90] [--models facemesh,sfm]
[--methods pushpull,telea,ns,patch,drag,plate,patch+plate,drag+plate] [--real-video d3] [--real-frames 150]``.
Needs the shared data and ``facesculpt setup``.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np

from benchmarks.realism.edits import EditSpec, displacement, write_preset
from benchmarks.realism.metrics import changed, psnr_from_mse, squared_error, ssim_map
from benchmarks.realism.raster import project_pixels
from benchmarks.realism.report import crop_boxes, side_by_side
from benchmarks.realism.scene import Scene, make_scene
from benchmarks.realism.sequences import read_video, render_sequences
from facesculpt.app.pipeline import Pipeline, read_preset
from facesculpt.geometry import merge_deformation
from facesculpt.nodes.fitter.config import FitterConfig
from facesculpt.paths import shared_data_dir

EDITS = {
    "jaw10": EditSpec("jaw10", {"vertex:1886": (-10.0, 0.0, 0.0), "vertex:1882": (10.0, 0.0, 0.0)}, 40.0,
                      "both sides of the jaw 10 mm toward the midline", True),
    "slim8": EditSpec("slim8", {"left_cheek": (-8.0, 0.0, 0.0), "right_cheek": (8.0, 0.0, 0.0)}, 50.0,
                      "both cheeks 8 mm toward the midline (face slimmed)", True),
}
METHODS = {"pushpull": ("pushpull", False), "telea": ("telea", False), "ns": ("ns", False),
           "patch": ("patch", False), "drag": ("drag", False), "plate": ("pushpull", True),
           "patch+plate": ("patch", True), "drag+plate": ("drag", True),
           "plate-face-only": ("pushpull", "face only"), "drag+plate-face-only": ("drag", "face only")}
SWAY_PERIOD = 50
REAL_PRESET = Path(__file__).resolve().parent.parent / "facesculpt" / "nodes" / "deformer" / "presets" / "cheeks.json"


def parse_args(argv=None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--out", type=Path, default=None)
    p.add_argument("--frames", type=int, default=90)
    p.add_argument("--neutral-frames", type=int, default=30)
    p.add_argument("--models", default="facemesh,sfm,truth",
                   help="models fitted as process does; 'truth': no fit, the true head and edit (default facemesh,sfm,truth)")
    p.add_argument("--edits", default=",".join(EDITS))
    p.add_argument("--methods", default=",".join(METHODS))
    p.add_argument("--real-video", default="d3", help="shared video for part 4 ('' for none)")
    p.add_argument("--real-frames", type=int, default=150)
    p.add_argument("--workers", type=int, default=0)
    p.add_argument("--sway", type=float, default=40.0, metavar="MM",
                   help="the head also sways sideways this far (mm, period 50 frames; default 40); 0: the realism "
                        "set's motion alone (turning, 12 mm of drift)")
    p.add_argument("--background", choices=("cluttered", "s18"), default="cluttered",
                   help="behind the head: s18's room with sharp clutter drawn over it (default), or s18's room "
                        "alone (out of focus)")
    a = p.parse_args(argv)
    a.models, a.edits, a.methods = ([v for v in x.split(",") if v] for x in (a.models, a.edits, a.methods))
    return a


class SwayingScene(Scene):
    """The realism scene with the head also swaying sideways, ``sway_mm`` (camera x, mm) over a
    period of ``SWAY_PERIOD`` frames, as a person in front of a still camera does."""

    sway_mm: float = 0.0

    def to_camera(self, V: np.ndarray, i: int) -> np.ndarray:
        return super().to_camera(V, i) + np.array([self.sway_mm * np.sin(2 * np.pi * i / SWAY_PERIOD), 0.0, 0.0])


def cluttered_background(base: np.ndarray, seed: int = 3) -> np.ndarray:
    """``base`` (H, W, 3) uint8 with sharp clutter drawn over it: filled and outlined boxes,
    lines and printed words in random colours (a room full of things in focus)."""
    rng = np.random.default_rng(seed)
    img = base.copy()
    H, W = img.shape[:2]
    for _ in range(260):
        x, y = int(rng.integers(0, W)), int(rng.integers(0, H))
        colour = tuple(int(c) for c in rng.integers(0, 256, 3))
        kind = rng.integers(0, 4)
        if kind == 0:
            cv2.rectangle(img, (x, y), (x + int(rng.integers(4, 40)), y + int(rng.integers(4, 40))), colour, -1)
        elif kind == 1:
            cv2.rectangle(img, (x, y), (x + int(rng.integers(8, 60)), y + int(rng.integers(8, 60))), colour, 2)
        elif kind == 2:
            cv2.line(img, (x, y), (x + int(rng.integers(-60, 60)), y + int(rng.integers(-60, 60))), colour, 2)
        else:
            cv2.putText(img, "".join(chr(int(c)) for c in rng.integers(65, 91, 4)), (x, y),
                        cv2.FONT_HERSHEY_SIMPLEX, 0.6, colour, 2)
    return img


def compositors(names: list[str], size: tuple[int, int]) -> dict:
    from facesculpt.nodes.renderer import Compositor
    from facesculpt.nodes.renderer.person_segmentation import PersonSegmenter

    first = None
    out = {}
    people = PersonSegmenter() if any(METHODS[m][1] is True for m in names) else None
    for m in names:
        fill, plate = METHODS[m]  # plate True: as process --plate on (no person learned); "face only": as before
        out[m] = Compositor(size[0], size[1], ctx=first.ctx if first else None, inpaint=fill, plate=bool(plate),
                            segmenter=people if plate is True else None)
        first = first or out[m]
    return out


class Scores:
    """Pooled fill-region squared error, SSIM and flicker of one method."""

    def __init__(self):
        self.se = self.n = self.ssim = self.ns = self.flick = self.nf = self.se2 = self.n2 = 0.0

    def add(self, out, truth, region, prev_out=None, both=None, filled=None):
        """``region``: the fill region; ``both``: the pixels the flicker is taken over (None: none);
        ``filled``: the part of the region push-pull's compositor filled (None: none)."""
        se, n = squared_error(out, truth, region)
        self.se, self.n = self.se + se, self.n + n
        if filled is not None and filled.any():
            se, n = squared_error(out, truth, filled)
            self.se2, self.n2 = self.se2 + se, self.n2 + n
        s = ssim_map(out, truth)[region]
        self.ssim, self.ns = self.ssim + float(s.sum()), self.ns + s.size
        if prev_out is not None and both is not None and both.any():
            d = np.abs(cv2.cvtColor(out, cv2.COLOR_BGR2GRAY).astype(float)
                       - cv2.cvtColor(prev_out, cv2.COLOR_BGR2GRAY))[both]
            self.flick, self.nf = self.flick + float(d.sum()), self.nf + d.size

    def summary(self) -> dict:
        return {"psnr": psnr_from_mse(self.se / self.n) if self.n else float("nan"),
                "ssim": self.ssim / self.ns if self.ns else float("nan"),
                "flicker": self.flick / self.nf if self.nf else float("nan"), "pixels": self.n / 3,
                "psnr_filled": psnr_from_mse(self.se2 / self.n2) if self.n2 else float("nan"), "filled": self.n2 / 3}


class FittedFaces:
    """The faces ``facesculpt process`` draws: ``model`` fitted by the project's pipeline (calibrated
    on the first ``neutral_frames``), each edit's preset solved once on its neutral."""

    def __init__(self, model: str, inputs: list, presets: dict, neutral_frames: int):
        self.pipe = Pipeline(model, fit=FitterConfig(neutral_frames=neutral_frames))
        self.pipe.calibrate(inputs[:neutral_frames], 25.0)
        self.disps = {}
        for e, preset in presets.items():
            self.pipe.set_edits(None)
            self.pipe.set_edits(read_preset(preset))
            self.disps[e] = dict(self.pipe.displacements)
        self.fits = {}

    def analyse(self, frame: np.ndarray, i: int) -> None:
        self.fits, _ = self.pipe.analyse(frame, i / 25.0)

    def faces(self, edit: str, i: int) -> dict:
        """Face key -> (fitted (V, 3), projected (V, 2), triangles, deformed (V, 3)) of the frame
        analysed last, for the faces ``edit`` was solved on (as process draws them: no other)."""
        out = {}
        for key, fit in self.fits.items():
            d = self.disps[edit].get(key)
            if d is not None:
                out[key] = (fit.vertices, fit.projected, self.pipe.model.triangles,
                            merge_deformation(fit.vertices, fit.R, fit.scale, d))
        return out

    def close(self) -> None:
        self.pipe.close()


class TrueFaces:
    """No fit: the true head, moved by each edit's true displacement (model ``truth``): what the fill
    and the plate give when registration is perfect."""

    def __init__(self, scene: Scene, specs: dict):
        self.scene = scene
        self.disps = {e: displacement(sp, scene.rest, scene.landmarks) for e, sp in specs.items()}

    def analyse(self, frame: np.ndarray, i: int) -> None:
        pass

    def faces(self, edit: str, i: int) -> dict:
        sc, n = self.scene, self.scene.model_vertices
        X0, X1 = sc.to_camera(sc.rest, i)[:n], sc.to_camera(sc.rest + self.disps[edit], i)[:n]
        return {0: (X0, project_pixels(sc.K, X0), sc.model_triangles, X1)}

    def close(self) -> None:
        pass


def run_model(model: str, seq, scene, presets: dict, args, out: Path) -> dict:
    """Every edit and method of one model (``truth``: :class:`TrueFaces`) on the synthetic set."""
    H, W = seq.inputs[0].shape[:2]
    source = TrueFaces(scene, {e: EDITS[e] for e in presets}) if model == "truth" else \
        FittedFaces(model, seq.inputs, presets, args.neutral_frames)
    comps = {e: compositors(args.methods, (W, H)) for e in presets}
    scored = list(range(args.neutral_frames, args.frames))
    yaw = seq.yaw[scored]
    rows = [scored[int(np.argmin(yaw))], scored[int(np.argmin(np.abs(yaw)))], scored[int(np.argmax(yaw))]]
    scores = {e: {m: Scores() for m in ["do nothing", *args.methods]} for e in presets}
    truth_flicker = {e: Scores() for e in presets}
    kept = {e: {} for e in presets}
    prev = {e: {} for e in presets}
    ms = {m: [] for m in args.methods}
    share = {e: {m: [0, 0] for m in args.methods if METHODS[m][1]} for e in presets}
    for i, frame in enumerate(seq.inputs):
        source.analyse(frame, i)
        for e in presets:
            faces = source.faces(e, i)
            truth = seq.truth[e][i]
            region = seq.face[i] & ~changed(truth, scene.background)
            results, filled = {"do nothing": frame}, {}
            for m, comp in comps[e].items():
                results[m] = frame
                for key, face in faces.items():
                    results[m] = comp.render(results[m], *face, face_key=key)
                filled[m] = np.zeros((H, W), bool)
                if comp.box is not None:
                    x0, y0, x1, y1 = comp.box
                    filled[m][y0:y1, x0:x1] = (comp.inpainted_region != 0) & (comp.deformed_region == 0)
                if faces and comp.timings.get("total"):
                    ms[m].append(comp.timings["total"])
                if i in scored and m in share[e] and comp.plate_region is not None:
                    unc = (comp.inpainted_region != 0) & (comp.deformed_region == 0)
                    share[e][m][0] += int((comp.plate_region[unc] >= 0.5).sum())
                    share[e][m][1] += int(unc.sum())
            if i in scored:
                p = prev[e]
                for m, img in results.items():
                    both = filled[m] & p["filled"][m] if p and m in filled else None
                    scores[e][m].add(img, truth, region, p.get(m), both,
                                     region & filled["pushpull"] if "pushpull" in filled else None)
                bg = ~seq.face[i] & ~seq.face[i - 1]  # the input's background in both frames
                truth_flicker[e].add(frame, frame, region, p.get("do nothing"), bg)
            prev[e] = {**results, "filled": filled}
            if i in rows:
                kept[e][i] = results
    source.close()
    for e in presets:
        for comp in comps[e].values():
            comp.release()
        boxes = crop_boxes([seq.truth[e][i] for i in rows], [seq.inputs[i] for i in rows], (W, H))
        panels = [[(f"input yaw {seq.yaw[i]:+.0f}", seq.inputs[i])] + [(m, kept[e][i][m]) for m in args.methods]
                  + [("ground truth", seq.truth[e][i])] for i in rows]
        cv2.imwrite(str(out / f"crops_{e}_{model}.png"), side_by_side(panels, boxes))
    res = {e: {m: s.summary() for m, s in scores[e].items()} for e in presets}
    for e in presets:
        res[e]["input background"] = {"flicker": truth_flicker[e].summary()["flicker"]}
        for m, (a, b) in share[e].items():
            res[e][m]["plate_share"] = a / b if b else float("nan")
    res["render_ms_median"] = {m: float(np.median(v)) if v else float("nan") for m, v in ms.items()}
    return res


def real_video(args, data: Path, out: Path) -> dict:
    """Part 4: the plate's share of the uncovered pixels over a real video, flicker, a picture."""
    frames = read_video(data / "video" / f"{args.real_video}.mp4", args.real_frames)
    H, W = frames[0].shape[:2]
    pipe = Pipeline("facemesh", fit=FitterConfig(neutral_frames=args.neutral_frames))
    pipe.calibrate(frames[: args.neutral_frames], 25.0)
    pipe.set_edits(read_preset(REAL_PRESET))
    plates = ["drag+plate", "drag+plate-face-only"]
    comps = compositors(["drag"] + plates, (W, H))
    share, flick_out, flick_in, flick_same, flick_drag, best = {m: [] for m in plates}, [], [], [], [], (-1.0, None)
    prev = None
    for i, frame in enumerate(frames):
        fits, timings = pipe.analyse(frame, i / 25.0)
        outs = {}
        for m, comp in comps.items():
            pipe.compositor = comp
            outs[m] = pipe.compose(frame, fits, dict(timings)).image
        for m in plates:
            comp = comps[m]
            uncovered = np.zeros((H, W), bool)
            plate_w = np.zeros((H, W), np.float32)
            if comp.box is not None and comp.inpainted_region is not None:
                x0, y0, x1, y1 = comp.box
                uncovered[y0:y1, x0:x1] = (comp.inpainted_region != 0) & (comp.deformed_region == 0)
                if comp.plate_region is not None:
                    plate_w[y0:y1, x0:x1] = comp.plate_region
            n = int(uncovered.sum())
            s = float((plate_w[uncovered] >= 0.5).mean()) if n else float("nan")
            share[m].append(s)
            if m == plates[0]:
                plate_uncovered = uncovered
            if m == plates[-1] and n and s * n > best[0]:  # the frame where the face-only plate gives the most
                best = (s * n, i, outs, frame, uncovered)
        face = np.zeros((H, W), np.uint8)
        if fits:
            hull = cv2.convexHull(np.asarray(fits[min(fits)].projected, np.float32)).astype(np.int32)
            cv2.fillConvexPoly(face, hull, 1)
        far = cv2.dilate(face, np.ones((41, 41), np.uint8)) == 0
        if prev is not None:
            g = [cv2.cvtColor(x, cv2.COLOR_BGR2GRAY).astype(float)
                 for x in (frame, prev[0], outs[plates[0]], prev[1], outs["drag"], prev[4])]
            flick_in.append(float(np.abs(g[0] - g[1])[far & prev[3]].mean()))
            both = plate_uncovered & prev[2]
            if both.any():
                flick_out.append(float(np.abs(g[2] - g[3])[both].mean()))
                flick_same.append(float(np.abs(g[0] - g[1])[both].mean()))  # the input's own, same pixels
                flick_drag.append(float(np.abs(g[4] - g[5])[both].mean()))  # the drag's without the plate
        prev = (frame, outs[plates[0]], plate_uncovered, far, outs["drag"])
    pipe.compositor = None
    pipe.close()
    for comp in comps.values():
        comp.release()
    if best[1] is not None:
        _, i, outs, frame, unc = best
        ys, xs = np.nonzero(unc)
        cx, cy = (xs.min() + xs.max()) // 2, (ys.min() + ys.max()) // 2
        side = int(min(max(xs.max() - xs.min(), ys.max() - ys.min(), 120) + 80, W, H))
        x0, y0 = int(np.clip(cx - side // 2, 0, W - side)), int(np.clip(cy - side // 2, 0, H - side))
        box = [(x0, y0, x0 + side, y0 + side)]
        panels = [[(f"input frame {i}", frame), ("drag (no plate)", outs["drag"]), ("drag + plate", outs[plates[0]]),
                   ("drag + plate, face only", outs[plates[1]])]]
        cv2.imwrite(str(out / f"real_{args.real_video}.png"), side_by_side(panels, box))
    return {"video": args.real_video, "share": share, "best_frame": best[1],
            "flicker_uncovered": float(np.mean(flick_out)) if flick_out else float("nan"),
            "flicker_input_background": float(np.mean(flick_in)) if flick_in else float("nan"),
            "flicker_input_same_pixels": float(np.mean(flick_same)) if flick_same else float("nan"),
            "flicker_drag_alone": float(np.mean(flick_drag)) if flick_drag else float("nan")}


def markdown(report: dict, args) -> str:
    lines = [f"# bench_background ({report['frames']} frames, scored {report['frames'] - args.neutral_frames}, "
             f"sway {args.sway:g} mm, background {args.background})", "",
             "Fill region: PSNR dB / SSIM / flicker (mean |frame-to-frame change|, grey levels)", "",
             "| edit | model | " + " | ".join(["do nothing", *args.methods]) + " |",
             "| --- | --- | " + " | ".join("---" for _ in range(len(args.methods) + 1)) + " |"]
    for m in args.models:
        for e in args.edits:
            r = report["synthetic"][m][e]
            cells = [f"{r[k]['psnr']:.2f} / {r[k]['ssim']:.3f} / {r[k]['flicker']:.2f}" for k in ["do nothing", *args.methods]]
            lines.append(f"| {e} | {m} | " + " | ".join(cells) + " |")
    lines += [] if "pushpull" not in args.methods else [
        "", "PSNR (dB) over the part of the fill region push-pull's compositor filled (the rest stays under "
              "the deformed face in every method): " + "; ".join(
                  f"{e} {m}: " + ", ".join(f"{k} {report['synthetic'][m][e][k]['psnr_filled']:.2f}"
                                           for k in ["do nothing", *args.methods])
                  + f" ({report['synthetic'][m][e]['pushpull']['filled'] / (report['frames'] - args.neutral_frames):.0f} px)"
                  for m in args.models for e in args.edits)]
    lines += ["", "Flicker of the input's background (both frames): " + "; ".join(
        f"{e} {m} {report['synthetic'][m][e]['input background']['flicker']:.2f}" for m in args.models for e in args.edits)]
    lines += ["", "Plate share of the uncovered pixels (scored frames): " + "; ".join(
        f"{e} {m} {k} {report['synthetic'][m][e][k].get('plate_share', float('nan')):.2f}"
        for m in args.models for e in args.edits for k in args.methods if METHODS[k][1])]
    lines += ["", "Fill-region pixels per frame: " + "; ".join(
        f"{e} {m} {report['synthetic'][m][e]['pushpull']['pixels'] / (report['frames'] - args.neutral_frames):.0f}"
        for m in args.models for e in args.edits if "pushpull" in report['synthetic'][m][e])]
    lines += ["", "Median compositor total (ms) per method and model: " + "; ".join(
        f"{m}: " + ", ".join(f"{k} {v:.1f}" for k, v in report["synthetic"][m]["render_ms_median"].items())
        for m in args.models)]
    if report.get("real"):
        r = report["real"]
        for m, share in r["share"].items():
            s = np.array(share, float)
            chunks = [f"{i}-{min(i + 15, len(s)) - 1}: {np.nanmean(s[i:i + 15]):.2f}" for i in range(0, len(s), 15)
                      if np.isfinite(s[i:i + 15]).any()]
            lines += ["", f"Real video {r['video']}, {m}: share of the uncovered pixels by frames: " + "; ".join(chunks)]
        lines += [f"flicker in the uncovered region {r['flicker_uncovered']:.2f} (the drag alone "
                  f"{r['flicker_drag_alone']:.2f}), the input's at the same pixels "
                  f"{r['flicker_input_same_pixels']:.2f}, input background {r['flicker_input_background']:.2f}; "
                  f"picture at frame {r['best_frame']}"]
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    args = parse_args(argv)
    data = shared_data_dir()
    if data is None:
        print("bench_background needs the shared data (../shared/data or FACESCULPT_DATA)", file=sys.stderr)
        return 2
    out = args.out or Path(tempfile.mkdtemp(prefix="bench_background_"))
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    report = {"frames": args.frames, "synthetic": {}}
    if args.models and args.edits:
        synthetic(args, data, out, report, t0)
    if args.real_video:
        report["real"] = real_video(args, data, out)
    report["total_s"] = time.perf_counter() - t0
    (out / "results.json").write_text(json.dumps(report, indent=1, default=float))
    text = markdown(report, args)
    (out / "results.md").write_text(text)
    print(text)
    print(f"results and crops in {out}")
    return 0


def synthetic(args, data: Path, out: Path, report: dict, t0: float) -> None:
    """Parts 1-3 for every model into ``report["synthetic"]``."""
    scene = make_scene(data, args.frames)
    if args.sway:
        scene = SwayingScene(**{f: getattr(scene, f) for f in scene.__dataclass_fields__})
        scene.sway_mm = args.sway
    if args.background == "cluttered":
        scene.background = cluttered_background(scene.background)
    specs = [EDITS[e] for e in args.edits]
    seq = render_sequences(scene, specs, args.workers or None)
    model_rest = scene.rest[: scene.model_vertices]
    presets = {sp.name: write_preset(sp, model_rest, scene.landmarks, scene.model_triangles, out) for sp in specs}
    for m in args.models:
        report["synthetic"][m] = run_model(m, seq, scene, presets, args, out)
        print(f"{m} done ({time.perf_counter() - t0:.0f} s)", file=sys.stderr)


if __name__ == "__main__":
    sys.exit(main())
