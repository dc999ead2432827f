"""Where things live on disk: the model directory, the per-run socket directory,
the shared test data, and files shipped inside the package."""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

PACKAGE_ROOT = Path(__file__).resolve().parent


class MissingModelsError(FileNotFoundError):
    """Raised when the model files made by `facesculpt setup` are not there."""


def model_home() -> Path:
    """Directory that `facesculpt setup` fills: ``$FACESCULPT_HOME``, else the user's cache dir."""
    env = os.environ.get("FACESCULPT_HOME")
    if env:
        return Path(env).expanduser()
    xdg = os.environ.get("XDG_CACHE_HOME")
    base = Path(xdg).expanduser() if xdg else Path.home() / ".cache"
    return base / "facesculpt"


def model_file(name: str) -> Path:
    """Path of one file made by `facesculpt setup`; raises :class:`MissingModelsError`
    naming the file and the command that makes it when it is absent."""
    path = model_home() / name
    if not path.is_file():
        raise MissingModelsError(
            f"{path} is missing: run `facesculpt setup` to fetch and convert the face networks "
            f"(or set FACESCULPT_HOME to the directory where it put them)"
        )
    return path


def run_dir() -> Path:
    """Directory for this user's ipc:// sockets (short, so socket paths stay under 107 bytes)."""
    env = os.environ.get("FACESCULPT_RUN_DIR")
    path = Path(env) if env else Path(tempfile.gettempdir()) / f"facesculpt-{os.getuid()}"
    path.mkdir(parents=True, exist_ok=True, mode=0o700)
    return path


def shared_data_dir() -> Path | None:
    """The shared test/benchmark data (``$FACESCULPT_DATA``, else ``../shared/data`` beside
    the repository), or None when it is absent, as on a user's fresh machine."""
    env = os.environ.get("FACESCULPT_DATA")
    candidates = [Path(env)] if env else []
    repo_root = PACKAGE_ROOT.parent
    candidates.append(repo_root.parent / "shared" / "data")
    candidates.append(Path.cwd().parent / "shared" / "data")
    for path in candidates:
        if path.is_dir():
            return path.resolve()
    return None


def _shipped_file(name_or_path: str, folder: Path, suffix: str, what: str) -> Path:
    """A file given as a path, or as the name (with or without ``suffix``) of one shipped in ``folder``."""
    path = Path(name_or_path)
    if path.is_file():
        return path
    for candidate in (folder / name_or_path, folder / f"{name_or_path}{suffix}"):
        if candidate.is_file():
            return candidate
    known = ", ".join(sorted(p.stem for p in folder.glob(f"*{suffix}"))) or "none"
    raise FileNotFoundError(f"{what} {name_or_path!r} not found (shipped: {known})")


def launch_file(name_or_path: str) -> Path:
    """Resolve a launch file given as a path, or as the name of one shipped in facesculpt/launch/."""
    from facesculpt import launch as launch_pkg

    return _shipped_file(name_or_path, Path(launch_pkg.__file__).parent, ".yaml", "launch file")


def shipped_launch_files() -> list[Path]:
    """The launch files shipped in facesculpt/launch/ (those with a top-level ``nodes:`` list; a gesture
    script such as demo_gestures.yaml is not one), sorted by name."""
    from facesculpt import launch as launch_pkg

    folder = Path(launch_pkg.__file__).parent
    return sorted(p for p in folder.glob("*.yaml") if "\nnodes:" in "\n" + p.read_text())


def preset_file(name_or_path: str) -> Path:
    """Resolve a deformer preset given as a path, or as the name of one shipped with the deformer
    (``nose_longer``, ``chin``, ``cheeks``: the paper's Fig. 6e edits)."""
    import importlib.util

    # Found on disk, not imported: paths sits below every layer and imports no node.
    spec = importlib.util.find_spec("facesculpt.nodes.deformer")
    folder = Path(list(spec.submodule_search_locations)[0]) / "presets"
    return _shipped_file(name_or_path, folder, ".json", "preset")


def embedded_face_image() -> Path:
    """A real face photo shipped by an installed package, the main job's default input:
    scikit-image's ``astronaut.png`` (Eileen Collins, NASA, public domain). Found on disk
    without importing scikit-image."""
    import importlib.util

    spec = importlib.util.find_spec("skimage")
    if spec is None or not spec.submodule_search_locations:
        raise FileNotFoundError("scikit-image is not installed; it ships the demo's face photo "
                                "(pip install scikit-image, or reinstall facesculpt)")
    path = Path(list(spec.submodule_search_locations)[0]) / "data" / "astronaut.png"
    if not path.is_file():
        raise FileNotFoundError(f"{path} is missing from the scikit-image installation")
    return path
