"""`facesculpt process IN -o OUT`: a video through the whole pipeline, in one process, every frame.

    facesculpt process in.mp4 -o out.mp4 --edits nose_longer
    facesculpt process in.mp4 -o frames/%05d.png --model sfm --side-by-side --width 856

Every frame is rendered with the face fitted on that very frame (the renderer's ``sync``
pairing); a frame without a face is written unchanged. The output is a video (by its suffix:
.mp4, .mov, .m4v, .avi, .mkv; H.264 by default, with the input's sound copied in sync) or, when
OUT holds a printf pattern (``out/%05d.png``), a lossless image sequence numbered from 0 like the
input's frames. Edits are deformer presets (JSON; several
accumulate in order); they are solved once on the person's neutral model, which a first pass over
the first frames learns (see :mod:`facesculpt.app.pipeline`), and applied to every frame. The result
is deterministic: the same input and options give the same output, bit for bit (PNG; a video
codec is deterministic too, but lossy). Ctrl-C or SIGTERM stops after the current frame and keeps
what was written, a playable file (:mod:`.safe_output`).
"""

from __future__ import annotations

import copy
import signal
import sys
import threading
from contextlib import nullcontext
from pathlib import Path

import cv2
import numpy as np

from facesculpt.app.image_sequence import LOSSLESS_SUFFIXES, ImageSequenceOutput  # noqa: F401 (process's names)
from facesculpt.geometry.pose_offset import FACE_CAMERA_LIMIT_DEG, FACE_CAMERA_SMOOTHING_S


def open_output(spec: str, fps: float, codec: str | None = None, crf: int = 18, audio_from: str | None = None,
                preset: str | None = None):
    """An image-sequence writer when ``spec`` holds a ``%`` field, else a video writer (by suffix;
    ``codec``, ``crf``, ``preset``, the sound of ``audio_from`` copied in) staged under a temporary
    name until it is complete (:class:`.safe_output.StagedVideo`)."""
    if "%" in spec:
        return ImageSequenceOutput(spec)
    from facesculpt.app.safe_output import StagedVideo
    from facesculpt.nodes.renderer.video_out import VideoOutput

    def writer(path):
        return VideoOutput(path, fps, codec=codec, crf=crf, preset=preset, audio_from=audio_from)

    writer(spec)  # checks suffix, codec, quality and rate now, before anything is written
    return StagedVideo(spec, writer)


def open_input(path: str, fov_deg: float = 60.0):
    """The input video as a frame source, or an RGB-D recording as an :class:`.rgbd_process.RGBDInput`
    (``fov_deg``: its colour camera's field of view where it does not say); one clear sentence when
    it cannot be read."""
    from facesculpt.app.rgbd_process import RGBDInput, is_rgbd_input
    from facesculpt.nodes.camera.sources import SourceError, VideoSource

    if is_rgbd_input(path):
        return RGBDInput(path, fov_deg)
    if not Path(path).exists():
        raise FileNotFoundError(f"cannot read {path}: no such file")
    if Path(path).is_dir():
        raise ValueError(f"cannot read {path}: it is a directory, not a video file")
    try:
        source = VideoSource(path)
    except SourceError:
        raise ValueError(f"cannot read {path}: not a video file OpenCV can decode") from None
    return source


class _Stop:
    """SIGINT/SIGTERM set a flag; the frame loop stops after the current frame. Off the main
    thread (a batch worker's task) signals are the worker's to handle: nothing is installed."""

    def __init__(self):
        self.signal: str | None = None
        self.previous = {}

    def __enter__(self):
        def on_signal(signum, frame):
            self.signal = signal.Signals(signum).name
        if threading.current_thread() is not threading.main_thread():
            return self
        for s in (signal.SIGINT, signal.SIGTERM):
            self.previous[s] = signal.signal(s, on_signal)
        return self

    def __exit__(self, *exc):
        for s, handler in self.previous.items():
            signal.signal(s, handler)


def _frames(source, width: int, limit: int, with_depth: bool = False):
    """The first ``limit`` frames (0: all) resized to ``width``; ``with_depth``: (frame, its
    DepthImage or None) pairs."""
    from facesculpt.nodes.camera.sources import resize_frame

    for i, (frame, _) in enumerate(source.frames()):  # the clock stamps are not used: time = index / fps
        if limit and i >= limit:
            return
        frame, depth = frame if isinstance(frame, tuple) else (frame, None)
        frame = resize_frame(frame, width, 0)
        yield (frame, depth) if with_depth else frame


def _progress(total: int | None, desc: str, quiet: bool):
    from tqdm import tqdm

    return tqdm(total=total, desc=desc, unit="frame", file=sys.stderr, disable=quiet, dynamic_ncols=True,
                leave=True)


def parse_edits(specs: list[str], selection) -> list[tuple[int | None, str]]:
    """``--edits`` values as (face key or None for every face, preset path or name). ``N:PRESET``
    names face N (numbered from 1), whose key is its track id N - 1 (:mod:`facesculpt.nodes.fitter.faces`)."""
    out = []
    for spec in specs:
        head, sep, rest = spec.partition(":")
        if sep and head.strip().isdigit() and rest:
            n = int(head)
            if n < 1:
                raise ValueError(f"--edits {spec}: faces are numbered from 1")
            if selection == "largest":
                raise ValueError(f"--edits {spec} edits face {n} only: add --faces all (or --faces {n})")
            if isinstance(selection, int) and selection != n:
                raise ValueError(f"--edits {spec} edits face {n}, but --faces {selection} fits face {selection} only")
            out.append((n - 1, rest))
        else:
            out.append((None, spec))
    return out


def missing_face(selection, track_ids: set[int], video) -> str:
    """The sentence for ``--faces N`` on ``video`` when face N (track id N - 1) was never found
    among the tracks ``track_ids`` found in it, naming how many were; "" when it was found or
    ``selection`` names no one face ("all", "largest")."""
    if not isinstance(selection, int) or selection - 1 in track_ids:
        return ""
    found = len(track_ids)
    how = ("no face was found" if found == 0 else "only 1 face was found (face 1)" if found == 1
           else f"only {found} faces were found (faces 1 to {found}, from the left)")
    return f"--faces {selection}: {how} in {video}, so there is no face {selection} to fit; no output written"


def _calibrate(pipeline, args, total, fps: float, stop, presets) -> None:
    """First pass: the person's neutral from the first frames, then the edit solved on it once."""
    calib = open_input(args.input, args.fov)
    try:
        with _progress(min(args.neutral_frames, total or args.neutral_frames), "neutral", args.quiet) as bar:
            def tick(_read):
                bar.update(1)
                if stop.signal:
                    raise KeyboardInterrupt
            pipeline.calibrate(_frames(calib, args.width, args.max_frames, True), fps, progress=tick)
    finally:
        calib.close()
    if pipeline.fitter is None or pipeline.fitted_frames == 0:
        print(f"facesculpt: no face found in the first frames of {args.input}: the edits apply to faces "
              f"found later, on the model's mean face", file=sys.stderr)
    for face, preset in presets:
        pipeline.set_edits(preset, face)


def _finish(completed: bool, *outputs) -> None:
    """Each staged output (video, bag) is renamed onto its target when the run completed, kept under
    its partial name when it was interrupted; an image sequence is already where it belongs (None: skipped)."""
    for output in filter(None, outputs):
        if not hasattr(output, "commit"):
            output.close()
        elif completed:
            output.commit()
        else:
            output.keep_partial()


def _render_frames(pipeline, source, args, fps: float, total, output, export, stop, seen: dict,
                   depth_output=None) -> None:
    """The rendering pass in three stages on two cores: every frame decoded and analysed a frame
    ahead (:mod:`.read_ahead`), composited and exported here, where the GL context is, and encoded
    a frame behind (:mod:`.write_behind`); decoding, landmarks, fitting and encoding release the
    GIL. In a batch worker (``args.read_ahead`` False), which is one core's worth of work already,
    all on this thread. ``seen`` counts frames with a face and the faces edited; ``depth_output``
    takes each frame's edited depth (:func:`.rgbd_process.write_edited_depth`). Raises
    KeyboardInterrupt on a stop signal."""
    from facesculpt.app.read_ahead import ReadAhead
    from facesculpt.app.write_behind import WriteBehind

    def analysed():
        for i, (frame, depth) in enumerate(_frames(source, args.width, args.max_frames, True)):
            yield frame, depth, pipeline.analyse(frame, i / fps, depth)

    pipelined = getattr(args, "read_ahead", True)
    ahead = ReadAhead(analysed(), depth=2) if pipelined else nullcontext(analysed())
    behind = WriteBehind(output, depth=2) if pipelined else nullcontext(output)
    with _progress(total, "process", args.quiet) as bar, ahead as frames, behind as writer:
        for index, (frame, depth, (fits, timings)) in enumerate(frames):
            if export is not None:
                export.add(index, index / fps, fits)
            result = pipeline.compose(frame, fits, timings)
            seen["frames_with_face"] += bool(result.fits)
            seen["faces_edited"].update(k for k in result.fits if pipeline.displacement_of(k) is not None)
            writer.write(np.hstack([frame, result.image]) if args.side_by_side else result.image)
            if depth_output is not None:
                from facesculpt.app.rgbd_process import write_edited_depth

                write_edited_depth(depth_output, result.image, pipeline.K, depth, result, pipeline.model.triangles)
            bar.update(1)
            if stop.signal:
                raise KeyboardInterrupt


def _atlas_options(args) -> tuple[str, str]:
    """(--save-texture's file or "", the Pipeline's atlas mode: "on", "learn" (only to save it) or
    "off"); a texture file over the input or not a .png raises ValueError."""
    from facesculpt.app.safe_output import refuse_output_over_input

    save_texture = getattr(args, "save_texture", "")
    if save_texture:
        refuse_output_over_input(args.input, save_texture)
        if Path(save_texture).suffix.lower() != ".png":
            raise ValueError(f"--save-texture {save_texture}: the atlas is written as a .png")
    atlas = getattr(args, "atlas", "off")
    return save_texture, "on" if atlas == "on" else ("learn" if save_texture else "off")


def _stage_options(args) -> dict:
    """The Pipeline's fitting, compositing and expression-label options (``fit``, ``render``,
    ``expression_labels``, ``fov_deg``) from the
    command line's flags (ValueError in one sentence on a bad value)."""
    from facesculpt.nodes.fitter.config import FitterConfig
    from facesculpt.nodes.fitter.expression_labels import ExpressionLabelOptions
    from facesculpt.nodes.renderer.compositor_options import CompositorOptions

    rotation_prior = args.rotation_prior
    if not rotation_prior >= 0:
        raise ValueError(f"--rotation-prior must be a weight >= 0 px per radian (0: off), got {rotation_prior}")
    refine = getattr(args, "refine", "off")
    fit = FitterConfig(neutral_frames=args.neutral_frames, rotation_prior_px=rotation_prior,
                       refine=None if refine == "off" else refine)
    render = {"inpaint": getattr(args, "inpaint", "drag"), "interpolation": getattr(args, "interpolation", "sinc")}
    if getattr(args, "outline_band", None) is not None:
        render["outline_band"] = args.outline_band
    labels = ExpressionLabelOptions(baseline_frames=args.neutral_frames,
                                    source=getattr(args, "expression_source", ExpressionLabelOptions.source),
                                    weights=getattr(args, "expression_weights", ExpressionLabelOptions.weights))
    return {"fov_deg": args.fov, "fit": fit, "render": CompositorOptions(**render), "expression_labels": labels}


def _pose_options(args) -> dict:
    """The Pipeline's pose options from --pose, --face-camera, its limit and smoothing, --keyframes (ValueError
    in one sentence on a bad value)."""
    from facesculpt.geometry.pose_offset import check_face_camera, parse_pose_offset

    face_camera = getattr(args, "face_camera", 0.0)
    limit = getattr(args, "face_camera_limit", FACE_CAMERA_LIMIT_DEG)
    smoothing = getattr(args, "face_camera_smoothing", FACE_CAMERA_SMOOTHING_S)
    check_face_camera(face_camera, limit, smoothing, ("--face-camera", "--face-camera-limit", "--face-camera-smoothing"))
    return {"pose": parse_pose_offset(getattr(args, "pose", "")), "face_camera": face_camera,
            "face_camera_limit_deg": limit, "face_camera_smoothing_s": smoothing,
            "keyframes": getattr(args, "keyframes", "auto"), "pose_limit": getattr(args, "pose_limit", "on") == "on"}


def _warn_reduced_turns(limiter) -> None:
    """One warning line when the pose limit reduced a turn (``limiter``: the pipeline's PoseLimiter or None)."""
    if limiter is not None and limiter.reduced:
        print(f"facesculpt: warning: the turn was reduced on {limiter.reduced} frame(s) (to {100 * limiter.lowest:.0f} % "
              f"at least): the video shows too little of the surface it would reveal (--pose-limit off draws it all; "
              f"docs/guide/new-views.md)", file=sys.stderr)


def _open_streams(args):
    """(the input source, fps, frame count or None, the video output, the edited depth's output or
    None, the colour K of an RGB-D input's frames as processed or None); one sentence (ValueError)
    for --depth-out without an RGB-D input, nothing left open."""
    from facesculpt.app.rgbd_process import RGBDInput, colour_intrinsics, open_depth_output

    source = open_input(args.input, args.fov)
    rgbd, depth_spec, depth_output = isinstance(source, RGBDInput), getattr(args, "depth_out", ""), None
    fps, total = source.native_fps, source.frame_count or None
    if total and args.max_frames:
        total = min(total, args.max_frames)
    try:
        if depth_spec and not rgbd:
            raise ValueError(f"--depth-out needs an RGB-D input (a folder of colour + 16-bit depth images, or a bag "
                             f"whose frames carry depth); {args.input} is a video")
        if depth_spec:
            depth_output = open_depth_output(depth_spec, args.input, fps)
        output = open_output(args.output, fps, args.codec, args.crf,
                             None if args.no_audio or rgbd else args.input, getattr(args, "preset", None))
    except BaseException:
        getattr(depth_output, "discard", lambda: None)()
        source.close()
        raise
    return source, fps, total, output, depth_output, colour_intrinsics(source, args.width) if rgbd else None


def process_file(args, input_path: str, output_spec: str, detector=None) -> tuple[int, str]:
    """One video through the pipeline with the options of ``args`` (the command line's); returns
    (exit status, the one line that says what was written). ``detector``: a
    :class:`LandmarkDetector` to reuse (a batch worker keeps its networks loaded); its tracks are
    reset first, so the output is the same as with a fresh one. Raises on bad input."""
    from facesculpt.app.pipeline import Pipeline, read_preset
    from facesculpt.app.safe_output import refuse_output_over_input
    from facesculpt.nodes.deformer.preset_format import check_strength, merge_presets, scale_preset
    from facesculpt.nodes.fitter import parse_faces

    args = copy.copy(args)
    args.input, args.output = input_path, output_spec
    from facesculpt.app.rgbd_process import input_file

    refuse_output_over_input(input_file(args.input), args.output)  # before anything is opened
    export, gaze = None, bool(getattr(args, "gaze", False))
    if getattr(args, "export_params", ""):
        from facesculpt.app.params_export import ParamsExport

        refuse_output_over_input(input_file(args.input), args.export_params)
        export = ParamsExport(args.export_params, gaze=gaze)
    selection = parse_faces(args.faces)
    strength = check_strength(args.strength, "--strength")
    presets = [(face, scale_preset(read_preset(p), strength)) for face, p in parse_edits(args.edits, selection)]
    pose_options, stage_options = _pose_options(args), _stage_options(args)
    source, fps, total, output, depth_output, K = _open_streams(args)
    save_texture, atlas = _atlas_options(args)
    pipeline = Pipeline(args.model, threads=args.threads, **stage_options, **pose_options,
                        faces=selection, detector=detector, atlas=atlas, plate=getattr(args, "plate", "off"),
                        expression=export is not None, gaze=gaze, K=K)
    if presets:
        from facesculpt.nodes.deformer import DeformerError

        try:  # a preset that does not fit the model fails now, not after the first pass
            pipeline.edit_stack().apply_preset(merge_presets([p for _, p in presets]))
        except DeformerError as exc:
            raise ValueError(f"the edits do not fit the {args.model} model: {exc}") from None
    seen = {"frames_with_face": 0, "faces_edited": set()}
    try:
        with _Stop() as stop:
            if presets:
                _calibrate(pipeline, args, total, fps, stop, presets)
            _render_frames(pipeline, source, args, fps, total, output, export, stop, seen, depth_output)
    except KeyboardInterrupt:
        _finish(False, output, depth_output)
        if export is not None:
            export.write()
        return 130, f"interrupted: kept {output.frames} frames in {output.path!s}"
    except BaseException:
        for out in (output, depth_output):
            getattr(out, "discard", lambda: None)()  # the unfinished file is ours; the target keeps what it held
        raise
    finally:
        source.close()
        texture, limiter = (pipeline.texture() if save_texture else None), pipeline.pose_limiter
        pipeline.close()
    _warn_reduced_turns(limiter)
    problem = (f"cannot read {args.input}: it holds no frames" if output.frames == 0
               else missing_face(selection, pipeline.track_ids_seen, args.input))
    if problem:
        for out in (output, depth_output):  # an image sequence has no discard: its frames stay
            getattr(out, "discard", lambda: None)()
        raise ValueError(problem)
    _finish(True, output, depth_output)
    if export is not None:
        export.write()
    if save_texture:
        if texture is None:
            print(f"facesculpt: no face seen: no texture written to {save_texture}", file=sys.stderr)
        elif not cv2.imwrite(str(save_texture), texture):
            raise RuntimeError(f"cannot write {save_texture}")
    frames_with_face, faces_edited = seen["frames_with_face"], seen["faces_edited"]
    if presets and not faces_edited:
        how = "no face was found" if not frames_with_face else "no face the edits name was found"
        return 0, f"wrote {output.frames} frames to {output.path!s} unedited: {how}"
    edits = f", edits from {', '.join(args.edits)} on {len(faces_edited)} face(s)" if faces_edited else ""
    depth = f"; the edited depth to {depth_output.path!s}" if depth_output is not None else ""
    return 0, f"wrote {output.frames} frames to {output.path!s} ({frames_with_face} with a face{edits}){depth}"
