"""`process --export-params FILE.csv|json`: the head pose and expression parameters of every frame.

One row per frame and fitted face: ``frame`` (index from 0), ``time_s``, ``face`` (the face key:
0 for the largest face, else its number from the left minus 1), the pose columns
(:data:`facesculpt.nodes.fitter.expression.POSE_NAMES`) and the expression components
(:data:`~facesculpt.nodes.fitter.expression.NAMES`, docs/guide/expressions.md), then the
expression recognised: ``expression`` (its label), ``expression_intensity`` (0..1) and
``expression_phase`` (:mod:`facesculpt.nodes.fitter.expression_labels`), and with ``gaze``
the gaze columns (:data:`facesculpt.nodes.fitter.gaze.GAZE_NAMES`, docs/guide/eyes.md). A frame
without a fitted face has one row with ``face`` and every value empty (CSV) or null (JSON). The
file is written beside its target under a temporary name and renamed when complete.
"""

from __future__ import annotations

import csv
import json
import math
import os
from pathlib import Path

from facesculpt.nodes.fitter.expression import NAMES, POSE_NAMES, head_pose
from facesculpt.nodes.fitter.gaze import GAZE_NAMES, gaze_values

SUFFIXES = (".csv", ".json")
LABEL_COLUMNS = ("expression", "expression_intensity", "expression_phase")
COLUMNS = ("frame", "time_s", "face", *POSE_NAMES, *NAMES, *LABEL_COLUMNS)


class ParamsExport:
    """Collects rows (:meth:`add`) and writes them (:meth:`write`) to ``path`` (.csv or .json;
    ValueError in one sentence otherwise); ``gaze``: with the gaze columns."""

    def __init__(self, path: str | Path, gaze: bool = False):
        self.path = Path(path)
        if self.path.suffix.lower() not in SUFFIXES:
            raise ValueError(f"--export-params {path}: write a .csv or a .json file")
        self.rows: list[dict] = []
        self.columns = COLUMNS + (GAZE_NAMES if gaze else ())

    def add(self, frame: int, time_s: float, fits: dict) -> None:
        """The rows of one frame: ``fits`` face key -> FitResult (with ``expression``)."""
        if not fits:
            self.rows.append({"frame": frame, "time_s": round(time_s, 6), "face": None})
            return
        for key, fit in sorted(fits.items()):
            row = {"frame": frame, "time_s": round(time_s, 6), "face": int(key)}
            row.update(zip(POSE_NAMES, (round(float(v), 4) for v in head_pose(fit))))
            if fit.expression is not None:
                row.update(zip(NAMES, (round(float(v), 4) for v in fit.expression)))
            label = getattr(fit, "expression_label", None)
            if label is not None:
                row.update(zip(LABEL_COLUMNS, (label.label, round(float(label.intensity), 4), label.phase)))
            if getattr(fit, "gaze", None) is not None:
                row.update(zip(GAZE_NAMES, (v if isinstance(v, int) else round(float(v), 4)
                                            for v in gaze_values(fit.gaze))))
            self.rows.append(row)

    def write(self) -> Path:
        """Write every row (missing values empty or null); returns the path."""
        self.path.parent.mkdir(parents=True, exist_ok=True)
        tmp = self.path.with_name(f".{self.path.name}.{os.getpid()}.writing")

        def value(row, column):
            v = row.get(column)
            return None if v is None or (isinstance(v, float) and not math.isfinite(v)) else v

        try:
            with open(tmp, "w", newline="") as f:
                if self.path.suffix.lower() == ".csv":
                    writer = csv.writer(f)
                    writer.writerow(self.columns)
                    for row in self.rows:
                        writer.writerow(["" if value(row, c) is None else value(row, c) for c in self.columns])
                else:
                    json.dump({"columns": list(self.columns),
                               "rows": [{c: value(row, c) for c in self.columns} for row in self.rows]}, f)
            os.replace(tmp, self.path)
        finally:
            tmp.unlink(missing_ok=True)
        return self.path
