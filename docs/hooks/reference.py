"""MkDocs hooks (mkdocs.yml ``hooks:``).

* The node parameter and command-line reference pages are generated from the code at every
  build (facesculpt/app/reference_docs.py), so they cannot drift from it.
* The API pages' docstrings are read from the source by mkdocstrings (griffe), which finds
  ``facesculpt.nodes.X`` in the folder ``facesculpt/nodes/X``: the folder path is the import path.
"""

from __future__ import annotations

import re
from pathlib import Path

from mkdocs.structure.files import File

from facesculpt.app.reference_docs import cli_markdown, node_params_markdown
from facesculpt.cli import build_parser
from facesculpt.nodes import BUILTIN_NODES

REPO = Path(__file__).resolve().parents[2]
# The docstrings cross-reference with Sphinx roles (:class:`Name`), which mkdocstrings shows
# as written; the API pages keep the name in code and drop the role.
SPHINX_ROLE = re.compile(r":(?:class|func|meth|mod|data|attr|exc|obj):(?=<code>)")

GENERATED = {
    "graph/nodes.md": lambda: node_params_markdown(BUILTIN_NODES),
    "reference/cli.md": lambda: cli_markdown(build_parser()),
}


def on_files(files, config):
    for src_uri, render in GENERATED.items():
        files.append(File.generated(config, src_uri, content=render()))
    return files


def on_page_content(html, page, config, files):
    return SPHINX_ROLE.sub("", html) if page.file.src_uri.startswith("api/") else html
