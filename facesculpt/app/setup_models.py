"""`facesculpt setup`: fetch the face, hand and person networks once and convert them to ONNX.

The networks are the face detector (short range), the 468-point face mesh, the palm detector
(full), the 21-point hand landmark network (full), the selfie (person) segmentation (general,
256x256) and the iris landmark network (5 iris points and 71 eye-contour points on a 64x64 eye
crop, given a free batch axis so both eyes run at once) that the ``mediapipe==0.10.14`` wheel on
PyPI ships as .tflite files (Apache-2.0). Setup downloads that
exact wheel with ``pip download --no-deps`` (fixed python version and platform, so any
interpreter fetches the same file), checks its sha256, extracts the networks and the mesh
tessellation (read as data), converts the networks with the project's own converter
(:mod:`facesculpt.nodes.landmarks.tflite_to_onnx`) and writes into the model directory
(:func:`facesculpt.paths.model_home`):

    face_detector.onnx, face_landmark.onnx    the converted face networks (run by onnxruntime)
    palm_detector.onnx, hand_landmark.onnx    the converted hand networks
    person_segmentation.onnx                   the converted person segmentation (the plate's mask)
    iris_landmark.onnx                         the converted iris network (irises and gaze)
    *.tflite (same names)                      the originals (reference for tests/benchmarks)
    facemesh_triangles.npy                     (T, 3) int32 triangles of the 468-point mesh
    manifest.json                              versions and the sha256 of every file
    downloads/<wheel>                          the wheel, so a re-run never needs the network
    calibration/sfm_shape_3448.npz             with --calibrate: the Surrey model's landmark calibration
                                               (when the shared data holds the model; `model calibrate`)

It is idempotent: when the manifest matches the files, nothing is downloaded or rewritten, and
the calibration is built only when it is not there. It also compiles the package's Python files
to bytecode beside them (:func:`compile_package`), so that a node process, each start and each
respawn, reads its modules compiled even where Python writes no bytecode itself
(``PYTHONDONTWRITEBYTECODE``, an install without it).
Nothing at run time downloads; the runtime only reads these files.
"""

from __future__ import annotations

import argparse
import hashlib
import io
import json
import logging
import os
import shutil
import subprocess
import sys
import tempfile
import time
import zipfile
from pathlib import Path

import numpy as np

from facesculpt.paths import model_home

log = logging.getLogger("facesculpt.setup")

MEDIAPIPE_VERSION = "0.10.14"
WHEEL_NAME = "mediapipe-0.10.14-cp311-cp311-manylinux_2_17_x86_64.manylinux2014_x86_64.whl"
WHEEL_SHA256 = "a807328339e7356fda0bb14df12fedbf1d33bdf81649c5f8666b0026b1cc30b4"
PIP_DOWNLOAD_ARGS = [
    "download", "--no-deps", "--only-binary=:all:", "--python-version", "3.11",
    "--platform", "manylinux_2_17_x86_64", f"mediapipe=={MEDIAPIPE_VERSION}",
    "--disable-pip-version-check", "--no-input", "--timeout", "30", "--retries", "2",
]
# Network name -> member of the wheel.
NETWORKS = {
    "face_detector": "mediapipe/modules/face_detection/face_detection_short_range.tflite",
    "face_landmark": "mediapipe/modules/face_landmark/face_landmark.tflite",
    "palm_detector": "mediapipe/modules/palm_detection/palm_detection_full.tflite",
    "hand_landmark": "mediapipe/modules/hand_landmark/hand_landmark_full.tflite",
    "person_segmentation": "mediapipe/modules/selfie_segmentation/selfie_segmentation.tflite",
    "iris_landmark": "mediapipe/modules/iris_landmark/iris_landmark.tflite",
}
CONNECTIONS_MEMBER = "mediapipe/python/solutions/face_mesh_connections.py"
TRIANGLES_FILE = "facemesh_triangles.npy"
MANIFEST_FILE = "manifest.json"
DOWNLOADS_DIR = "downloads"
MANIFEST_FORMAT = 1


class SetupError(RuntimeError):
    """Setup cannot proceed; the message is one sentence saying what to do."""


def sha256_file(path: Path) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def _converter_version() -> str:
    from facesculpt.nodes.landmarks.tflite_to_onnx import CONVERTER_VERSION

    return CONVERTER_VERSION


def manifest_is_valid(home: Path) -> bool:
    """True when ``home/manifest.json`` exists, names this mediapipe wheel and converter version,
    and every file it lists is there with the recorded sha256."""
    try:
        manifest = json.loads((home / MANIFEST_FILE).read_text())
        if (manifest.get("format") != MANIFEST_FORMAT
                or manifest.get("mediapipe_version") != MEDIAPIPE_VERSION
                or manifest.get("wheel_sha256") != WHEEL_SHA256
                or manifest.get("converter_version") != _converter_version()):
            return False
        files = manifest["files"]
        needed = {f"{n}.onnx" for n in NETWORKS} | {TRIANGLES_FILE}
        if not needed <= set(files):
            return False
        return all(sha256_file(home / name) == entry["sha256"] for name, entry in files.items())
    except (OSError, ValueError, KeyError, TypeError):
        return False


def _check_wheel(path: Path) -> None:
    if not path.is_file():
        raise SetupError(f"the wheel {path} does not exist")
    digest = sha256_file(path)
    if digest != WHEEL_SHA256:
        raise SetupError(
            f"{path} has sha256 {digest}, not the pinned {WHEEL_SHA256} of {WHEEL_NAME}: "
            f"delete it and run `facesculpt setup` again")


def _pip_command() -> list[str]:
    probe = subprocess.run([sys.executable, "-m", "pip", "--version"], capture_output=True, text=True)
    if probe.returncode == 0:
        return [sys.executable, "-m", "pip"]
    pip = shutil.which("pip") or shutil.which("pip3")
    if pip:
        return [pip]
    raise SetupError("pip is not available to download the mediapipe wheel: install pip, or download "
                     f"{WHEEL_NAME} elsewhere and run `facesculpt setup --wheel FILE`")


def download_wheel(dest_dir: Path) -> Path:
    """Download the pinned wheel into ``dest_dir`` with pip; returns its path (hash-checked)."""
    dest_dir.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(dir=dest_dir) as tmp:
        cmd = _pip_command() + PIP_DOWNLOAD_ARGS + ["-d", tmp]
        log.info("downloading mediapipe==%s (35.7 MB) with pip", MEDIAPIPE_VERSION)
        try:
            result = subprocess.run(cmd, capture_output=True, text=True, timeout=900)
        except subprocess.TimeoutExpired:
            result = None
        got = Path(tmp) / WHEEL_NAME
        if result is None or result.returncode != 0 or not got.is_file():
            detail = (result.stderr.strip().splitlines() or ["timed out"])[-1] if result else "timed out"
            log.info("pip download failed: %s", detail)
            raise SetupError(
                f"could not download mediapipe=={MEDIAPIPE_VERSION} from PyPI and no converted networks "
                f"are in {dest_dir.parent}: connect to the internet and run `facesculpt setup` again, or "
                f"fetch {WHEEL_NAME} on another machine and run `facesculpt setup --wheel FILE`")
        _check_wheel(got)
        final = dest_dir / WHEEL_NAME
        os.replace(got, final)
    return final


def _write_atomic(path: Path, data: bytes) -> None:
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_bytes(data)
    os.replace(tmp, path)


def _npy_bytes(array: np.ndarray) -> bytes:
    buf = io.BytesIO()
    np.save(buf, array, allow_pickle=False)
    return buf.getvalue()


def _verify_onnx(data: bytes, name: str) -> None:
    """Load the converted network in onnxruntime and run it once on zeros."""
    import onnxruntime as ort

    options = ort.SessionOptions()
    options.intra_op_num_threads = 1
    session = ort.InferenceSession(data, options, providers=["CPUExecutionProvider"])
    feeds = {i.name: np.zeros([d if isinstance(d, int) else 1 for d in i.shape], np.float32)
             for i in session.get_inputs()}
    outputs = session.run(None, feeds)
    if not all(np.isfinite(o).all() for o in outputs):
        raise SetupError(f"the converted {name} network gives non-finite outputs: please report this")


def run_setup(home: Path | None = None, wheel: Path | None = None, force: bool = False) -> dict:
    """Fill ``home`` (default :func:`model_home`) with the converted networks; returns the manifest.

    ``wheel``: use this already-downloaded wheel (still hash-checked) instead of pip.
    Raises :class:`SetupError` with one sentence saying what to do when it cannot proceed.
    """
    from facesculpt.nodes.landmarks.tessellation import parse_connections, triangles_from_edges
    from facesculpt.nodes.landmarks.tflite_to_onnx import convert_tflite

    home = Path(home) if home is not None else model_home()
    if not force and manifest_is_valid(home):
        log.info("%s is up to date (mediapipe %s, converter %s)", home, MEDIAPIPE_VERSION, _converter_version())
        return json.loads((home / MANIFEST_FILE).read_text())
    try:
        home.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise SetupError(f"cannot create the model directory {home} ({exc.strerror}): "
                         f"choose another with --home or FACESCULPT_HOME") from exc

    if wheel is not None:
        wheel_path = Path(wheel).expanduser()
        _check_wheel(wheel_path)
        source = str(wheel_path)
    else:
        cached = home / DOWNLOADS_DIR / WHEEL_NAME
        if cached.is_file() and sha256_file(cached) == WHEEL_SHA256:
            log.info("using the downloaded wheel %s", cached)
            wheel_path = cached
        else:
            wheel_path = download_wheel(home / DOWNLOADS_DIR)
        source = f"https://pypi.org/project/mediapipe/{MEDIAPIPE_VERSION}/"

    try:
        with zipfile.ZipFile(wheel_path) as zf:
            members = {name: zf.read(member) for name, member in NETWORKS.items()}
            connections = zf.read(CONNECTIONS_MEMBER).decode("utf-8")
    except (zipfile.BadZipFile, KeyError) as exc:
        raise SetupError(f"{wheel_path} is not the expected mediapipe wheel ({exc})") from exc

    outputs: dict[str, tuple[bytes, str]] = {}
    for name, tflite in members.items():
        t0 = time.perf_counter()
        model = convert_tflite(tflite, name=name)
        if name == "iris_landmark":  # both eyes in one run
            from facesculpt.nodes.landmarks.irises import free_batch_axis

            free_batch_axis(model)
        data = model.SerializeToString()
        _verify_onnx(data, name)
        log.info("converted %s: %d ONNX nodes (%.1f s)", NETWORKS[name].rsplit("/", 1)[-1],
                 len(model.graph.node), time.perf_counter() - t0)
        outputs[f"{name}.onnx"] = (data, f"converted from {NETWORKS[name]}")
        outputs[f"{name}.tflite"] = (tflite, NETWORKS[name])
    edges = parse_connections(connections).get("FACEMESH_TESSELATION")
    if not edges:
        raise SetupError(f"{CONNECTIONS_MEMBER} in {wheel_path} has no FACEMESH_TESSELATION edge list")
    triangles = triangles_from_edges(edges)
    log.info("face mesh: %d triangles from %d tessellation edges", len(triangles), len(edges))
    outputs[TRIANGLES_FILE] = (_npy_bytes(triangles), f"triangles of FACEMESH_TESSELATION in {CONNECTIONS_MEMBER}")

    (home / MANIFEST_FILE).unlink(missing_ok=True)  # invalid until every file is written
    files = {}
    for name, (data, origin) in outputs.items():
        _write_atomic(home / name, data)
        files[name] = {"sha256": hashlib.sha256(data).hexdigest(), "bytes": len(data), "source": origin}
    manifest = {
        "format": MANIFEST_FORMAT,
        "mediapipe_version": MEDIAPIPE_VERSION,
        "wheel": WHEEL_NAME,
        "wheel_sha256": WHEEL_SHA256,
        "wheel_source": source,
        "converter_version": _converter_version(),
        "created": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
        "files": files,
    }
    _write_atomic(home / MANIFEST_FILE, json.dumps(manifest, indent=2).encode())
    log.info("wrote %d files to %s", len(files) + 1, home)
    return manifest


def sfm_calibration(home: Path, force: bool = False) -> Path | None:
    """Build the Surrey model's landmark calibration into ``home``/calibration/ (where
    ``load_model("sfm")`` reads it; :mod:`facesculpt.app.landmark_calibration`, about a minute of
    CPU) when the shared data folder that holds the model is there and the file is not (or
    ``force``). Returns the file, or None when there is no shared data."""
    from facesculpt.paths import shared_data_dir

    data = shared_data_dir()
    if data is None or not (data / "sfm" / "sfm_shape_3448.bin").is_file():
        log.info("no shared data folder with the Surrey model: its landmark calibration is not built "
                 "(`facesculpt model calibrate` builds it later)")
        return None
    path = home / "calibration" / "sfm_shape_3448.npz"
    if path.is_file() and not force:
        return path
    from facesculpt.app.landmark_calibration import build_sfm_calibration

    start = time.perf_counter()
    log.info("building the Surrey model's landmark calibration (renders of its own; about a minute of CPU)")
    build_sfm_calibration(data, path)
    log.info("wrote %s (%.0f s)", path, time.perf_counter() - start)
    return path


def compile_package() -> bool:
    """Compile the facesculpt package's .py files to bytecode in their ``__pycache__`` folders
    (:mod:`compileall`: files whose bytecode is up to date are skipped). Python reads bytecode
    whose recorded source time and size match the file, so an edited file is compiled again at
    its import, as without this. False, with a log line, where it could not write (a read-only
    install): nothing else changes."""
    import compileall

    import facesculpt

    package = Path(facesculpt.__file__).resolve().parent
    done = compileall.compile_dir(str(package), quiet=2, workers=1)
    if not done:
        log.info("the bytecode of %s was not (all) written: node processes compile their modules at each start",
                 package)
    return bool(done)


def _main(args: argparse.Namespace) -> int:
    compile_package()
    try:
        run_setup(args.home, args.wheel, args.force)
    except SetupError as exc:
        print(f"facesculpt setup: {exc}", file=sys.stderr)
        return 1
    # only where load_model("sfm") reads it: the models folder of this environment
    if args.calibrate and (args.home is None or args.home.expanduser().resolve() == model_home().resolve()):
        try:
            sfm_calibration(model_home(), args.force)
        except (RuntimeError, ValueError, OSError) as exc:
            print(f"facesculpt setup: the Surrey model's landmark calibration was not built: {exc}", file=sys.stderr)
            return 1
    return 0


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "setup", help="download and convert the face and hand networks (run once)",
        description="Download the pinned mediapipe wheel, convert its face and hand networks to ONNX and write "
                    "them with the face-mesh triangles into the model directory; with --calibrate, where the shared data "
                    "folder holds the Surrey model, build its landmark calibration there too. Also compiles the "
                    "package's Python files to bytecode, so node processes start without compiling them.")
    p.add_argument("--home", type=Path, default=None,
                   help="model directory (default: $FACESCULPT_HOME or ~/.cache/facesculpt)")
    p.add_argument("--wheel", type=Path, default=None,
                   help=f"use this already-downloaded {WHEEL_NAME} (hash-checked) instead of pip")
    p.add_argument("--force", action="store_true", help="convert again even when the directory is up to date")
    p.add_argument("--calibrate", action="store_true",
                   help="also build the Surrey model's landmark calibration into the models folder that load_model "
                   "reads, where the shared data folder holds the model (`facesculpt model calibrate`; about a minute "
                   "of CPU; not by default: it did not win on real faces, docs/results/registration.md)")
    p.set_defaults(func=_main)
