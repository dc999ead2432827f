"""`facesculpt encode VIDEO -o talk.fsc` and `facesculpt decode talk.fsc -o OUT`: model-based coding.

    facesculpt encode talk.mp4 -o talk.fsc
    facesculpt decode talk.fsc -o talk_decoded.mp4

See :mod:`facesculpt.app.coding` for what is sent and how it is rendered back, and
:mod:`facesculpt.coding.fsc` for the stream's layout. ``encode`` prints the bitrate: the
per-frame stream (what a live link spends) and the whole file with its one-time header.
"""

from __future__ import annotations

import sys
from pathlib import Path

from facesculpt.app.option_arguments import add_option_argument
from facesculpt.nodes.camera.intrinsics import IntrinsicsOptions
from facesculpt.nodes.fitter.config import FitterConfig


def register(sub) -> None:
    p = sub.add_parser("encode", help="code a talking-head video as a keyframe plus pose and expression per frame",
                       description="Model-based coding: one keyframe (the first frame with a face, WebP: face "
                                   "texture and background still), the fitted neutral and an expression basis once, "
                                   "then per frame only the quantised head pose (7 numbers) and expression "
                                   "coefficients. Prints the bitrate.",
                       epilog="Example: facesculpt encode talk.mp4 -o talk.fsc; facesculpt decode talk.fsc -o out.mp4")
    p.add_argument("input", metavar="VIDEO", help="input video")
    p.add_argument("-o", "--output", required=True, metavar="FILE.fsc", help="the coded stream")
    p.add_argument("--components", type=int, default=12, metavar="N",
                   help="expression coefficients per frame, 1 to 64 (default 12; one byte each)")
    # The default is facesculpt.coding.fsc.KEY_QUALITY, not imported here (it pulls in scipy at every start).
    p.add_argument("--key-quality", type=int, default=None, metavar="Q",
                   help="keyframe WebP quality, 1 to 100 (default 70)")
    add_option_argument(p, FitterConfig(), "neutral_frames", "--neutral-frames", metavar="N",
                        extra_help="the person's neutral face is learned from them")
    p.add_argument("--max-frames", type=int, default=0, metavar="N", help="code only the first N frames (0: all)")
    add_option_argument(p, IntrinsicsOptions(), "fov_deg", "--fov", metavar="DEG")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=cmd_encode)
    d = sub.add_parser("decode", help="render a .fsc stream back to a video",
                       description="Renders each frame of a .fsc stream: the keyframe's face posed and deformed by "
                                   "the frame's parameters, composited onto the keyframe (background still; "
                                   "uncovered regions inpainted; a mouth opened wider than the keyframe's closed one "
                                   "gets a dark interior with a soft teeth band).")
    d.add_argument("input", metavar="FILE.fsc", help="the coded stream")
    d.add_argument("-o", "--output", required=True, metavar="OUT",
                   help="output video (.mp4, .mov, .m4v, .avi, .mkv) or image pattern such as out/%%05d.png")
    d.add_argument("--codec", default=None, metavar="NAME", help="video encoder (as for process)")
    d.add_argument("--crf", type=int, default=18, metavar="Q", help="H.264/H.265 quality (default 18)")
    d.add_argument("--quiet", action="store_true", help="no progress bar")
    d.set_defaults(func=cmd_decode)


def cmd_encode(args) -> int:
    from facesculpt.app.coding import analyse, encode
    from facesculpt.app.process import _frames, _progress, open_input
    from facesculpt.app.safe_output import refuse_output_over_input, temporary_name
    from facesculpt.coding.fsc import KEY_QUALITY
    from facesculpt.runtime.process_limits import limit_threads

    limit_threads(1)
    args.key_quality = KEY_QUALITY if args.key_quality is None else args.key_quality
    if not 1 <= args.components <= 64 or not 1 <= args.key_quality <= 100 or args.neutral_frames < 1:
        raise ValueError("--components must be 1 to 64, --key-quality 1 to 100 and --neutral-frames >= 1")
    if args.max_frames < 0:
        raise ValueError("--max-frames must be >= 0")
    refuse_output_over_input(args.input, args.output)
    probe = open_input(args.input)
    fps, total = probe.native_fps, probe.frame_count or None
    probe.close()
    if total and args.max_frames:
        total = min(total, args.max_frames)
    opened = []

    def frames():
        source = open_input(args.input)
        opened.append(source)
        return _frames(source, 0, args.max_frames)

    try:
        with _progress(total, "encode", args.quiet) as bar:
            analysis = analyse(frames, fps, args.neutral_frames, args.fov, progress=bar.update)
    finally:
        for source in opened:
            source.close()
    target = Path(args.output).expanduser()
    staging = temporary_name(target)
    try:
        sizes = encode(analysis, staging, args.components, args.key_quality)
        staging.replace(target)
    finally:
        staging.unlink(missing_ok=True)
    n = len(analysis.present)
    seconds = n / fps
    print(f"wrote {n} frames to {target} ({int(analysis.present.sum())} with a face): per-frame stream "
          f"{sizes['stream'] * 8 / seconds / 1000:.2f} kbit/s at {fps:g} fps; header {sizes['total'] - sizes['records']} "
          f"bytes once (keyframe {sizes['keyframe']}); whole file {sizes['total'] * 8 / seconds / 1000:.1f} kbit/s "
          f"over {seconds:.1f} s", file=sys.stderr)
    return 0


def cmd_decode(args) -> int:
    from facesculpt.app.coding import decode_file
    from facesculpt.app.process import _finish, _progress, open_output
    from facesculpt.app.safe_output import refuse_output_over_input

    refuse_output_over_input(args.input, args.output)
    if not Path(args.input).is_file():
        raise FileNotFoundError(f"cannot read {args.input}: no such file")
    stream, decoder = decode_file(args.input)
    output = open_output(args.output, float(stream.header["fps"]), args.codec, args.crf, None)
    try:
        with _progress(len(stream.present), "decode", args.quiet) as bar:
            for i in range(len(stream.present)):
                output.write(decoder.frame(i))
                bar.update(1)
    except BaseException:
        if hasattr(output, "discard"):
            output.discard()
        raise
    finally:
        decoder.close()
    _finish(True, output)
    print(f"wrote {output.frames} frames to {output.path!s}", file=sys.stderr)
    return 0
