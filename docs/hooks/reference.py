"""MkDocs hooks (mkdocs.yml ``hooks:``).

* The node parameter and command-line reference pages are generated from the code at every
  build (facesculpt/app/reference_docs.py), so they cannot drift from it.
* The API pages' docstrings are read from the source by mkdocstrings (griffe), which looks up
  ``facesculpt.nodes.X`` as the folder ``facesculpt/nodes/X``; this repository installs
  ``nodes/``, ``msgs/`` and ``launch/`` under ``facesculpt`` (pyproject.toml's package-dir), so
  the build shows griffe a tree of links with the installed layout, in build/docs-api.
"""

from __future__ import annotations

import re
import shutil
from pathlib import Path

from mkdocs.structure.files import File

from facesculpt.app.reference_docs import cli_markdown, node_params_markdown
from facesculpt.cli import build_parser
from facesculpt.nodes import BUILTIN_NODES

REPO = Path(__file__).resolve().parents[2]
# Repository folder -> where it sits in the installed package (pyproject.toml [tool.setuptools]).
INSTALLED_AS = {"msgs": "msgs", "nodes": "nodes", "launch": "launch"}
# mkdocs.yml's mkdocstrings `paths` names this folder (build/ is ignored by git).
API_TREE = REPO / "build" / "docs-api"

# The docstrings cross-reference with Sphinx roles (:class:`Name`), which mkdocstrings shows
# as written; the API pages keep the name in code and drop the role.
SPHINX_ROLE = re.compile(r":(?:class|func|meth|mod|data|attr|exc|obj):(?=<code>)")

GENERATED = {
    "graph/nodes.md": lambda: node_params_markdown(BUILTIN_NODES),
    "reference/cli.md": lambda: cli_markdown(build_parser()),
}


def package_tree(root: Path) -> Path:
    """``root/facesculpt/`` made (again) as it is installed: links to each entry of the
    repository's ``facesculpt/`` and to the folders installed beneath it. Returns ``root``."""
    package = root / "facesculpt"
    shutil.rmtree(root, ignore_errors=True)
    package.mkdir(parents=True)
    source = REPO / "src" / "facesculpt" if (REPO / "src" / "facesculpt").is_dir() else REPO / "facesculpt"
    for entry in source.iterdir():
        (package / entry.name).symlink_to(entry)
    for folder, name in INSTALLED_AS.items():
        if (REPO / folder).is_dir() and not (package / name).exists():
            (package / name).symlink_to(REPO / folder)
    return root


# Made when MkDocs loads this hook, before mkdocstrings reads its `paths` (mkdocs.yml).
package_tree(API_TREE)


def on_files(files, config):
    for src_uri, render in GENERATED.items():
        files.append(File.generated(config, src_uri, content=render()))
    return files


def on_page_content(html, page, config, files):
    return SPHINX_ROLE.sub("", html) if page.file.src_uri.startswith("api/") else html
