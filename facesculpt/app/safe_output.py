"""A user's files are never lost to `facesculpt process`: the output may not be the input, and a
video is written beside its target under a temporary name and renamed onto it only when it is
complete. A failure leaves no file under the target's name (and an existing one untouched); an
interrupt keeps what was written under a clear name of its own (``NAME.partial.SUFFIX``)."""

from __future__ import annotations

import os
import re
from pathlib import Path


def partial_name(target: Path) -> Path:
    """Where an interrupted run keeps its frames: ``out.mp4`` -> ``out.partial.mp4`` beside it."""
    return target.with_name(f"{target.stem}.partial{target.suffix}")


def temporary_name(target: Path) -> Path:
    """Where a run writes until it is complete: a hidden name beside the target (same filesystem,
    so the final rename is atomic), unique to this process."""
    return target.with_name(f".{target.stem}.{os.getpid()}.writing{target.suffix}")


def _pattern_regex(pattern: str) -> re.Pattern:
    """A printf pattern with one integer field (``out/%05d.png``) as a regex of the names it makes."""
    parts = re.split(r"%0?\d*d", pattern, maxsplit=1)
    if len(parts) != 2:
        return re.compile(re.escape(pattern) + r"\Z")
    return re.compile(re.escape(parts[0]) + r"\d+" + re.escape(parts[1]) + r"\Z")


def refuse_output_over_input(input_path: str | os.PathLike, output_spec: str) -> None:
    """ValueError in one sentence when writing ``output_spec`` (a video path, or an image pattern
    such as ``out/%05d.png``) could overwrite the input: the same file after resolving links, or
    an input whose name the pattern can make."""
    source = Path(input_path).expanduser().resolve()
    if "%" in output_spec:
        folder = Path(output_spec).expanduser().parent.resolve()
        made = _pattern_regex(Path(output_spec).name)
        if source.parent == folder and made.match(source.name):
            raise ValueError(f"refusing to write the output pattern {output_spec} over the input {input_path} "
                             f"(one of its frame names is the input's): choose another -o")
        return
    target = Path(output_spec).expanduser()
    same = target.exists() and os.path.samefile(target, source)
    if same or target.resolve() == source:
        raise ValueError(f"refusing to write the output {output_spec} over the input {input_path} "
                         f"(they are the same file): choose another -o")


class StagedVideo:
    """A video output (anything with ``write``, ``close``, ``frames``, ``path``) written under
    :func:`temporary_name` and moved onto ``target`` by :meth:`commit`, or onto
    :func:`partial_name` by :meth:`keep_partial`; :meth:`discard` removes it (it is ours).

    ``open_writer(path)`` makes the underlying writer for the temporary path."""

    def __init__(self, target: str | os.PathLike, open_writer):
        self.target = Path(target).expanduser()
        self.staging = temporary_name(self.target)
        self.writer = open_writer(self.staging)
        self.path = self.target

    @property
    def frames(self) -> int:
        return self.writer.frames

    def write(self, frame) -> None:
        self.writer.write(frame)

    def close(self) -> None:
        self.writer.close()

    def commit(self) -> Path:
        """Finish the file and give it the target's name (replacing an older file of that name)."""
        self.writer.close()
        os.replace(self.staging, self.target)
        return self.target

    def keep_partial(self) -> Path:
        """Finish the file and keep it as ``NAME.partial.SUFFIX``; ``path`` then names it."""
        self.writer.close()
        if self.staging.exists():
            self.path = partial_name(self.target)
            os.replace(self.staging, self.path)
        return self.path

    def discard(self) -> None:
        """Remove the unfinished file (never the target)."""
        self.writer.close()
        self.staging.unlink(missing_ok=True)
