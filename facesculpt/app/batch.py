"""`facesculpt process` on many videos: files, folders and globs in, one output per input in a folder.

    facesculpt process videos/ more/*.mov -o edited/ --edits chin
    facesculpt process videos/ -o edited/ --cluster tcp://scheduler:8786

Jobs run in parallel on Dask distributed workers: a local cluster with one single-threaded
worker process per core by default (``--workers N``), or an existing cluster (``--cluster
ADDRESS``). Dask rather than Ray: it is pure Python from PyPI, starts a local cluster in about a
second, and its scheduler needs nothing but a TCP port. Each worker keeps the face networks
loaded (:func:`_detector`, one per worker process) and runs the single-file command's own code
(:func:`facesculpt.app.process.process_file`), so every output is the single-file command's,
byte for byte. A failing input is reported and the others go on; an output that already exists
is complete (videos are renamed into place only when finished), so a rerun skips it and resumes.
"""

from __future__ import annotations

import copy
import glob
import os
import sys
from pathlib import Path

VIDEO_SUFFIXES = (".mp4", ".mov", ".m4v", ".mkv", ".avi", ".webm")

# One landmark detector per worker process (its networks loaded once, not per video).
_DETECTORS: dict = {}


def is_batch(args) -> bool:
    """Several inputs, a folder (not an RGB-D recording) or glob among them, -o naming a folder, or batch
    options given."""
    if len(args.input) > 1 or args.cluster or args.workers:
        return True
    only = args.input[0]
    from facesculpt.app.rgbd_process import is_rgbd_input

    if is_rgbd_input(only):  # a folder of colour + depth images is one recording
        return args.output.endswith(os.sep) or Path(args.output).is_dir()
    return Path(only).is_dir() or glob.has_magic(only) or args.output.endswith(os.sep) or Path(args.output).is_dir()


def expand_inputs(specs: list[str]) -> list[Path]:
    """Files as given, folders as the videos directly in them (sorted), globs expanded (sorted);
    ValueError in one sentence when a spec names nothing."""
    out: list[Path] = []
    for spec in specs:
        p = Path(spec)
        if glob.has_magic(spec):
            found = sorted(Path(f) for f in glob.glob(spec) if Path(f).is_file())
        elif p.is_dir():
            found = sorted(f for f in p.iterdir() if f.is_file() and f.suffix.lower() in VIDEO_SUFFIXES)
        elif p.exists():
            found = [p]
        else:
            raise FileNotFoundError(f"cannot read {spec}: no such file, folder or matching glob")
        if not found:
            raise ValueError(f"{spec} holds no video ({', '.join(VIDEO_SUFFIXES)})")
        out += [f for f in found if f not in out]
    return out


def plan_jobs(inputs: list[Path], out_dir: Path, suffix: str) -> list[tuple[Path, Path]]:
    """(input, output) pairs: each output named after its input's stem with ``suffix`` in
    ``out_dir``; ValueError when two inputs would write the same output."""
    if not suffix.startswith("."):
        suffix = "." + suffix
    jobs, seen = [], {}
    for inp in inputs:
        out = out_dir / (inp.stem + suffix)
        if out in seen:
            raise ValueError(f"{seen[out]} and {inp} would both be written to {out}: rename one")
        seen[out] = inp
        jobs.append((inp, out))
    return jobs


def _detector(threads: int):
    """This worker's landmark detector (networks loaded on first use)."""
    from facesculpt.nodes.landmarks import LandmarkDetector

    if threads not in _DETECTORS:
        _DETECTORS[threads] = LandmarkDetector(threads=threads)
    return _DETECTORS[threads]


def run_job(options, input_path: str, output_path: str) -> tuple[str, int, str]:
    """One video on a worker: (input, exit status, the line that says what happened). With
    ``--export-params`` (its suffix), the parameters go beside the video: ``OUT.csv`` / ``OUT.json``."""
    from facesculpt.app.process import process_file
    from facesculpt.runtime.process_limits import limit_threads

    limit_threads(1)
    if options.export_params:
        options = copy.copy(options)
        options.export_params = str(Path(output_path).with_suffix(Path(options.export_params).suffix))
    try:
        code, message = process_file(options, input_path, output_path, detector=_detector(options.threads))
    except Exception as exc:  # reported for this input; the other jobs go on
        return input_path, 1, f"{type(exc).__name__}: {exc}" if not str(exc) else str(exc)
    return input_path, code, message


def _client(args):
    import logging

    from dask.distributed import Client, LocalCluster

    logging.getLogger("distributed").setLevel(logging.WARNING)  # the engine's own chatter
    if args.cluster:
        return Client(args.cluster, timeout=30), None
    workers = args.workers or os.cpu_count() or 1
    cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=":0",
                           silence_logs=40)
    return Client(cluster), cluster


def run_batch(args, inputs: list[Path]) -> int:
    """Every input through :func:`run_job` on the cluster; one progress bar over the jobs, a line
    per job; exit status 1 naming the inputs that failed."""
    from dask.distributed import as_completed
    from tqdm import tqdm

    from facesculpt.app.safe_output import refuse_output_over_input

    out_dir = Path(args.output)
    if "%" in args.output:
        raise ValueError("a batch writes one video per input into a folder: -o must name a folder, not a pattern")
    if out_dir.exists() and not out_dir.is_dir():
        raise ValueError(f"-o {out_dir} is a file: a batch writes one video per input into a folder")
    jobs = plan_jobs(inputs, out_dir, args.suffix)
    for inp, out in jobs:
        refuse_output_over_input(str(inp), str(out))
    todo = [(i, o) for i, o in jobs if args.overwrite or not o.exists()]
    for inp, out in jobs:
        if (inp, out) not in todo:
            print(f"skipped {inp}: {out} is already complete (--overwrite to redo it)", file=sys.stderr)
    if not todo:
        print(f"nothing to do: all {len(jobs)} outputs in {out_dir} are complete", file=sys.stderr)
        return 0
    out_dir.mkdir(parents=True, exist_ok=True)
    options = copy.copy(args)
    options.quiet, options.func = True, None
    options.read_ahead = False  # one worker per core: no second thread each
    failed = []
    client, cluster = _client(args)
    try:
        futures = [client.submit(run_job, options, str(i), str(o), pure=False) for i, o in todo]
        with tqdm(total=len(todo), desc="videos", unit="video", file=sys.stderr, disable=args.quiet) as bar:
            for future in as_completed(futures):
                inp, code, message = future.result()
                if code != 0:
                    failed.append(inp)
                bar.write(f"{'FAILED ' if code else ''}{inp}: {message}", file=sys.stderr)
                bar.set_postfix(failed=len(failed))
                bar.update(1)
    finally:
        client.close()
        if cluster is not None:
            cluster.close()
    done = len(todo) - len(failed)
    if failed:
        print(f"{done} of {len(todo)} videos written to {out_dir}; failed: {', '.join(failed)}", file=sys.stderr)
        return 1
    print(f"{done} videos written to {out_dir}", file=sys.stderr)
    return 0
