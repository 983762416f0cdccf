"""The documentation: the mkdocs site builds with no warning, the README stays short, and every
relative link in README.md and docs/ (and every repository path docs/ names in a code span) leads
to a file that exists, and to a heading that exists where the link names one."""

from __future__ import annotations

import importlib.util
import os
import re
import subprocess
import sys
import unicodedata
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
DOCS = ROOT / "docs"
README_MAX_LINES = 150

_LINK = re.compile(r"(?<!!)\[[^\]]*\]\(([^)\s]+)\)")
_FENCE = re.compile(r"^(```|~~~).*?^\1", re.S | re.M)
_CODE_SPAN = re.compile(r"`([^`\n]+)`")
#: a code span that names a file of the repository: `benchmarks/README.md#bake-scaling`, `pipeline/cli.py`
_REPO_PATH = re.compile(r"^((?:benchmarks|docs|exporters|js|pipeline|runtime_blender|runtime_shaders|runtime_three|"
                        r"samples|tests)/[\w./-]*\w)(#[\w-]+)?$")


def _markdown_files() -> list[Path]:
    return [ROOT / "README.md", *sorted(DOCS.rglob("*.md"))]


def _prose(text: str) -> str:
    """`text` without its fenced code blocks (their brackets and backticks are code)."""
    return _FENCE.sub("", text)


def _slug(heading: str) -> str:
    """The anchor mkdocs (Python-Markdown's toc) gives a heading: its text without code and emphasis
    marks, in ASCII, characters other than word characters, spaces and hyphens removed, lower case,
    each run of spaces and hyphens one hyphen. GitHub's agrees on the headings README.md links to."""
    text = re.sub(r"[`*]", "", heading)
    text = unicodedata.normalize("NFKD", text).encode("ascii", "ignore").decode("ascii")
    text = re.sub(r"[^\w\s-]", "", text).strip().lower()
    return re.sub(r"[-\s]+", "-", text)


def _anchors(path: Path) -> set[str]:
    return {_slug(m.group(1)) for m in re.finditer(r"^#{1,6}\s+(.+?)\s*#*$", _prose(path.read_text()), re.M)}


def _targets(path: Path) -> list[tuple[str, Path, str]]:
    """(as written, file, anchor) for each relative link in `path`."""
    out = []
    for m in _LINK.finditer(_prose(path.read_text())):
        link = m.group(1)
        if re.match(r"^[a-z][a-z0-9+.-]*:", link):  # https:, mailto:
            continue
        file, _, anchor = link.partition("#")
        out.append((link, (path.parent / file).resolve() if file else path, anchor))
    return out


def test_readme_is_short():
    lines = (ROOT / "README.md").read_text().splitlines()
    assert len(lines) <= README_MAX_LINES, f"README.md has {len(lines)} lines; move detail into docs/"


def test_readme_starts_with_the_two_commands():
    lines = (ROOT / "README.md").read_text().splitlines()
    assert lines[3].startswith("bash .ci/setup && .venv/bin/sssbake bake samples/ -o out/")
    assert lines[4].startswith("bash .ci/setup && .venv/bin/python -m pytest -q")


@pytest.mark.parametrize("path", _markdown_files(), ids=lambda p: str(p.relative_to(ROOT)))
def test_relative_links_resolve(path: Path):
    broken = []
    for link, target, anchor in _targets(path):
        if not target.exists():
            broken.append(f"{link}: no such file")
        elif anchor and target.suffix == ".md" and anchor not in _anchors(target):
            broken.append(f"{link}: no heading with anchor #{anchor}")
    assert not broken, f"{path.relative_to(ROOT)}: " + "; ".join(broken)


@pytest.mark.parametrize("path", sorted(DOCS.rglob("*.md")), ids=lambda p: str(p.relative_to(ROOT)))
def test_repository_paths_named_in_docs_exist(path: Path):
    """docs/ names files outside the site as repository paths in code spans (mkdocs resolves links only
    inside docs/): each must exist, with its heading where it names one."""
    missing = []
    for m in _CODE_SPAN.finditer(path.read_text()):
        named = _REPO_PATH.match(m.group(1))
        if not named:
            continue
        file, anchor = named.group(1), (named.group(2) or "")[1:]
        target = ROOT / file
        if "*" in file or not re.search(r"\.\w+$|/$", file):
            continue  # a glob or a bare folder name such as `runtime_shaders/kernels_*`
        if not target.exists():
            missing.append(f"`{m.group(1)}`: no such file")
        elif anchor and target.suffix == ".md" and anchor not in _anchors(target):
            missing.append(f"`{m.group(1)}`: no heading with anchor #{anchor}")
    assert not missing, f"{path.relative_to(ROOT)}: " + "; ".join(sorted(set(missing)))


def test_site_builds_strict(tmp_path: Path):
    if importlib.util.find_spec("mkdocs") is None or importlib.util.find_spec("material") is None:
        pytest.skip("mkdocs-material is not installed (pip install -e '.[docs]')")
    proc = subprocess.run(
        [sys.executable, "-m", "mkdocs", "build", "--strict", "--config-file", str(ROOT / "mkdocs.yml"),
         "--site-dir", str(tmp_path / "site")],
        capture_output=True, text=True, cwd=ROOT, timeout=300, env={**os.environ, "NO_MKDOCS_2_WARNING": "1"},
    )
    assert proc.returncode == 0, proc.stderr[-4000:]
    assert not re.search(r"^WARNING", proc.stderr, re.M), proc.stderr[-4000:]
    for page in ("index.html", "baking/index.html", "techniques/prt/index.html", "troubleshooting/index.html"):
        assert (tmp_path / "site" / page).is_file(), page
