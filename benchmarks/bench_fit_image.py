"""3D active appearance model fit of still photos (issue 20, seed 004): the 68-point error of the
landmark fit's projection against the same fit aligned by appearance (``Fitter.fit_image``).

The shared annotated photos (43 faces, hand-marked iBUG-68 landmarks; ../shared/data/faces) are
found by the landmark networks and fitted by their landmarks with the SFM (perspective, the
photo's width as focal length). Leave one photo out: for each face, an appearance model is trained
(:mod:`facesculpt.app.appearance_training`: frontal faces only, |yaw| <= 15 degrees) on the faces of
the *other* photos, and the face's landmark fit is aligned with it. Reported: the NME (mean point
error over the outer-eye-corner distance) of the 68 fitted landmark points (the model points each
landmark was matched to) before and after, over all faces, frontal ones and turned ones, and the
milliseconds a fit_image takes.

Run: ``python -m benchmarks.bench_fit_image [--components 10] [--json FILE]``. Needs the shared data
and ``facesculpt setup``.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import cv2
import numpy as np

from facesculpt.app.appearance_training import MAX_YAW_DEG, frontal_samples, photo_fits
from facesculpt.geometry.ibug68 import dlib_annotations
from facesculpt.paths import shared_data_dir


def nme(fit, truth: np.ndarray) -> float:
    """Mean distance of the fit's 68 landmark points from ``truth`` over the outer eye corners' distance."""
    verts, weights = fit.correspondences
    points = dict(zip(fit.correspondence_ids, (fit.projected[verts] * weights[..., None]).sum(axis=1)))
    err = [np.linalg.norm(points[str(k + 1)] - truth[k]) for k in range(68) if str(k + 1) in points]
    return float(np.mean(err) / np.linalg.norm(truth[36] - truth[45]))


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--components", type=int, default=10, help="appearance components (default 10)")
    p.add_argument("--json", default="", help="write the figures here")
    args = p.parse_args(argv)
    data = shared_data_dir()
    if data is None:
        print("bench_fit_image: the shared data folder is missing (../shared/data or FACESCULPT_DATA)", file=sys.stderr)
        return 2
    from facesculpt.nodes.fitter import FitterConfig, load_model, make_fitter
    from facesculpt.nodes.fitter.appearance_model import train_appearance
    from facesculpt.nodes.landmarks import LandmarkDetector

    model = load_model("sfm")
    detector = LandmarkDetector(max_faces=50, min_face=0.05)
    photos, faces = {}, []   # file -> (image, fits, frontal samples); (file, fit, truth)
    for split in ("training", "testing"):
        for file, box, truth in dlib_annotations(data / "faces" / f"{split}_with_face_landmarks.xml"):
            if file not in photos:
                image = cv2.imread(str(data / "faces" / file))
                fits = photo_fits(image, model, detector)
                photos[file] = (image, fits, frontal_samples(image, fits, model, MAX_YAW_DEG))
            centre = box[:2] + box[2:] / 2
            near = [(np.linalg.norm(f.projected.mean(0) - centre), i) for i, f in enumerate(photos[file][1])]
            near = [c for c in near if c[0] < box[2] / 2]
            if near:
                faces.append((file, photos[file][1][min(near)[1]], truth))
    rows, took = [], []
    for file, fit, truth in faces:
        others = [s for f, (_, _, samples) in photos.items() if f != file for s in samples]
        appearance = train_appearance(np.array(others), args.components, model.model_id)
        image = photos[file][0]
        h, w = image.shape[:2]
        fitter = make_fitter(model, FitterConfig(), (w, h), np.array([[w, 0, w / 2], [0, w, h / 2], [0, 0, 1.0]]))
        t0 = time.perf_counter()
        aligned = fitter.fit_image(image, fit, appearance)
        took.append((time.perf_counter() - t0) * 1e3)
        rows.append({"photo": file, "yaw": float(fit.yaw_pitch_roll[0]), "trained_on": len(others),
                     "nme_landmarks": nme(fit, truth), "nme_fit_image": nme(aligned, truth)})
    lines = ["| faces | count | NME, landmark fit | NME, fit_image | better in |", "| --- | --- | --- | --- | --- |"]
    for label, sel in (("all", lambda r: True), (f"frontal (|yaw| <= {MAX_YAW_DEG:.0f})", lambda r: abs(r["yaw"]) <= MAX_YAW_DEG),
                       ("turned", lambda r: abs(r["yaw"]) > MAX_YAW_DEG)):
        rs = [r for r in rows if sel(r)]
        if rs:
            a, b = np.mean([r["nme_landmarks"] for r in rs]), np.mean([r["nme_fit_image"] for r in rs])
            better = sum(r["nme_fit_image"] < r["nme_landmarks"] for r in rs)
            lines.append(f"| {label} | {len(rs)} | {a:.4f} | {b:.4f} | {better} of {len(rs)} |")
    lines.append(f"\nfit_image: {np.median(took):.1f} ms (median); appearance models of {args.components} components, "
                 f"trained on {rows[0]['trained_on'] if rows else 0}-{max((r['trained_on'] for r in rows), default=0)} frontal faces")
    print("\n".join(lines))
    if args.json:
        Path(args.json).write_text(json.dumps({"rows": rows, "fit_image_ms": float(np.median(took))}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
