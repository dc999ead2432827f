"""Nostrils through ``nose_longer`` (issue 51): the darkest skin of the nose and the flicker of the
edit region, per frame, on the shared real videos, with the shipped preset and with the tip alone
(the preset before issue 51) in the same run.

    python -m benchmarks.bench_nostrils [--videos d0,d3,d12] [--frames 90] [--strengths 1,2] [--crops DIR]

Each video's first ``--frames`` frames go through the offline pipeline (``facesculpt process``'s:
facemesh, the neutral learned on the first frames as ``process`` does, then every frame edited),
once per preset and strength:

- ``tip``: the tip alone moved 6 mm down and 6 mm out (``nose_longer`` before issue 51);
- ``shipped``: ``nose_longer`` as shipped (the tip, and the columella and nostrils with it, the upper lip held).

Per frame:

- darkness: the mean grey level of the darkest 5 % of the nose region, output over input (1: the
  nostrils as dark as in the input; above 1: lighter). The nose region is the union of the convex
  hulls, in the input and in the output, of the face mesh's vertices within ``NOSE_RADIUS`` times
  the distance between the eyes' inner corners of its nose tip (the fitted neutral, model space:
  the tip, the nostrils, the columella, the lower bridge), grown by ``GROW`` of that distance;
- flicker: the mean absolute frame-to-frame change of the grey level over the pixels the
  compositor re-rendered on both frames, output over input on the same pixels (1: the edit region
  changes from frame to frame as the input does).

Prints a table (means, and the worst frame's darkness), and with ``--crops DIR`` writes
``nostrils_VIDEO_S.png``: input | tip | shipped around the nose, at three frames, enlarged 3x.
"""

from __future__ import annotations

import argparse
import copy
from pathlib import Path

import cv2
import numpy as np

NOSE_RADIUS = 0.6   # the nose region: face-mesh vertices this close to the tip, as a share of the eyes' inner corners' distance
GROW = 0.1          # ... grown by this share of the eyes' inner corners' distance in the frame (the nostrils' rims)
DARKEST_SHARE = 0.05


def read_video(name: str, n: int) -> tuple[list[np.ndarray], float]:
    """The first ``n`` frames of the shared video ``name`` (BGR) and its fps."""
    from facesculpt.paths import shared_data_dir

    data = shared_data_dir()
    if data is None:
        raise SystemExit("shared data not found: set FACESCULPT_DATA")
    cap, out = cv2.VideoCapture(str(data / "video" / f"{name}.mp4")), []
    while len(out) < n:
        ok, frame = cap.read()
        if not ok:
            break
        out.append(frame)
    fps = cap.get(cv2.CAP_PROP_FPS) or 25.0
    cap.release()
    return out, fps


def tip_only(preset: dict) -> dict:
    """``preset`` with only its first edit's nose-tip handle and no pins (the preset before issue 51)."""
    doc = copy.deepcopy(preset)
    doc["static"] = []
    doc["edits"] = [dict(doc["edits"][0], handles=[h for h in doc["edits"][0]["handles"]
                                                    if h.get("landmark") == "nose_tip"])]
    return doc


def darkest_mean(grey: np.ndarray, mask: np.ndarray) -> float:
    """Mean of the darkest DARKEST_SHARE of ``grey`` (h, w) over ``mask`` (h, w) bool."""
    values = np.sort(grey[mask].ravel())
    return float(values[: max(1, int(len(values) * DARKEST_SHARE))].mean())


def hull_mask(shape: tuple[int, int], *point_sets: np.ndarray) -> np.ndarray:
    """(h, w) bool: the union of the convex hulls of each (N, 2) pixel set."""
    mask = np.zeros(shape, np.uint8)
    for pts in point_sets:
        cv2.fillConvexPoly(mask, cv2.convexHull(np.round(pts).astype(np.int32)), 1)
    return mask > 0


def nose_vertices(neutral: np.ndarray, model) -> np.ndarray:
    """(V,) bool: the vertices of ``neutral`` (V, 3) model mm within NOSE_RADIUS times the distance
    between the eyes' inner corners of the nose tip (``model``'s named landmarks)."""
    at = dict(zip(model.landmark_names, model.landmark_vertices))
    reach = NOSE_RADIUS * np.linalg.norm(neutral[at["left_eye_inner"]] - neutral[at["right_eye_inner"]])
    return np.linalg.norm(neutral - neutral[at["nose_tip"]], axis=1) < reach


def run(frames: list[np.ndarray], fps: float, preset: dict, calibration: int) -> tuple[np.ndarray, list]:
    """Per frame (darkness ratio, flicker of output, flicker of input) and the outputs."""
    from facesculpt.app.pipeline import Pipeline

    rows, outs, last = [], [], None
    with Pipeline("facemesh") as pipe:
        pipe.calibrate(frames[:calibration], fps)
        pipe.set_edits(preset)
        m = pipe.model
        at = dict(zip(m.landmark_names, m.landmark_vertices))
        tip, eyes = at["nose_tip"], [at["left_eye_inner"], at["right_eye_inner"]]
        for i, frame in enumerate(frames):
            result = pipe.process(frame, i / fps)
            outs.append(result.image)
            comp = pipe.compositor
            if result.fit is None or comp is None or comp.box is None:
                last = None
                continue
            nose = nose_vertices(pipe.neutral_of(min(result.fits)), m)
            region = hull_mask(frame.shape[:2], result.fit.projected[nose], comp.drawn_px(comp.deformed_px)[nose])
            grow = int(round(GROW * np.linalg.norm(np.subtract(*result.fit.projected[eyes]))))
            region = cv2.dilate(region.view(np.uint8), np.ones((2 * grow + 1,) * 2, np.uint8)) > 0
            g_in = cv2.cvtColor(frame, cv2.COLOR_BGR2GRAY).astype(np.float32)
            g_out = cv2.cvtColor(result.image, cv2.COLOR_BGR2GRAY).astype(np.float32)
            dark = darkest_mean(g_out, region) / max(darkest_mean(g_in, region), 1e-6)
            changed = comp.full_frame_regions()["changed"].astype(bool)
            flick_out = flick_in = np.nan
            if last is not None:
                both = changed & last[0]
                if both.any():
                    flick_out = float(np.abs(g_out - last[2])[both].mean())
                    flick_in = float(np.abs(g_in - last[1])[both].mean())
            last = (changed, g_in, g_out)
            rows.append((dark, flick_out, flick_in, i, *result.fit.projected[tip]))
    return np.array(rows), outs


def crop_strip(frames, outs_by_label, i: int, centre: np.ndarray, half: int) -> np.ndarray:
    x, y = np.round(centre).astype(int)
    h, w = frames[i].shape[:2]
    x0, y0 = max(0, x - half), max(0, y - half)
    x1, y1 = min(w, x + half), min(h, y + half)
    tiles = [frames[i][y0:y1, x0:x1]] + [o[i][y0:y1, x0:x1] for o in outs_by_label]
    return cv2.resize(np.hstack(tiles), None, fx=3, fy=3, interpolation=cv2.INTER_NEAREST)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--videos", default="d0,d3,d12")
    p.add_argument("--frames", type=int, default=90)
    p.add_argument("--strengths", default="1,2")
    p.add_argument("--calibration", type=int, default=30, help="frames the neutral is learned from first")
    p.add_argument("--crops", default="", metavar="DIR")
    args = p.parse_args()
    from facesculpt.app.pipeline import read_preset
    from facesculpt.nodes.deformer.preset_format import scale_preset
    from facesculpt.runtime.process_limits import limit_threads

    limit_threads(1)
    shipped = read_preset("nose_longer")
    print("| video | strength | preset | darkness out/in (mean, worst frame) | frames within 10 % | flicker out/in |")
    print("| --- | --- | --- | --- | --- | --- |")
    for name in args.videos.split(","):
        frames, fps = read_video(name, args.frames)
        for s in (float(x) for x in args.strengths.split(",")):
            outs = {}
            for label, preset in (("tip", tip_only(shipped)), ("shipped", shipped)):
                rows, outs[label] = run(frames, fps, scale_preset(preset, s), args.calibration)
                dark, fo, fi = rows[:, 0], rows[:, 1], rows[:, 2]
                ok = np.isfinite(fo)
                within = int(np.sum(np.abs(dark - 1.0) <= 0.10))
                print(f"| {name} | {s:g} | {label} | {dark.mean():.3f}, {dark[np.argmax(np.abs(dark - 1))]:.3f} "
                      f"| {within} / {len(dark)} | {fo[ok].mean() / fi[ok].mean():.3f} |", flush=True)
            if args.crops:
                Path(args.crops).mkdir(parents=True, exist_ok=True)
                idx = [len(frames) // 6, len(frames) // 2, len(frames) - 1 - len(frames) // 6]
                h = frames[0].shape[0]
                tips = {int(r[3]): r[4:6] for r in rows}
                strips = [crop_strip(frames, [outs["tip"], outs["shipped"]], i, tips.get(i, (frames[0].shape[1] / 2, h / 2)),
                                     max(24, h // 8)) for i in idx]
                cv2.imwrite(str(Path(args.crops) / f"nostrils_{name}_{s:g}.png"), np.vstack(strips))


if __name__ == "__main__":
    main()
