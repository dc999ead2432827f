"""docs/architecture.md is the design in the repository: cited correctly, and complete enough
that every module is one hop from it."""

from __future__ import annotations

import re
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
DOC = REPO / "docs" / "architecture.md"
CITATION = re.compile(r'docs/architecture\.md,? "([^"]+)"')
TEXT_SUFFIXES = {".py", ".md", ".toml", ".yaml", ".yml"}


def _repo_text_files() -> list[Path]:
    skip = {".git", ".venv", "build", "dist"}
    return [p for p in REPO.rglob("*") if p.suffix in TEXT_SUFFIXES and p.is_file()
            and not skip & set(p.relative_to(REPO).parts) and ".egg-info" not in str(p)]


def _sections() -> set[str]:
    return {m.group(1).strip() for m in re.finditer(r"^##+ (.+)$", DOC.read_text(), re.M)}


def test_no_file_cites_a_design_document_the_repository_does_not_hold():
    stale = [str(p.relative_to(REPO)) for p in _repo_text_files()
             if p.name != Path(__file__).name and "DESIGN.md" in p.read_text(errors="replace")]
    assert not stale, stale


def test_every_citation_names_a_section_of_the_document():
    sections = _sections()
    cited = {(str(p.relative_to(REPO)), m.group(1)) for p in _repo_text_files() if p != Path(__file__)
             for m in CITATION.finditer(p.read_text(errors="replace"))}
    assert cited, "no docstring cites docs/architecture.md"
    wrong = sorted((f, s) for f, s in cited if s not in sections)
    assert not wrong, f"citations of sections the document does not have: {wrong}; it has {sorted(sections)}"


def test_every_module_is_named_in_the_layout():
    layout = DOC.read_text().split("## Layout", 1)[1]
    modules = sorted(p for folder in ("facesculpt",) for p in (REPO / folder).rglob("*.py")
                     if p.name != "__init__.py")
    missing = [str(p.relative_to(REPO)) for p in modules if f"`{p.relative_to(REPO)}`" not in layout]
    assert not missing, f"docs/architecture.md \"Layout\" does not name: {missing}"
