"""`facesculpt model ...`: model-file commands (import-eos, info, train-appearance)."""

from __future__ import annotations

import argparse
from pathlib import Path


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
    imp.set_defaults(func=_import_eos)

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
    save_model(model, output)
    print(describe(model))
    print(f"wrote {output}")
    return 0


def _train_appearance(args: argparse.Namespace) -> int:
    import sys

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
    return "\n".join(lines)
