"""Every import the README and docs/ show (`from densecalib_ros... import ...` in their code
blocks) imports: a module moved or a name renamed breaks the page, not only the code."""
import re
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
PAGES = [REPO / "README.md", *sorted((REPO / "docs").glob("*.md"))]
IMPORT = re.compile(
    r"^\s*(from densecalib_ros[\w.]* import \(?[\w, ]+\)?|import densecalib_ros[\w.]*)", re.M)


def _shown_imports():
    for page in PAGES:
        for block in re.findall(r"```python\n(.*?)```", page.read_text(), re.S):
            for statement in IMPORT.findall(block):
                yield pytest.param(statement.strip(), id=f"{page.name}: {statement.strip()}")


@pytest.mark.parametrize("statement", list(_shown_imports()))
def test_the_import_a_page_shows_works(statement):
    exec(statement, {})


def test_the_pages_show_imports():
    assert len(list(_shown_imports())) >= 8  # the pattern still finds them
