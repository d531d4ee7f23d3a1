"""The README is short and the site holds everything the old, long README said (issue 27).

tests/data/readme_terms.txt lists the commands, flags, topic and service names, files, environment variables and
figures of the README before it was cut to a page; each must still appear in the site's Markdown or in README.md.
A dropped term names itself here: put it back where it belongs, or, if it no longer exists in the code, remove it
from the data file in the same commit that removes it from the code.
"""
import re
from pathlib import Path
from urllib.parse import urlsplit

import pytest

ROOT = Path(__file__).resolve().parent.parent
TERMS_FILE = ROOT / "tests" / "data" / "readme_terms.txt"
README_MAX_LINES = 200


def _flat(text: str) -> str:
    """Whitespace-insensitive: re-wrapping a paragraph must not count as losing a figure."""
    return re.sub(r"\s+", " ", text)


def _terms() -> list[str]:
    lines = TERMS_FILE.read_text(encoding="utf-8").splitlines()
    return [line for line in lines if line.strip() and not line.startswith("#")]


@pytest.fixture(scope="module")
def written_text() -> str:
    pages = sorted((ROOT / "docs").rglob("*.md"))
    assert pages, "docs/ holds no Markdown pages"
    return _flat("\n".join(p.read_text(encoding="utf-8") for p in pages) + "\n"
                 + (ROOT / "README.md").read_text(encoding="utf-8"))


def test_the_terms_file_is_the_old_readmes_inventory():
    terms = _terms()
    assert len(terms) == len(set(terms)), "tests/data/readme_terms.txt lists a term twice"
    # Guards against an emptied or truncated data file making the next test pass vacuously.
    for expected in ("vr-teleop serve", "--generate-tokens", "/vr_teleop/control/engage", "make bench",
                     "bench/wan.py", "46,700 msg/s"):
        assert expected in terms


def test_nothing_the_old_readme_said_is_lost(written_text):
    missing = [term for term in _terms() if _flat(term) not in written_text]
    assert not missing, (f"{len(missing)} term(s) of the old README appear nowhere in docs/ or README.md: "
                         f"{missing}")


def test_readme_is_short():
    lines = (ROOT / "README.md").read_text(encoding="utf-8").splitlines()
    assert len(lines) <= README_MAX_LINES, f"README.md has {len(lines)} lines; at most {README_MAX_LINES}"


def test_readme_links_point_at_files_that_exist():
    """The README is read on GitHub, outside the site's strict build: its relative links are checked here."""
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    broken = []
    for target in re.findall(r"\]\(([^)\s]+)\)", text):
        parts = urlsplit(target)
        if parts.scheme or parts.netloc or not parts.path:
            continue
        if not (ROOT / parts.path).exists():
            broken.append(target)
    assert not broken, f"README.md links to files that do not exist: {broken}"
