"""Hand time per frame: onnxruntime (the networks converted by the project's own converter) next
to ai-edge-litert running the original .tflite networks, through the same HandDetector, in the
same run.

    python -m benchmarks.bench_hands [--repeats 40] [--threads 1] [--json out.json]

Inputs: the five shared hand photos (hands/*.jpg). Measured per call, interleaving the two
runtimes call by call:
  detection  ``detect()``: palm detector on the letterboxed photo, landmarks twice per hand
  tracking   ``track()``: landmarks once per tracked hand, from the last points
and each network alone (palm detector 192px, hand landmarks 224px) on one input. Reported:
medians (ms), the ratio onnxruntime / litert (target <= 1.2), and the largest landmark
difference between the runtimes as a fraction of the crop size (target <= 1e-3).
"""

from __future__ import annotations

import sys

import cv2
import numpy as np

from benchmarks.runtime_pair import BACKENDS, report, runtime_arguments, timed
from facesculpt.nodes.hands.detector import HandDetector


def main(argv=None) -> int:
    args, data, models = runtime_arguments(__doc__, lambda parser: parser.add_argument(
        "--repeats", type=int, default=40, help="rounds over the five photos"), argv)
    if data is None:
        return 2
    photos = [cv2.imread(str(p)) for p in sorted((data / "hands").glob("*.jpg"))]
    detectors = {b: HandDetector(models, threads=args.threads, backend=b) for b in BACKENDS}
    trackers = {b: [HandDetector(models, threads=args.threads, backend=b) for _ in photos] for b in BACKENDS}

    agreement, hands = 0.0, 0
    for image in photos:  # warm-up, and the same hands from both runtimes
        ours, ref = (detectors[b].detect(image) for b in BACKENDS)
        if len(ours) != len(ref):
            print("the runtimes found different numbers of hands", file=sys.stderr)
            return 1
        hands += len(ours)
        for a, b in zip(ours, ref):
            agreement = max(agreement, float(np.abs(a.points[:, :2] - b.points[:, :2]).max()) / float(a.roi[2]))
    for b in BACKENDS:
        for tracker, image in zip(trackers[b], photos):
            tracker.track(image)

    times = {f"{kind}/{b}": [] for kind in ("detect", "track", "palm_net", "hand_net") for b in BACKENDS}
    x_palm = np.random.default_rng(0).uniform(0, 1, (1, 192, 192, 3)).astype(np.float32)
    x_hand = np.random.default_rng(1).uniform(0, 1, (1, 224, 224, 3)).astype(np.float32)
    for i in range(args.repeats):
        order = BACKENDS if i % 2 == 0 else BACKENDS[::-1]
        for k, image in enumerate(photos):
            for b in order:
                times[f"detect/{b}"].append(timed(detectors[b].detect, image))
                times[f"track/{b}"].append(timed(trackers[b][k].track, image))
                times[f"palm_net/{b}"].append(timed(detectors[b].palm_net.run, x_palm))
                times[f"hand_net/{b}"].append(timed(detectors[b].hand_net.run, x_hand))

    rows = [("detection (detect)", "detect"), ("tracking (track)", "track"),
            ("  palm detector 192px", "palm_net"), ("  hand landmarks 224px", "hand_net")]
    result = {"photos": len(photos), "hands": hands, "threads": args.threads, "repeats": args.repeats,
              "max_point_difference_of_crop": agreement}
    report(f"hands on the {len(photos)} shared photos ({hands} hands), {args.threads} thread(s), "
           f"{args.repeats} rounds, median ms per call", rows, times, result, args.json)
    print(f"largest landmark difference between the runtimes: {agreement:.2e} of the crop size")
    return 0


if __name__ == "__main__":
    sys.exit(main())
