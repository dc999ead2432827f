"""`facesculpt reenact --source PHOTO_OR_VIDEO --driving VIDEO -o OUT`: a performer animates a face.

    facesculpt reenact --source photo.jpg --driving talk.mp4 -o avatar.mp4
    facesculpt reenact --driving talk.mp4 -o avatar.mp4 --pose --side-by-side

The driving video's expression (and with ``--pose`` its head rotation), each relative to the
driver's own neutral, animates the source (a photo, or a video's first frame; default: the
embedded photo); see :mod:`facesculpt.app.reenactment`. The output is written as `process` writes
its own (a video staged until complete, or an image pattern), at the driving video's rate, one
frame per driving frame.
"""

from __future__ import annotations

import sys
from pathlib import Path

import cv2
import numpy as np

from facesculpt.app.option_arguments import add_option_argument
from facesculpt.nodes.camera.intrinsics import IntrinsicsOptions
from facesculpt.nodes.fitter.config import FitterConfig


def register(sub) -> None:
    p = sub.add_parser("reenact", help="animate a source face with a driving video's expression (avatar)",
                       description="The driving video's expression, relative to the driver's own neutral face "
                                   "(learned from its first frames), deforms the source face, which is re-rendered "
                                   "from the source image by the compositor (background kept). Where the driver "
                                   "opens a mouth the source shows closed, a dark interior with a soft teeth band "
                                   "is painted; a source showing its own open mouth keeps its interior.",
                       epilog="Example: facesculpt reenact --source photo.jpg --driving talk.mp4 -o avatar.mp4")
    p.add_argument("--source", default="", metavar="PHOTO_OR_VIDEO",
                   help="the face to animate: an image, or a video (its first frame); default: the embedded photo")
    p.add_argument("--driving", required=True, metavar="VIDEO", help="the performer's video")
    p.add_argument("-o", "--output", required=True, metavar="OUT",
                   help="output video (.mp4, .mov, .m4v, .avi, .mkv) or image pattern such as out/%%05d.png")
    p.add_argument("--pose", action="store_true",
                   help="also turn the source head as the driver's turns away from its neutral pose")
    p.add_argument("--no-mouth", action="store_true", help="do not paint the mouth interior")
    p.add_argument("--side-by-side", action="store_true", help="write source | driver | result side by side")
    add_option_argument(p, FitterConfig(), "neutral_frames", "--neutral-frames", metavar="N",
                        extra_help="driving frames the driver's neutral face is learned from")
    p.add_argument("--max-frames", type=int, default=0, metavar="N", help="stop after N driving frames (0: all)")
    p.add_argument("--codec", default=None, metavar="NAME", help="video encoder (as for process)")
    p.add_argument("--crf", type=int, default=18, metavar="Q", help="H.264/H.265 quality (default 18)")
    add_option_argument(p, IntrinsicsOptions(), "fov_deg", "--fov", metavar="DEG")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=cmd_reenact)


def read_source(path: str) -> np.ndarray:
    """(H, W, 3) uint8 BGR: the image at ``path``, or the first frame of the video there."""
    if not Path(path).is_file():
        raise FileNotFoundError(f"cannot read {path}: no such file")
    image = cv2.imread(path, cv2.IMREAD_COLOR)
    if image is None:
        cap = cv2.VideoCapture(path)
        ok, image = cap.read()
        cap.release()
        if not ok:
            raise ValueError(f"cannot read {path}: neither an image nor a video OpenCV can decode")
    return image


def _side_by_side(source: np.ndarray, driver: np.ndarray, result: np.ndarray) -> np.ndarray:
    h = source.shape[0]
    scaled = cv2.resize(driver, (max(1, round(driver.shape[1] * h / driver.shape[0])), h))
    return np.hstack([source, scaled, result])


def reenact_file(args) -> tuple[int, str]:
    """The command's work with the options of ``args``; (exit status, what was written)."""
    from facesculpt.app.pipeline import Pipeline
    from facesculpt.app.process import _finish, _frames, _progress, _Stop, open_input, open_output
    from facesculpt.app.reenactment import Reenactor, fit_source, mean_rotation
    from facesculpt.app.safe_output import refuse_output_over_input
    from facesculpt.paths import embedded_face_image

    source_path = args.source or str(embedded_face_image())
    for given in (source_path, args.driving):
        refuse_output_over_input(given, args.output)
    source = fit_source(read_source(source_path), fov_deg=args.fov)
    driving = open_input(args.driving)
    fps = driving.native_fps
    total = min(driving.frame_count or 0, args.max_frames or 10**9) or None
    output = open_output(args.output, fps, args.codec, args.crf, None)
    pipe = Pipeline("facemesh", fov_deg=args.fov, fit=FitterConfig(neutral_frames=args.neutral_frames))
    reenactor, with_face = None, 0
    try:
        with _Stop() as stop:
            calib = open_input(args.driving)
            try:
                rotations = []
                with _progress(min(args.neutral_frames, total or args.neutral_frames), "neutral", args.quiet) as bar:
                    for i, frame in enumerate(_frames(calib, 0, args.max_frames)):
                        fit = pipe.fit_frame(frame, i / fps)
                        if fit is not None:
                            rotations.append(fit.R)
                        bar.update(1)
                        if pipe.neutral_complete or stop.signal:
                            break
            finally:
                calib.close()
            pipe.detector.reset()
            if pipe.faces is not None:
                pipe.faces.reset_tracking()
            if not rotations:
                raise ValueError(f"no face was found in the first frames of {args.driving}")
            turn = mean_rotation(rotations) if args.pose else None
            reenactor = Reenactor(source, pipe.model, pipe.neutral, turn, mouth=not args.no_mouth)
            with _progress(total, "reenact", args.quiet) as bar:
                for i, frame in enumerate(_frames(driving, 0, args.max_frames)):
                    fit = pipe.fit_frame(frame, i / fps)
                    with_face += fit is not None
                    result = reenactor.render(fit)
                    output.write(_side_by_side(source.image, frame, result) if args.side_by_side else result)
                    bar.update(1)
                    if stop.signal:
                        raise KeyboardInterrupt
    except KeyboardInterrupt:
        _finish(False, output)
        return 130, f"interrupted: kept {output.frames} frames in {output.path!s}"
    except BaseException:
        if hasattr(output, "discard"):
            output.discard()
        raise
    finally:
        driving.close()
        pipe.close()
        if reenactor is not None:
            reenactor.close()
    _finish(True, output)
    return 0, f"wrote {output.frames} frames to {output.path!s} ({with_face} driving frames with a face)"


def cmd_reenact(args) -> int:
    from facesculpt.runtime.process_limits import limit_threads

    limit_threads(1)
    if args.neutral_frames < 1 or args.max_frames < 0:
        raise ValueError("--neutral-frames must be >= 1 and --max-frames >= 0")
    code, message = reenact_file(args)
    print(message, file=sys.stderr, flush=True)
    return code
