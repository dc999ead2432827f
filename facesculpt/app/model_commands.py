"""`facesculpt model ...`: model-file commands (import-eos, calibrate, info, train-appearance)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np


def register(subparsers) -> None:
    model = subparsers.add_parser("model", help="morphable-model files: import from eos, inspect")
    sub = model.add_subparsers(dest="model_command", metavar="ACTION")

    imp = sub.add_parser(
        "import-eos",
        help="convert an eos model (e.g. the Surrey Face Model) to the facesculpt .npz format",
        description="Read an eos MorphableModel binary (with optional blendshapes, landmark mapping and "
        "model contours) with facesculpt's own reader and write a facesculpt .npz model.",
    )
    imp.add_argument("shape_bin", type=Path, help="eos MorphableModel file, e.g. sfm_shape_3448.bin")
    imp.add_argument("--blendshapes", type=Path, help="eos blendshapes file, e.g. expression_blendshapes_3448.bin")
    imp.add_argument("--landmarks", type=Path, help="eos landmark mapping, e.g. ibug_to_sfm.txt")
    imp.add_argument("--contours", type=Path, help="eos model contour JSON, e.g. sfm_model_contours.json")
    imp.add_argument("--id", dest="model_id", help="model id (default: the file's stem)")
    imp.add_argument("-o", "--output", type=Path, required=True, help="output .npz path")
    imp.add_argument("--calibrate", action="store_true",
                     help="also learn the model's landmark calibration (`facesculpt model calibrate`: about a minute of "
                     "CPU; not by default, docs/guide/face-models.md)")
    _texture_arguments(imp)
    imp.set_defaults(func=_import_eos)

    cal = sub.add_parser(
        "calibrate",
        help="learn where the landmark network's points lie on a model (its landmark calibration)",
        description="Render a synthetic head of the model, textured from each photo, turning through a motion of "
        "its own; track the landmark network's points on it; learn each landmark's offset from its vertex and its "
        "weight, and the network's rotation gain (docs/guide/face-models.md). For 'sfm' the calibration is written "
        "where load_model('sfm') reads it; for a .npz model, a new .npz with it.",
    )
    cal.add_argument("model", nargs="?", default="sfm", help="'sfm' or a sparse .npz model (default sfm)")
    cal.add_argument("-o", "--output", type=Path,
                     help="output (.npz): for 'sfm' default the models folder's calibration/<model id>.npz; "
                     "for a .npz model required (the model with its calibration; not overwritten)")
    cal.add_argument("--force", action="store_true", help="replace the 'sfm' calibration when there is one")
    _texture_arguments(cal)
    cal.set_defaults(func=_calibrate)

    info = sub.add_parser("info", help="print a model's sizes, landmarks and units")
    info.add_argument("model", help="'facemesh' or a .npz model file")
    info.set_defaults(func=_info)
    train = sub.add_parser(
        "train-appearance",
        help="learn the appearance model of Fitter.fit_image (a 3D AAM, seed 004) from photos",
        description="Find the faces in the photos, fit the model to their landmarks, and keep the mean and leading "
        "components of the frontal ones' grey levels at the model's vertices (docs/guide/face-models.md).",
    )
    train.add_argument("photos", nargs="+", type=Path, help="photos (.jpg, .png) or folders of them")
    train.add_argument("--model", default="sfm", help="a sparse model: 'sfm' or a .npz (default sfm)")
    train.add_argument("--components", type=int, default=10, help="components kept (default 10)")
    train.add_argument("--max-yaw", type=float, default=15.0, help="faces turned further (degrees) are left out "
                       "(default 15: frontal only)")
    train.add_argument("-o", "--output", type=Path, required=True, help="output .npz (not overwritten)")
    train.set_defaults(func=_train_appearance)
    model.set_defaults(func=lambda args: (model.print_help(), 2)[1])


def _import_eos(args: argparse.Namespace) -> int:
    from facesculpt.nodes.fitter.eos_import import import_eos
    from facesculpt.nodes.fitter.model import save_model

    output = args.output if args.output.suffix == ".npz" else args.output.with_suffix(args.output.suffix + ".npz")
    model = import_eos(args.shape_bin, blendshapes=args.blendshapes, landmarks=args.landmarks,
                       contours=args.contours, model_id=args.model_id)
    if args.calibrate and output.exists():
        print(f"facesculpt model import-eos: {output} exists; not overwritten", file=sys.stderr)
        return 2
    save_model(model, output)
    print(describe(model))
    print(f"wrote {output}")
    if args.calibrate:
        try:
            textures, what = _textures(args)
        except (ValueError, RuntimeError) as exc:
            print(f"not calibrated: {exc} (`facesculpt model calibrate {output} --textures PHOTO ...` does it later)")
            return 0
        model = _calibrated(model, textures, what, args)
        if model is None:
            return 2
        save_model(model, output)
        print(f"wrote {output} with its landmark calibration")
    return 0


def _texture_arguments(parser) -> None:
    parser.add_argument("--textures", nargs="+", type=Path, default=None,
                        help="photos of faces (.jpg, .png), one calibration sequence each; three or more other "
                        "people recommended (default: three frames of the shared data's videos, when present)")
    parser.add_argument("--frames", type=int, default=80, help="frames per calibration sequence (default 80)")
    parser.add_argument("--workers", type=int, default=0, help="rendering processes (default: one per core, at most 4)")


def _textures(args) -> tuple[list, str]:
    """The texture photos the arguments name (or the shared data's), and what they are in words.
    ValueError / RuntimeError with the reason when there are none or one cannot be read."""
    import cv2

    from facesculpt.app.landmark_calibration import SHARED_TEXTURES, shared_textures
    from facesculpt.paths import shared_data_dir

    if args.textures:
        photos = [cv2.imread(str(p)) for p in args.textures]
        bad = [str(p) for p, img in zip(args.textures, photos) if img is None]
        if bad:
            raise ValueError(f"cannot read the texture photo {', '.join(bad)}")
        return photos, ", ".join(p.name for p in args.textures)
    data = shared_data_dir()
    if data is None:
        raise ValueError("no texture photos: give --textures PHOTO ... (the shared data folder is absent)")
    return shared_textures(data), "the shared data's " + ", ".join(f"{v} frame {i}" for v, i in SHARED_TEXTURES)


def _calibrated(model, textures: list, what: str, args):
    """``model`` with the calibration learned from the texture photos (None, after a sentence on
    stderr, when it cannot be learned)."""
    import time

    from facesculpt.app.landmark_calibration import learn, sequences

    if args.frames < 8:
        print("facesculpt model calibrate: --frames must be at least 8", file=sys.stderr)
        return None
    start = time.perf_counter()
    tick = lambda done, total: print(f"sequence {done}/{total} rendered and tracked ({time.perf_counter() - start:.0f} s)")  # noqa: E731
    try:
        seqs = sequences(model, textures, args.frames, args.workers, tick)
        calibrated, learned = learn(model, seqs, what)
    except (ValueError, RuntimeError) as exc:
        print(f"facesculpt model calibrate: {exc}", file=sys.stderr)
        return None
    sigma = learned["sigma"]
    print(f"calibrated {len(learned['names'])} landmarks: offset {np.linalg.norm(learned['offsets'], axis=1).mean():.1f} mm "
          f"mean, network spread {np.median(sigma):.2f} px median; the network's points turn "
          f"{learned['rotation_slopes'][0]:.3f} of the pitch, {learned['rotation_slopes'][1]:.3f} of the yaw")
    return calibrated


def _calibrate(args: argparse.Namespace) -> int:
    from facesculpt.nodes.fitter.calibration import calibration_file
    from facesculpt.nodes.fitter.model import ModelFormatError, save_model
    from facesculpt.nodes.fitter.model_loading import load_model

    try:
        model = load_model(args.model)
    except (FileNotFoundError, ModelFormatError) as exc:
        print(f"facesculpt model calibrate: {exc}", file=sys.stderr)
        return 2
    if model.dense:
        print(f"facesculpt model calibrate: {args.model} is a dense model; only a sparse model's landmarks are "
              f"calibrated", file=sys.stderr)
        return 2
    builtin = args.model == "sfm"
    output = args.output or (calibration_file(model.model_id) if builtin else None)
    if output is None:
        print("facesculpt model calibrate: a .npz model needs -o OUTPUT (the model with its calibration)", file=sys.stderr)
        return 2
    if output.exists() and not (builtin and args.force):
        print(f"facesculpt model calibrate: {output} exists; not overwritten"
              + (" (--force replaces it)" if builtin else ""), file=sys.stderr)
        return 2
    try:
        textures, what = _textures(args)
    except (ValueError, RuntimeError) as exc:
        print(f"facesculpt model calibrate: {exc}", file=sys.stderr)
        return 2
    calibrated = _calibrated(model, textures, what, args)
    if calibrated is None:
        return 2
    if builtin:
        from facesculpt.app.landmark_calibration import save_builtin

        save_builtin(calibrated, output)
    else:
        save_model(calibrated, output)
    print(f"wrote {output}")
    return 0


def _train_appearance(args: argparse.Namespace) -> int:
    from facesculpt.app.appearance_training import train_from_photos

    if args.output.exists():
        print(f"facesculpt model train-appearance: {args.output} exists; not overwritten (remove it or choose "
              f"another name)", file=sys.stderr)
        return 2
    photos = [q for p in args.photos for q in (sorted(p.iterdir()) if p.is_dir() else [p])
              if q.suffix.lower() in (".jpg", ".jpeg", ".png")]
    try:
        appearance, faces = train_from_photos(photos, args.model, args.components, args.max_yaw)
    except (ValueError, FileNotFoundError) as exc:
        print(f"facesculpt model train-appearance: {exc}", file=sys.stderr)
        return 2
    appearance.save(args.output)
    print(f"learned from {faces} frontal faces in {len(photos)} photos: {len(appearance.sd)} components; "
          f"wrote {args.output}")
    return 0


def _info(args: argparse.Namespace) -> int:
    from facesculpt.nodes.fitter.model_loading import load_model

    print(describe(load_model(args.model)))
    return 0


def describe(model) -> str:
    """One paragraph about a model: sizes, expression kind, landmarks, outlines, units."""
    lines = [
        f"model {model.model_id}: {model.num_vertices} vertices, {len(model.triangles)} triangles, "
        f"{model.num_shape} shape components, {model.num_expression} expression components "
        f"({model.expression_kind}{': ' + ', '.join(model.expression_names) if model.num_expression else ''})",
        f"units {model.units}; texture coordinates: {'yes' if len(model.texcoords) else 'no'}; "
        f"dense: {'yes' if model.dense else 'no'}",
        f"{len(model.landmark_names)} named landmarks; outline vertices right/left: "
        f"{len(model.outline_right)}/{len(model.outline_left)}; outline landmarks right/left: "
        f"{len(model.outline_landmarks_right)}/{len(model.outline_landmarks_left)}",
    ]
    if model.source:
        lines.append(f"source: {model.source}")
    if model.calibration:
        lines.append(f"landmark calibration: {model.calibration}")
    return "\n".join(lines)
