"""`facesculpt setup`: conversion into a fresh directory from the pinned wheel, idempotence
without network, the one-sentence failure with no network and nothing there, hash checks,
and the face-mesh triangle list it writes."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from collections import Counter

import numpy as np
import pytest

from facesculpt.app.setup_models import (
    DOWNLOADS_DIR,
    MANIFEST_FILE,
    TRIANGLES_FILE,
    WHEEL_NAME,
    WHEEL_SHA256,
    SetupError,
    compile_package,
    manifest_is_valid,
    run_setup,
    sha256_file,
)

# pip pointed at a closed local port: any download attempt fails at once.
NO_NETWORK = {"PIP_INDEX_URL": "http://127.0.0.1:9/simple", "PIP_NO_CACHE_DIR": "1", "PIP_FIND_LINKS": "",
              "PIP_RETRIES": "0"}


@pytest.fixture(scope="module")
def wheel(models_dir):
    """The wheel `facesculpt setup` downloaded (so this test never downloads it again)."""
    path = models_dir / DOWNLOADS_DIR / WHEEL_NAME
    if not path.is_file():
        pytest.skip(f"{path} not present: `facesculpt setup` keeps the wheel there")
    return path


@pytest.fixture(scope="module")
def fresh_home(wheel, tmp_path_factory):
    home = tmp_path_factory.mktemp("models")
    run_setup(home, wheel=wheel)
    return home


def _cli(*args, env_extra=None, timeout=120):
    env = dict(os.environ, **(env_extra or {}))
    return subprocess.run([sys.executable, "-m", "facesculpt.cli", "setup", *args], env=env,
                          capture_output=True, text=True, timeout=timeout)


def test_setup_writes_networks_triangles_and_a_manifest_of_hashes(fresh_home):
    manifest = json.loads((fresh_home / MANIFEST_FILE).read_text())
    assert manifest["mediapipe_version"] == "0.10.14"
    assert manifest["wheel_sha256"] == WHEEL_SHA256
    expected = {f"{name}.{ext}" for name in ("face_detector", "face_landmark", "palm_detector", "hand_landmark",
                                            "person_segmentation", "iris_landmark")
                for ext in ("onnx", "tflite")} | {TRIANGLES_FILE}
    assert set(manifest["files"]) == expected
    for name, entry in manifest["files"].items():
        assert sha256_file(fresh_home / name) == entry["sha256"], name
    assert manifest_is_valid(fresh_home)
    # A damaged file invalidates the manifest.
    target = fresh_home / "face_landmark.onnx"
    data = target.read_bytes()
    target.write_bytes(data[:-1] + bytes([data[-1] ^ 1]))
    try:
        assert not manifest_is_valid(fresh_home)
    finally:
        target.write_bytes(data)
    assert manifest_is_valid(fresh_home)


def test_second_run_without_network_reuses_what_is_there(fresh_home):
    before = {p.name: p.stat().st_mtime_ns for p in fresh_home.iterdir() if p.is_file()}
    result = _cli("--home", str(fresh_home), env_extra=NO_NETWORK)
    assert result.returncode == 0, result.stderr
    assert "up to date" in result.stderr
    after = {p.name: p.stat().st_mtime_ns for p in fresh_home.iterdir() if p.is_file()}
    assert after == before


@pytest.mark.slow
def test_no_network_and_nothing_there_says_what_to_do_in_one_sentence(tmp_path):
    result = _cli("--home", str(tmp_path / "empty"), env_extra=NO_NETWORK)
    assert result.returncode == 1
    message = result.stderr.strip().splitlines()[-1]
    assert message.startswith("facesculpt setup: could not download mediapipe==0.10.14")
    assert "run `facesculpt setup` again" in message and "--wheel FILE" in message
    assert message.count(". ") == 0  # one sentence
    assert not (tmp_path / "empty" / MANIFEST_FILE).exists()


def test_a_wheel_with_the_wrong_hash_is_refused(tmp_path):
    fake = tmp_path / WHEEL_NAME
    fake.write_bytes(b"PK\x05\x06" + bytes(18))  # an empty zip: right name, wrong content
    with pytest.raises(SetupError, match="sha256"):
        run_setup(tmp_path / "home", wheel=fake)
    assert not (tmp_path / "home" / MANIFEST_FILE).exists()


def test_triangles_form_a_consistently_oriented_mesh_with_four_boundaries(fresh_home):
    tri = np.load(fresh_home / TRIANGLES_FILE)
    assert tri.dtype == np.int32 and tri.ndim == 2 and tri.shape[1] == 3
    assert len(tri) == 852 and tri.min() == 0 and tri.max() == 467
    assert len({tuple(sorted(t)) for t in tri.tolist()}) == len(tri)
    directed = Counter((int(t[i]), int(t[(i + 1) % 3])) for t in tri for i in range(3))
    assert max(directed.values()) == 1  # no edge walked twice the same way: consistent orientation
    boundary = {e for e in directed if e[::-1] not in directed}
    edges = {tuple(sorted(e)) for e in directed}
    # Euler characteristic V - E + F = 2 - (number of boundary loops): outer, two eyes, mouth.
    assert 468 - len(edges) + len(tri) == 2 - 4
    nxt = dict(boundary)
    loops, seen = [], set()
    for start in nxt:
        if start in seen:
            continue
        loop, v = [start], nxt[start]
        seen.add(start)
        while v != start:
            loop.append(v)
            seen.add(v)
            v = nxt[v]
        loops.append(loop)
    assert len(loops) == 4
    outer = max(loops, key=len)
    # Counter-clockwise on screen: forehead -> right cheek (image left) -> chin -> left cheek.
    start = outer.index(10)
    outer = outer[start:] + outer[:start]
    assert outer.index(234) < outer.index(152) < outer.index(454)


def test_stale_conversion_is_redone_offline_from_the_kept_wheel(wheel, tmp_path):
    home = tmp_path / "home"
    (home / DOWNLOADS_DIR).mkdir(parents=True)
    shutil.copyfile(wheel, home / DOWNLOADS_DIR / WHEEL_NAME)
    (home / MANIFEST_FILE).write_text(json.dumps({"format": 1, "converter_version": "0"}))
    result = _cli("--home", str(home), env_extra=NO_NETWORK)
    assert result.returncode == 0, result.stderr
    assert "using the downloaded wheel" in result.stderr
    assert manifest_is_valid(home)


def test_setup_leaves_every_module_of_the_package_compiled():
    """compile_package: every .py of the package has bytecode Python will read (its recorded
    source size and time match the file), so a node process starts without compiling its modules
    even where Python writes no bytecode itself (PYTHONDONTWRITEBYTECODE)."""
    import importlib.util
    from pathlib import Path

    import facesculpt

    assert compile_package()
    package = Path(facesculpt.__file__).resolve().parent
    sources = sorted(package.rglob("*.py"))
    assert len(sources) > 100
    for source in sources:
        pyc = Path(importlib.util.cache_from_source(str(source)))
        header = pyc.read_bytes()[:16]   # magic, flags, source mtime, source size (PEP 552)
        assert header[:4] == importlib.util.MAGIC_NUMBER, source
        assert int.from_bytes(header[8:12], "little") == int(source.stat().st_mtime) & 0xFFFFFFFF, source
        assert int.from_bytes(header[12:16], "little") == source.stat().st_size & 0xFFFFFFFF, source
