"""The options of a detect-then-track landmark detector (the face mesh's and the hands'): one
dataclass, each field with its default, unit, valid range and help text, from which the
detectors take their settings and the landmarks and hands nodes declare their parameters.

A detector's own defaults are one instance of it (the face detector's are the class defaults;
the hands room keeps its instance beside its detector). :func:`with_values` applies the keyword
arguments a detector is constructed with, including a room's own name for a field
(``max_faces``, ``max_hands`` for ``max_tracked``).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

from facesculpt.options import option


@dataclass(frozen=True)
class DetectorOptions:
    """Settings of a detector that finds objects (faces, hands) with an SSD detector and tracks
    each with a landmark network on a crop from its last points.

    ``min_face`` counts for the face detector only (the palm detector sees the whole frame),
    ``mirrored`` for the hands only (handedness).
    """

    models_dir: str = option("", "directory filled by `facesculpt setup` (\"\": FACESCULPT_HOME / cache)")
    threads: int = option(1, "onnxruntime intra-op threads per network (0: onnxruntime's default)",
                           range=(0, 64))
    max_tracked: int = option(1, "the most faces (hands) tracked at once; faces: the largest are kept", range=(1, 16))
    min_detection_score: float = option(0.5, "detector score threshold", range=(0.0, 1.0))
    min_tracking_score: float = option(0.5, "presence score below which one counts as lost and the detector "
                                             "reruns", range=(0.0, 1.0))
    nms_iou: float = option(0.3, "overlap (IoU) above which two detections merge", range=(0.0, 1.0))
    redetect_interval: int = option(15, "frames between detector runs while fewer than the most are tracked",
                                     unit="frames", range=(1, 1000))
    min_face: float = option(0.15, "smallest face to detect, fraction of the short image side (0: whole image "
                                    "only)", range=(0.0, 1.0))
    mirrored: bool = option(False, "the camera image is mirrored (a selfie view): swaps handedness")
    backend: str = option("onnxruntime", "the runtime: onnxruntime (the converted networks) or litert (the "
                                          "original .tflite networks, a reference)",
                           choices=("onnxruntime", "litert"))


def with_values(options: DetectorOptions, aliases: dict[str, str], values: dict) -> DetectorOptions:
    """``options`` with ``values`` (field name, or a room's name in ``aliases`` -> field name) in
    place of its own; a value of None keeps the option's. An unknown name raises TypeError."""
    names = {f.name for f in dataclasses.fields(DetectorOptions)}
    changes = {}
    for key, value in values.items():
        name = aliases.get(key, key)
        if name not in names:
            raise TypeError(f"unknown detector option {key!r} (known: {', '.join(sorted(names | set(aliases)))})")
        if value is not None:
            changes[name] = str(value) if name == "models_dir" else value
    return dataclasses.replace(options, **changes)
