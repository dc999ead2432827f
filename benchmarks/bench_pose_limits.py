"""New views that know their limits (issue 51): turns of the shared real videos with the pose limit
on and off, in the same run.

    python -m benchmarks.bench_pose_limits [--videos d0,d3,d12] [--turns yaw=15,yaw=-15,face-camera=1]
        [--frames 24] [--crops DIR]

Each video's first ``--frames`` frames go through the offline pipeline (``facesculpt process``'s,
facemesh, keyframes auto) turned by each of ``--turns`` (``yaw=D``: ``--pose yaw=D``;
``face-camera=F``: ``--face-camera F``), once with ``pose_limit`` off (the renderer before issue
51: the whole turn on every frame) and once on (the turn reduced where the video shows too little
of the surface it reveals: :mod:`facesculpt.nodes.renderer.pose_limit`). Per frame:

- seam: the mean gradient magnitude (Sobel, grey) of the output over a band 3 px either side of
  the re-rendered region's boundary (the compositor's changed region), over the input's on the
  same band (1: the boundary is as sharp as the input there; above: an edge the edit drew);
- background in the face: the share of the turned face's region (the deformed face, eroded by
  3 px) that the person segmenter (mediapipe's selfie segmentation, not tuned to here) calls
  background in the output;
- share: the share of the turn drawn (1 with the limit off);
- face outline: the mean gradient magnitude over a band 3 px either side of the outline of the
  drawn face mesh (the far silhouette of a turned head included), over the input's on the same band.

``--limits`` picks the runs (default ``off,on``). Prints a table (means over the frames, worst
frame's seam), and with ``--crops DIR`` writes ``limits_VIDEO_TURN.png``: input | each run's output
at the frame whose turn was reduced most (the last run with the limit on), else whose face outline
figure is highest.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import cv2
import numpy as np

from benchmarks.bench_nostrils import read_video
from benchmarks.realism.metrics import gradient_magnitude, seam_band

SEAM_HALF_WIDTH_PX = 3
ERODE_PX = 3


def _turn_options(turn: str) -> dict:
    from facesculpt.geometry.pose_offset import parse_pose_offset

    if turn.startswith("face-camera="):
        return {"face_camera": float(turn.split("=", 1)[1])}
    return {"pose": parse_pose_offset(turn)}


def _run(frames, fps, turn, limit, segmenter):
    """Per frame (seam ratio, background share, drawn share, frame index, outline ratio) and the outputs."""
    from facesculpt.app.pipeline import Pipeline

    rows, outs = [], []
    with Pipeline("facemesh", pose_limit=limit, **_turn_options(turn)) as pipe:
        for i, frame in enumerate(frames):
            result = pipe.process(frame, i / fps)
            out = result.image
            outs.append(out)
            comp = pipe.compositor
            if comp is None or comp.box is None:
                continue
            regions = comp.full_frame_regions()
            band = seam_band(regions["changed"], SEAM_HALF_WIDTH_PX)
            g_in, g_out = gradient_magnitude(frame)[band].mean(), gradient_magnitude(out)[band].mean()
            face = cv2.erode(regions["deformed"].view(np.uint8), np.ones((2 * ERODE_PX + 1,) * 2, np.uint8)) > 0
            background = float(((segmenter(out) == 0) & face).sum() / max(face.sum(), 1))
            share = 1.0 if not limit or pipe.pose_limiter is None else pipe.pose_limiter.last.get(min(result.fits), 1.0)
            rim = seam_band(regions["deformed"], SEAM_HALF_WIDTH_PX)   # the face's own outline, far side included
            o_in, o_out = gradient_magnitude(frame)[rim].mean(), gradient_magnitude(out)[rim].mean()
            rows.append((g_out / max(g_in, 1e-9), background, share, i, o_out / max(o_in, 1e-9)))
    return np.array(rows), outs


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--videos", default="d0,d3,d12")
    p.add_argument("--turns", default="yaw=15,yaw=-15,face-camera=1")
    p.add_argument("--frames", type=int, default=24)
    p.add_argument("--crops", default="", metavar="DIR")
    p.add_argument("--limits", default="off,on", help="the pose limit's settings to run (default off,on)")
    args = p.parse_args()
    from facesculpt.nodes.renderer.person_segmentation import PersonSegmenter
    from facesculpt.runtime.process_limits import limit_threads

    limit_threads(1)
    segmenter = PersonSegmenter()
    print("| video | turn | limit | seam (mean) | seam (worst frame) | background in the face (mean, max) "
          "| share drawn (mean, min) | face outline (mean, worst frame) |")
    print("| --- | --- | --- | --- | --- | --- | --- | --- |")
    for name in args.videos.split(","):
        frames, fps = read_video(name, args.frames)
        for turn in args.turns.split(","):
            outs = {}
            limits = [x == "on" for x in args.limits.split(",")]
            for limit in limits:
                rows, outs[limit] = _run(frames, fps, turn, limit, segmenter)
                print(f"| {name} | {turn} | {'on' if limit else 'off'} | {rows[:, 0].mean():.3f} | {rows[:, 0].max():.3f} "
                      f"| {rows[:, 1].mean():.4f}, {rows[:, 1].max():.4f} | {rows[:, 2].mean():.2f}, {rows[:, 2].min():.2f} "
                      f"| {rows[:, 4].mean():.3f}, {rows[:, 4].max():.3f} |",
                      flush=True)
                worst = int(rows[int(np.argmin(rows[:, 2])), 3]) if limit else int(rows[int(np.argmax(rows[:, 4])), 3])
            if args.crops:
                Path(args.crops).mkdir(parents=True, exist_ok=True)
                strip = np.hstack([frames[worst]] + [outs[limit][worst] for limit in limits])
                cv2.imwrite(str(Path(args.crops) / f"limits_{name}_{turn.replace('=', '')}.png"), strip)


if __name__ == "__main__":
    main()
