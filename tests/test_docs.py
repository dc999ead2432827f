"""The README and the documentation site: the README stays short and starts with the two
commands CI runs; the generated reference pages list every node parameter and every command
(facesculpt/app/reference_docs.py); every page the README links to exists; and, where MkDocs is
installed (the docs extra), the site builds strictly (no broken link, no missing page)."""

from __future__ import annotations

import importlib.util
import re
import subprocess
import sys
from pathlib import Path

import pytest

from facesculpt.app.docs_command import find_mkdocs_config
from facesculpt.app.reference_docs import cli_markdown, node_params_markdown
from facesculpt.cli import build_parser
from facesculpt.nodes import BUILTIN_NODES
from facesculpt.runtime.node import load_node_class
from facesculpt.runtime.parameters import declared

REPO = Path(__file__).resolve().parent.parent
README = REPO / "README.md"
INSTALL_AND_DEMO = ("python3 -m venv .venv && . .venv/bin/activate && pip install -e . && facesculpt setup "
                    "&& facesculpt demo")
TEST_COMMAND = '. .venv/bin/activate && pip install -q -e ".[test]" && python -m pytest -q -p no:cacheprovider'


def _code_blocks(text: str) -> list[str]:
    return [block.strip() for block in re.findall(r"```[a-z]*\n(.*?)```", text, flags=re.S)]


def test_the_readme_is_short_and_starts_with_the_two_commands():
    text = README.read_text()
    assert len(text.splitlines()) <= 250
    assert _code_blocks(text)[:2] == [INSTALL_AND_DEMO, TEST_COMMAND]


def test_ci_runs_the_readmes_test_command_verbatim_and_builds_the_site_strictly():
    ci = (REPO / ".ci" / "run").read_text().splitlines()
    assert ci[-1] == _code_blocks(README.read_text())[1]
    assert any(line.strip().startswith("NO_MKDOCS_2_WARNING=1 mkdocs build --strict") for line in ci)


def test_every_page_the_readme_links_to_exists():
    links = re.findall(r"\]\(([^)#\s]+)", README.read_text())
    local = [link for link in links if not re.match(r"[a-z]+://", link)]
    assert any(link.startswith("docs/") for link in local)
    missing = [link for link in local if not (REPO / link).exists()]
    assert not missing, missing


def test_every_docs_page_the_code_names_exists():
    """Help texts and docstrings point at documentation pages by path (docs/guide/new-views.md)."""
    named = {(path.relative_to(REPO), page) for folder in ("facesculpt", "examples", "benchmarks")
             for path in (REPO / folder).rglob("*.py")
             for page in re.findall(r"docs/[\w/.-]+?\.md", path.read_text())}
    assert named
    missing = sorted((str(path), page) for path, page in named if not (REPO / page).is_file())
    assert not missing, missing


def test_the_node_reference_lists_every_parameter_of_every_built_in_node():
    page = node_params_markdown(BUILTIN_NODES)
    for short_name, target in BUILTIN_NODES.items():
        section = page.split(f"## `{short_name}`\n", 1)[1].split("\n## ", 1)[0]
        for name, param in declared(load_node_class(target).PARAMS).items():
            row = next((line for line in section.splitlines() if line.startswith(f"| `{name}` |")), None)
            assert row is not None, f"{short_name}.{name} missing"
            assert repr(param.default).replace("|", "\\|") in row
            if param.range is not None:
                assert param.range_text() in row


def test_the_cli_reference_has_every_command_and_every_option():
    page = cli_markdown(build_parser())
    for command in ("facesculpt process", "facesculpt bag record", "facesculpt topic echo", "facesculpt docs",
                    "facesculpt keys generate", "facesculpt model import-eos"):
        assert f"`{command}`" in page, command
    process = page.split("## `facesculpt process`", 1)[1].split("\n## ", 1)[0]
    for option in ("--edits", "--inpaint", "--refine", "--pose", "--face-camera", "--export-params", "--cluster"):
        assert f"`{option}" in process, option


def test_docs_finds_the_checkouts_mkdocs_yml():
    assert find_mkdocs_config() == REPO / "mkdocs.yml"
    with pytest.raises(FileNotFoundError, match="mkdocs.yml"):
        find_mkdocs_config(Path("/usr/lib/python3/facesculpt/__init__.py"))


@pytest.mark.slow
@pytest.mark.skipif(importlib.util.find_spec("mkdocs") is None, reason="MkDocs not installed (the docs extra)")
def test_the_site_builds_strictly_with_the_generated_pages(tmp_path):
    result = subprocess.run([sys.executable, "-m", "facesculpt.cli", "docs", "--build", str(tmp_path)],
                            capture_output=True, text=True, timeout=280)
    assert result.returncode == 0, result.stderr[-3000:]
    nodes = (tmp_path / "graph" / "nodes" / "index.html").read_text()
    assert "pace_in_flight" in nodes and "rotation_prior_px" in nodes
    assert "FitterConfig" in (tmp_path / "api" / "fitter" / "index.html").read_text()


def _python_blocks(text: str) -> list[str]:
    return [block for block in re.findall(r"```python\n(.*?)```", text, flags=re.S)]


@pytest.mark.parametrize("page", ["README.md", "docs/guide/library.md"])
def test_the_library_example_runs_on_a_real_photo(page, models_dir, tmp_path):
    """The first Python example of the page, run as written on the embedded photo saved as face.jpg."""
    import cv2
    import skimage.data

    cv2.imwrite(str(tmp_path / "face.jpg"), cv2.cvtColor(skimage.data.astronaut(), cv2.COLOR_RGB2BGR))
    code = _python_blocks((REPO / page).read_text())[0]
    check = "\nassert fit.vertices.shape == (468, 3) and fit.projected.shape == (468, 2) and face.score > 0.5\n"
    result = subprocess.run([sys.executable, "-c", code + check], cwd=tmp_path, capture_output=True, text=True,
                            timeout=120)
    assert result.returncode == 0, result.stderr[-3000:]
