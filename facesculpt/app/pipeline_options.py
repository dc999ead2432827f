"""The in-process pipeline's options by their old keyword names (``Pipeline(neutral_frames=10,
inpaint="pushpull")``), now the fields of :class:`FitterConfig` (``fit=``) and
:class:`CompositorOptions` (``render=``): still accepted for one release, each with a warning."""

from __future__ import annotations

import dataclasses
import warnings

from facesculpt.nodes.fitter.config import FitterConfig
from facesculpt.nodes.renderer.compositor_options import CompositorOptions

#: Old Pipeline keyword -> (which options, field).
OLD_NAMES = {
    "neutral_frames": ("fit", "neutral_frames"),
    "iterations": ("fit", "iterations"),
    "rotation_prior_px": ("fit", "rotation_prior_px"),
    "refine": ("fit", "refine"),
    "inpaint": ("render", "inpaint"),
    "feather_px": ("render", "feather_px"),
    "dilate_px": ("render", "dilate_px"),
    "interpolation": ("render", "interpolation"),
    "outline_band": ("render", "outline_band"),
}


def options_of_old_names(fit: FitterConfig, render: CompositorOptions, given: dict
                         ) -> tuple[FitterConfig, CompositorOptions]:
    """``fit`` and ``render`` with the old keywords in ``given`` applied (a None value keeps the
    option's); TypeError naming an unknown keyword. Warns (DeprecationWarning) once per call."""
    unknown = sorted(set(given) - set(OLD_NAMES))
    if unknown:
        raise TypeError(f"Pipeline got unexpected keyword argument(s) {', '.join(unknown)}")
    changes = {"fit": {}, "render": {}}
    for name, value in given.items():
        if value is not None:
            which, field = OLD_NAMES[name]
            changes[which][field] = value
    if given:
        warnings.warn(f"Pipeline({', '.join(f'{k}=' for k in sorted(given))}): give these as "
                      f"fit=FitterConfig(...) / render=CompositorOptions(...); the old keywords go in the next "
                      f"release", DeprecationWarning, stacklevel=3)
    return (dataclasses.replace(fit, **changes["fit"]) if changes["fit"] else fit,
            dataclasses.replace(render, **changes["render"]) if changes["render"] else render)
