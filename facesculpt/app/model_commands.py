"""`facesculpt model ...`: model-file commands (import-eos, info)."""

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


def _info(args: argparse.Namespace) -> int:
    from facesculpt.nodes.fitter.model import load_model

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
