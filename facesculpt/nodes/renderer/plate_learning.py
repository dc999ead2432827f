"""The background plate's learning on threads of its own (docs/architecture.md "Stages", 4; issue 16).

Each frame's update of the plate (:class:`.background_plate.BackgroundPlate`) runs beside the
compositor's drawing (OpenCV and onnxruntime let go of the GIL) and is waited for before the fill
reads the plate, so every frame sees the plate it would see without the threads. With a person
segmenter the plate learns nothing where a person is (grown by the plate's margin). The people need
only the frame: :meth:`PlateLearner.prefetch` starts looking for them as soon as the frame is there
(while its face is fitted), on a second thread; a frame not prefetched is searched when it is learned.
"""

from __future__ import annotations

import threading
from concurrent.futures import Future, ThreadPoolExecutor

import numpy as np

from .background_plate import BackgroundPlate, occluded_region
from .drag_fill import dragged_to
from .inpaint import dilate

PREFETCHED = 4   # frames whose people may be searched ahead of their learning
MATCH_LEVELS = 24  # a frame pixel within this many grey levels of the plate (every channel) shows the background


def grown_in_box(mask: np.ndarray, radius: int, box: tuple[int, int, int, int] | None) -> np.ndarray:
    """(H, W) uint8 ``mask`` grown by a disk of ``radius`` px inside ``box`` (x0, y0, x1, y1; None: the
    whole frame), as it is outside (the plate learns only inside the box; its registration looks
    for the background everywhere)."""
    if box is None:
        return dilate(mask, radius)
    h, w = mask.shape
    x0, y0, x1, y1 = max(0, box[0]), max(0, box[1]), min(w, box[2]), min(h, box[3])
    out = mask.copy()
    if x1 > x0 and y1 > y0:   # grown with the people up to ``radius`` outside the box
        X0, Y0, X1, Y1 = max(0, x0 - radius), max(0, y0 - radius), min(w, x1 + radius), min(h, y1 + radius)
        out[y0:y1, x0:x1] = dilate(mask[Y0:Y1, X0:X1], radius)[y0 - Y0:y1 - Y0, x0 - X0:x1 - X0]
    return out


class PlateLearner:
    """PlateLearner(plate, segmenter=None): learns into ``plate``; ``segmenter`` a callable frame ->
    (H, W) uint8 0/1 mask of people (None: only the face is kept off the plate).

    :meth:`prefetch` when a frame arrives (optional), :meth:`learn` once a frame, :meth:`sync`
    before the plate is read, :meth:`close` at the end."""

    def __init__(self, plate: BackgroundPlate, segmenter=None):
        self.plate, self.segmenter = plate, segmenter
        self._pool = ThreadPoolExecutor(1, thread_name_prefix="plate")
        self._people_pool = ThreadPoolExecutor(1, thread_name_prefix="people") if segmenter is not None else None
        self._job = None
        self._lock = threading.Lock()
        self._ahead: list[tuple[np.ndarray, Future]] = []   # (frame, its people), oldest first
        self._people: Future | None = None   # the people of the frame learned last

    def prefetch(self, frame: np.ndarray) -> None:
        """Start looking for the people of ``frame`` ((H, W, 3) uint8; the same array, unchanged, is
        later given to :meth:`learn`). Nothing without a segmenter."""
        if self._people_pool is None:
            return
        job = self._people_pool.submit(self.segmenter, frame)
        with self._lock:
            self._ahead = self._ahead[-(PREFETCHED - 1):] + [(frame, job)]

    def learn(self, frame: np.ndarray, projected_px: np.ndarray, margin_px: float,
              keep_box: tuple[int, int, int, int] | None, keep_mask: np.ndarray | None = None) -> None:
        """Start taking ``frame`` ((H, W, 3) uint8) into the plate outside the face (its (V, 2)
        ``projected_px`` hull grown by ``margin_px``), ``keep_mask`` ((H, W), non-zero: in front of the
        background) and the people grown by ``margin_px``; ``keep_box`` (x0, y0, x1, y1): what the plate
        keeps when the camera moves (:meth:`.BackgroundPlate.update`)."""
        self.sync()
        people = None
        if self._people_pool is not None:
            with self._lock:
                found = [job for f, job in self._ahead if f is frame]
                self._ahead = [(f, job) for f, job in self._ahead if f is not frame]
            people = found[0] if found else self._people_pool.submit(self.segmenter, frame)
        self._people = people
        occluded = occluded_region((self.plate.height, self.plate.width), projected_px, margin_px, keep_mask)
        self._job = self._pool.submit(self._update, frame.copy(), occluded, keep_box, margin_px, people)

    def _update(self, frame: np.ndarray, occluded: np.ndarray | None, keep_box, margin_px: float,
                people: Future | None) -> None:
        if people is not None:
            grown = grown_in_box(people.result(), int(np.ceil(margin_px)), keep_box)
            occluded = grown if occluded is None else occluded | grown
        self.plate.update(frame, occluded, keep_box)

    def people(self) -> np.ndarray | None:
        """(H, W) uint8 0/1: the people of the frame learned last (as found, not grown); None without
        a segmenter."""
        return None if self._people is None else self._people.result()

    def background_at(self, frame: np.ndarray, xs: np.ndarray, ys: np.ndarray) -> np.ndarray:
        """(N,) bool: whether the pixels (``xs``, ``ys``) (N,) int of ``frame`` (the one learned last)
        show the background: where the plate knows them, the frame matches it (background
        subtraction: every channel within MATCH_LEVELS); elsewhere, nobody is there (the segmenter's
        people; without a segmenter, yes)."""
        known = self.plate.known_at(xs, ys)
        same = np.abs(frame[ys, xs].astype(np.float32) - self.plate.colour[ys, xs]).max(axis=1) <= MATCH_LEVELS
        people = self.people()
        nobody = np.ones(len(xs), bool) if people is None else people[ys, xs] == 0
        return np.where(known, same, nobody)

    def background_pixels(self, frame: np.ndarray, fill: np.ndarray, dragged_in: np.ndarray, dragged: np.ndarray,
                          box: tuple[int, int, int, int]) -> np.ndarray:
        """(h, w) uint8 0/1: the pixels of ``fill`` ((h, w), non-zero: what an edit uncovered in the frame's
        ``box``) that show the background, so the plate may take them. ``dragged_in`` (h, w) bool: the
        drag fill's pixels, with their ``dragged`` (h, w, 2) offsets: those whose dragged source shows
        the background (:meth:`background_at`; where it shows a person, the pixel is that person's
        rim, which the fitted outline lay inside). The others: where the segmenter saw nobody (all of
        them without a segmenter)."""
        out = (fill != 0) & ~dragged_in
        people = self.people()
        if people is not None:
            x0, y0, x1, y1 = box
            out &= people[y0:y1, x0:x1] == 0
        ys, xs = np.nonzero(dragged_in)
        sx, sy, inside = dragged_to(dragged, ys, xs, box[:2], frame.shape)
        shown = self.background_at(frame, sx[inside], sy[inside])
        out[ys[inside][shown], xs[inside][shown]] = True
        return out.view(np.uint8)

    def sync(self) -> None:
        """Wait for the plate's update of the last frame."""
        if self._job is not None:
            job, self._job = self._job, None
            job.result()

    def close(self) -> None:
        """Wait for the work started and stop the threads."""
        self.sync()
        self._pool.shutdown(wait=True)
        if self._people_pool is not None:
            self._people_pool.shutdown(wait=True)
