"""A contact sheet of the shipped presets (issue 51): every shipped preset at each strength on every
shared video, input | output crops around the face at three frames each, one JPEG per video.

    python -m benchmarks.contact_sheet [--out docs/results/images] [--videos d0,d3,d12,s18]
        [--strengths 1,2] [--frames 90] [--turned d3] [--height 170]

Each video's first ``--frames`` frames go through the offline pipeline (``facesculpt process``'s:
facemesh, the neutral learned on the first frames, then every frame edited), once per shipped
preset (the deformer's ``presets/*.json``) and strength. The three
frames shown are at 1/6, 1/2 and 5/6 of the frames read; for the videos of ``--turned`` a fourth
sheet (``contact-VIDEO-turned.jpg``) shows the three frames where the fitted head is turned most
(largest |yaw|, at least a second apart), so every preset is also seen on a turned face. Rows: preset
x strength; columns: (input | output) per frame, the crop the face's box grown by a fifth of its size,
scaled to ``--height`` px. Writes ``contact-VIDEO.jpg`` to ``--out`` and prints each sheet's frames
(and yaws).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import cv2
import numpy as np

from benchmarks.bench_nostrils import read_video

JPEG_QUALITY = 80


def run(frames: list[np.ndarray], fps: float, preset: dict | None, calibration: int = 30):
    """The outputs, and per frame the face's box (x0, y0, x1, y1) px and yaw (degrees) or None."""
    from facesculpt.app.pipeline import Pipeline
    from facesculpt.geometry.head_angles import euler_from_rotation

    outs, boxes, yaws = [], [], []
    with Pipeline("facemesh") as pipe:
        pipe.calibrate(frames[:calibration], fps)
        if preset is not None:
            pipe.set_edits(preset)
        for i, frame in enumerate(frames):
            result = pipe.process(frame, i / fps)
            outs.append(result.image)
            if result.fit is None:
                boxes.append(None)
                yaws.append(None)
                continue
            lo, hi = result.fit.projected.min(0), result.fit.projected.max(0)
            boxes.append((*lo, *hi))
            yaws.append(euler_from_rotation(result.fit.R)[0])
    return outs, boxes, yaws


def crop(image: np.ndarray, box, height: int) -> np.ndarray:
    """The square around ``box`` grown by a fifth of its size, scaled to ``height`` px."""
    x0, y0, x1, y1 = box
    cx, cy, half = (x0 + x1) / 2, (y0 + y1) / 2, 0.6 * max(x1 - x0, y1 - y0)
    h, w = image.shape[:2]
    a, b = int(max(0, cx - half)), int(min(w, cx + half))
    c, d = int(max(0, cy - half)), int(min(h, cy + half))
    return cv2.resize(image[c:d, a:b], (height, height), interpolation=cv2.INTER_AREA)


def label(tile: np.ndarray, text: str) -> np.ndarray:
    out = tile.copy()
    cv2.putText(out, text, (4, 14), cv2.FONT_HERSHEY_SIMPLEX, 0.4, (0, 0, 0), 3, cv2.LINE_AA)
    cv2.putText(out, text, (4, 14), cv2.FONT_HERSHEY_SIMPLEX, 0.4, (255, 255, 255), 1, cv2.LINE_AA)
    return out


def most_turned(yaws: list, fps: float, count: int = 3) -> list[int]:
    """Indices of the ``count`` frames with the largest |yaw|, at least a second apart."""
    order = sorted((i for i, y in enumerate(yaws) if y is not None), key=lambda i: -abs(yaws[i]))
    chosen: list[int] = []
    for i in order:
        if all(abs(i - j) >= fps for j in chosen):
            chosen.append(i)
        if len(chosen) == count:
            break
    return sorted(chosen)


def sheet(frames, runs: dict, boxes, picks: list[int], height: int, yaws=None) -> np.ndarray:
    """Rows per run (label -> outputs), (input | output) per picked frame, cropped around ``boxes``."""
    rows = []
    for name, outs in runs.items():
        tiles = []
        for i in picks:
            box = boxes[i] or (0, 0, frames[i].shape[1], frames[i].shape[0])
            note = f"#{i}" + (f" yaw {yaws[i]:+.0f}" if yaws is not None and yaws[i] is not None else "")
            tiles += [label(crop(frames[i], box, height), f"input {note}"), label(crop(outs[i], box, height), name)]
            tiles.append(np.full((height, 4, 3), 255, np.uint8))
        rows.append(np.hstack(tiles[:-1]))
        rows.append(np.full((4, rows[-1].shape[1], 3), 255, np.uint8))
    return np.vstack(rows[:-1])


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--out", default="docs/results/images")
    p.add_argument("--videos", default="d0,d3,d12,s18")
    p.add_argument("--strengths", default="1,2")
    p.add_argument("--frames", type=int, default=90)
    p.add_argument("--turned", default="d3", help="videos that also get a sheet of their most turned frames")
    p.add_argument("--height", type=int, default=170)
    args = p.parse_args()
    from facesculpt.app.pipeline import read_preset
    from facesculpt.nodes.deformer.preset_format import scale_preset
    from facesculpt.paths import preset_file
    from facesculpt.runtime.process_limits import limit_threads

    limit_threads(1)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    turned = set(filter(None, args.turned.split(",")))
    for name in args.videos.split(","):
        frames, fps = read_video(name, args.frames if name not in turned else 10 ** 6)
        runs, boxes, yaws = {}, None, None
        for preset in sorted(p.stem for p in preset_file("chin").parent.glob("*.json")):
            for s in (float(x) for x in args.strengths.split(",")):
                outs, b, y = run(frames, fps, scale_preset(read_preset(preset), s))
                runs[f"{preset} x{s:g}"] = outs
                if boxes is None:
                    boxes, yaws = b, y
        n = min(len(frames), args.frames)
        picks = [n // 6, n // 2, n - 1 - n // 6]
        path = out / f"contact-{name}.jpg"
        cv2.imwrite(str(path), sheet(frames, runs, boxes, picks, args.height), [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY])
        print(f"{path}: frames {picks}", flush=True)
        if name in turned:
            picks = most_turned(yaws, fps)
            path = out / f"contact-{name}-turned.jpg"
            cv2.imwrite(str(path), sheet(frames, runs, boxes, picks, args.height, yaws),
                        [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY])
            print(f"{path}: frames {picks}, yaw {[round(yaws[i], 1) for i in picks]}", flush=True)


if __name__ == "__main__":
    main()
