"""Loading a model by name or path: the built-in face mesh, the Surrey Face Model imported on the
fly (with its landmark calibration when one was built), or a ``.npz`` model file. Apart from
:mod:`.model` (the format), whose builders (:mod:`.facemesh_model`, :mod:`.eos_import`,
:mod:`.calibration`) import it."""

from __future__ import annotations

from pathlib import Path

from facesculpt.nodes.fitter.model import ModelFormatError, MorphableModel, load_npz


def load_model(name_or_path: str | Path = "facemesh") -> MorphableModel:
    """Load a model: ``"facemesh"`` (built-in, needs `facesculpt setup`), ``"sfm"`` (the Surrey Face
    Model, imported on the fly from the shared data folder, with the landmark calibration of
    :func:`.calibration.calibration_file` when there is one), or a path to a ``.npz`` model file.
    Raises FileNotFoundError / :class:`ModelFormatError` with a message saying what is wrong."""
    # the named models' builders are imported when asked for (scipy, eos files): a quicker start
    if isinstance(name_or_path, MorphableModel):
        return name_or_path
    text = str(name_or_path)
    if text == "facemesh":
        from facesculpt.nodes.fitter.facemesh_model import facemesh_model

        return facemesh_model()
    if text == "sfm":
        from facesculpt.nodes.fitter.calibration import calibration_file, load_calibration
        from facesculpt.nodes.fitter.eos_import import import_eos, sfm_files

        model = import_eos(**sfm_files(), model_id="sfm_shape_3448")
        # the network points' calibration (`bench_registration.py --calibrate`), when one was built
        calibration = calibration_file(model.model_id)
        return load_calibration(calibration, model) if calibration.is_file() else model
    path = Path(text).expanduser()
    if not path.is_file():
        raise FileNotFoundError(
            f"model {text!r} not found: give 'facemesh', or a .npz made by `facesculpt model import-eos`"
        )
    if path.suffix == ".bin":
        raise ModelFormatError(f"{path} is an eos binary: convert it first with `facesculpt model import-eos {path} -o MODEL.npz`")
    return load_npz(path)
