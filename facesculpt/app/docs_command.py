"""`facesculpt docs`: serve the documentation site (mkdocs.yml, docs/) locally, or build it.

The site's sources live in the repository checkout beside the package (an editable install,
``pip install -e ".[docs]"``); MkDocs with the Material theme and mkdocstrings come with the
``docs`` extra.
"""

from __future__ import annotations

import importlib.util
import os
import subprocess
import sys
from pathlib import Path

import facesculpt


def find_mkdocs_config(start: Path | None = None) -> Path:
    """The ``mkdocs.yml`` of the checkout the package was installed from: looked for in the
    package folder's parent and grandparent (``facesculpt/`` or ``src/facesculpt/``)."""
    package = (start or Path(facesculpt.__file__)).resolve().parent
    for folder in (package.parent, package.parent.parent):
        if (folder / "mkdocs.yml").is_file():
            return folder / "mkdocs.yml"
    raise FileNotFoundError(f"no mkdocs.yml beside {package}: the documentation sources come with the "
                            "repository checkout (pip install -e \".[docs]\" from it)")


def register(sub) -> None:
    p = sub.add_parser("docs", help="serve the documentation site locally (or --build it into a folder)",
                       description=__doc__.split("\n\n")[0])
    p.add_argument("--port", type=int, default=8000, help="port on 127.0.0.1 to serve on (default 8000)")
    p.add_argument("--build", metavar="DIR", help="build the site into DIR (strict: a broken link fails) "
                                                  "instead of serving it")
    p.set_defaults(func=cmd_docs)


def cmd_docs(args) -> int:
    if importlib.util.find_spec("mkdocs") is None:
        raise RuntimeError("MkDocs is not installed: pip install -e \".[docs]\" adds it")
    config = find_mkdocs_config()
    env = dict(os.environ, NO_MKDOCS_2_WARNING="1")  # Material's banner about its successor
    if args.build:
        command = ["build", "--strict", "-f", str(config), "-d", str(Path(args.build).resolve())]
        return subprocess.call([sys.executable, "-m", "mkdocs", *command], cwd=config.parent, env=env)
    if not 0 < args.port < 65536:
        raise ValueError(f"--port {args.port} is not a port (1-65535)")
    print(f"serving the documentation on http://127.0.0.1:{args.port} (Ctrl-C stops)", flush=True)
    # The server replaces this process, so stopping `facesculpt docs` stops the server.
    os.chdir(config.parent)
    os.execve(sys.executable, [sys.executable, "-m", "mkdocs", "serve", "-f", str(config),
                               "-a", f"127.0.0.1:{args.port}"], env)
