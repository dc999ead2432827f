"""The `facesculpt process` command line: its arguments and the dispatch to one file
(:func:`facesculpt.app.process.process_file`) or a batch (:mod:`facesculpt.app.batch`)."""

from __future__ import annotations

import sys

from facesculpt.app.option_arguments import add_option_argument
from facesculpt.geometry.pose_offset import FACE_CAMERA_LIMIT_DEG, FACE_CAMERA_SMOOTHING_S
from facesculpt.nodes.camera.intrinsics import IntrinsicsOptions
from facesculpt.nodes.fitter.config import FitterConfig
from facesculpt.nodes.fitter.expression_labels import ExpressionLabelOptions
from facesculpt.nodes.landmarks.detector import FACE_OPTIONS
from facesculpt.nodes.renderer.compositor_options import CompositorOptions

#: The defaults of the flags that are fitter and compositor options (declared in those classes).
FITTER, RENDER, LABELS = FitterConfig(), CompositorOptions(), ExpressionLabelOptions()


def _add_fit_arguments(p) -> None:
    """--model, --neutral-frames, --fov, --refine, --rotation-prior: how each frame's face is fitted."""
    p.add_argument("--model", default="facemesh", metavar="facemesh|sfm|MODEL.npz",
                   help="face model: facemesh (built in, default), sfm (Surrey Face Model from the shared data, "
                        "non-commercial) or a .npz from `facesculpt model import-eos`")
    add_option_argument(p, FITTER, "neutral_frames", "--neutral-frames", metavar="N",
                        extra_help="the first pass learns the neutral face from them, before the edits are solved")
    add_option_argument(p, IntrinsicsOptions(), "fov_deg", "--fov", metavar="DEG")
    add_option_argument(p, FITTER, "refine", "--refine")
    add_option_argument(p, FITTER, "rotation_prior_px", "--rotation-prior", metavar="PX",
                        extra_help="with --model sfm (docs/guide/face-models.md)")


def _add_pose_arguments(p) -> None:
    """--pose, --face-camera, --face-camera-limit, --keyframes (docs/guide/new-views.md)."""
    p.add_argument("--pose", default="", metavar="yaw=D,pitch=D,roll=D,x=MM,y=MM,z=MM",
                   help="turn (degrees, added to the head's own angles) and move (mm, camera axes) every fitted head, "
                        "e.g. yaw=10,pitch=-5 (docs/guide/new-views.md, for the angles results hold to)")
    p.add_argument("--face-camera", type=float, default=0.0, metavar="F",
                   help="turn each face F (0-1) of the way toward looking into the camera, every frame "
                        "(at most --face-camera-limit degrees; on top of --pose)")
    p.add_argument("--face-camera-limit", type=float, default=FACE_CAMERA_LIMIT_DEG, metavar="DEG",
                   help=f"the largest turn --face-camera applies, yaw and pitch each (default {FACE_CAMERA_LIMIT_DEG:g}, "
                        "the largest the new-views benchmark's figures hold for; at most 45)")
    p.add_argument("--face-camera-smoothing", type=float, default=FACE_CAMERA_SMOOTHING_S, metavar="S",
                   help="time constant (s) smoothing the direction to the camera over the frames (default 0: none, "
                        "which follows the head best; docs/guide/new-views.md)")
    p.add_argument("--pose-limit", choices=("on", "off"), default="on",
                   help="on (default): each frame draws only the share of the turn that what the video showed of the "
                        "surface it reveals allows, reduced smoothly beyond it (with a warning); off: the whole turn")
    p.add_argument("--keyframes", choices=("auto", "on", "off"), default="auto",
                   help="render a turned head's surface from the stored view of the video closest to it where that "
                        "sees it better than the frame (image-based rendering); auto (default): with a pose edit")


def register(sub) -> None:
    p = sub.add_parser("process", help="run a video file through the pipeline (landmarks, fit, edits, render)",
                       description="A video through the whole pipeline in one process, every frame: the face "
                                   "fitted on a frame is rendered on that frame; a frame without a face is "
                                   "written unchanged.",
                       epilog="Examples: facesculpt process in.mp4 -o out.mp4 --edits nose_longer; "
                              "facesculpt process in.mp4 -o frames/%05d.png --side-by-side")
    p.add_argument("input", metavar="IN", nargs="+",
                   help="input video file, or an RGB-D recording (a folder of colour + 16-bit depth PNGs, bag:FILE or "
                        "a .mcap bag with depth: each fit is refined on the depth); several files, folders or globs "
                        "make a batch (-o is then a folder)")
    p.add_argument("-o", "--output", metavar="OUT", required=True,
                   help="output video (.mp4, .mov, .m4v, .avi, .mkv) or image pattern such as out/%%05d.png "
                        "(lossless: png, bmp, tif); for a batch, a folder (each output named after its input)")
    p.add_argument("--workers", type=int, default=0, metavar="N",
                   help="batch: parallel workers on this machine (default: one per core)")
    p.add_argument("--cluster", default="", metavar="ADDRESS",
                   help="batch: run on a Dask distributed cluster, e.g. tcp://scheduler:8786 (workers need facesculpt "
                        "installed and set up)")
    p.add_argument("--suffix", default=".mp4", metavar=".EXT", help="batch: output video suffix (default .mp4)")
    p.add_argument("--overwrite", action="store_true",
                   help="batch: process inputs whose output already exists (default: skip them, so a rerun resumes)")
    p.add_argument("--edits", action="append", default=[], metavar="[N:]PRESET",
                   help="a deformer preset file, or the name of a shipped one (nose_longer, chin, cheeks); "
                        "repeat to stack several, in order; N:PRESET edits face N only (with --faces all)")
    p.add_argument("--strength", type=float, default=1.0, metavar="S",
                   help="multiply the edits' offsets by S, 0 (no edit) to 3 (default 1)")
    _add_pose_arguments(p)
    p.add_argument("--faces", default="largest", metavar="all|largest|N",
                   help="which faces to fit and edit: the largest (default), all, or face N only "
                        "(faces numbered 1, 2, ... from the left as they first appear)")
    _add_fit_arguments(p)
    p.add_argument("--side-by-side", action="store_true", help="write the input and the result next to each other")
    p.add_argument("--depth-out", default="", metavar="PATTERN|FILE.mcap",
                   help="with an RGB-D input: also write the edited depth, as 16-bit PNGs (a pattern such as "
                        "depth/%%05d.png; existing files are never overwritten) or an RGB-D bag of the edited frames "
                        "(.mcap; docs/guide/depth-cameras.md)")
    p.add_argument("--export-params", default="", metavar="FILE.csv|json",
                   help="also write each frame's head pose, expression parameters and the expression recognised "
                        "(docs/guide/expressions.md); in a batch, beside each output video with this suffix")
    add_option_argument(p, LABELS, "source", "--expression-source", extra_help="with --export-params")
    add_option_argument(p, LABELS, "weights", "--expression-weights", metavar="FILE.json",
                        extra_help="with --export-params")
    p.add_argument("--gaze", action="store_true",
                   help="find the irises and estimate each face's gaze (docs/guide/eyes.md); --export-params then "
                        "writes the gaze columns too")
    p.add_argument("--codec", default=None, metavar="NAME",
                   help="video encoder (default by suffix: libx264 (H.264) for .mp4/.mov/.m4v/.mkv, mjpeg for .avi; "
                        "others: libx265, mpeg4, ffv1, ...)")
    p.add_argument("--crf", type=int, default=18, metavar="Q",
                   help="H.264/H.265 quality, 0 (lossless) to 51; lower is better and larger (default 18)")
    p.add_argument("--preset", default="auto", metavar="NAME",
                   help="H.264/H.265 speed preset: ultrafast, superfast, veryfast, faster, fast, medium, slow, ... "
                        "(faster: larger files at about the same --crf quality); default auto: the encoder's own "
                        "(medium) up to 1920x1080, ultrafast above, where medium alone limits 4K to a few fps")
    p.add_argument("--no-audio", action="store_true", help="do not copy the input's sound into the output video")
    p.add_argument("--width", type=int, default=0, metavar="W", help="resize frames to this width first (aspect kept)")
    p.add_argument("--max-frames", type=int, default=0, metavar="N", help="stop after N frames (0: all)")
    add_option_argument(p, FACE_OPTIONS, "threads", "--threads", metavar="N")
    p.add_argument("--atlas", choices=("on", "off"), default="off",
                   help="keep a texture memory (UV atlas) of the face over the frames and take colours from it "
                        "where the frame sees the edited surface badly: stretched or hidden (default off)")
    p.add_argument("--save-texture", default="", metavar="FILE.png",
                   help="write the face's texture atlas (in the model's UV layout) as a PNG at the end "
                        "(learned even with --atlas off)")
    add_option_argument(p, RENDER, "inpaint", "--inpaint", old_flags=("--fill",))
    p.add_argument("--plate", choices=("on", "off"), default="off",
                   help="keep a background plate (the background seen behind the face and the person in other frames, "
                        "registered when the camera moves) and take what an edit uncovers from it where known "
                        "(default off)")
    add_option_argument(p, RENDER, "outline_band", "--outline-band", metavar="S")
    add_option_argument(p, RENDER, "interpolation", "--interpolation")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=cmd_process)


def cmd_process(args) -> int:
    from facesculpt.app.batch import expand_inputs, is_batch, run_batch
    from facesculpt.app.process import process_file
    from facesculpt.runtime.process_limits import limit_threads

    limit_threads(1)  # one thread per stage is faster here (see facesculpt.runtime.process_limits)
    if args.width < 0 or args.max_frames < 0 or args.neutral_frames < 1:
        raise ValueError("--width and --max-frames must be >= 0 and --neutral-frames >= 1")
    if is_batch(args):
        return run_batch(args, expand_inputs(args.input))
    code, message = process_file(args, args.input[0], args.output)
    print(message, file=sys.stderr, flush=True)
    return code
