"""Per-process limits for the graph's nodes.

Several nodes share a few cores; a library that spreads each small operation over
every core only adds contention: the fitter's small least squares and the
renderer's fills of small bands run faster on one thread each than spread over
cores that the graph's other processes already use. The same holds for Mesa's software
rasteriser (llvmpipe): its own threads wait for cores the other nodes hold, and the renderer
waits for them.
"""

from __future__ import annotations

import ctypes
import os


def limit_threads(threads: int = 1) -> list[str]:
    """Limit the worker threads of OpenBLAS (:func:`limit_blas_threads`), OpenCV
    (``cv2.setNumThreads``) and llvmpipe (``LP_NUM_THREADS``: ``threads`` - 1 threads of its own
    beside the one that draws, for OpenGL contexts made afterwards) in this process to
    ``threads``; 0 leaves them at their defaults (one per core). Child processes inherit the limit
    through ``FACESCULPT_THREADS``, which :func:`facesculpt.runtime.node.run_node` reads. Returns
    the BLAS libraries changed."""
    threads = int(threads)
    os.environ["FACESCULPT_THREADS"] = str(threads)
    if threads <= 0:
        return []
    os.environ["LP_NUM_THREADS"] = str(threads - 1)
    try:
        import cv2
    except ImportError:  # pragma: no cover - a dependency of the package
        pass
    else:
        cv2.setNumThreads(threads)
    return limit_blas_threads(threads)


def limit_blas_threads(threads: int = 1) -> list[str]:
    """Make OpenBLAS (numpy's and scipy's) use ``threads`` threads in this process and in the
    processes it starts. The fitter's least squares are small (68 landmarks x 69 coefficients):
    a second BLAS thread only spins, and slows the fit beside the graph's other processes. Sets ``OPENBLAS_NUM_THREADS`` (read by
    libraries loaded later and by child processes) and calls ``*openblas_set_num_threads*`` of the
    libraries already loaded (Linux: found in /proc/self/maps). Returns the libraries changed."""
    os.environ["OPENBLAS_NUM_THREADS"] = str(int(threads))
    changed = []
    try:
        with open("/proc/self/maps") as maps:
            paths = {line.split()[-1] for line in maps if "openblas" in line.lower() and ".so" in line}
    except OSError:
        return changed
    for path in sorted(paths):
        try:
            lib = ctypes.CDLL(path)
        except OSError:
            continue
        for name in ("scipy_openblas_set_num_threads64_", "scipy_openblas_set_num_threads",
                     "openblas_set_num_threads64_", "openblas_set_num_threads"):
            setter = getattr(lib, name, None)
            if setter is not None:
                setter(int(threads))
                changed.append(path)
                break
    return changed
