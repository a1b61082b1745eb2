"""The docs: every FAQ fix runs and does what it says; papers.md resolves every citation."""

from __future__ import annotations

import re
from pathlib import Path

import pytest
from typer.testing import CliRunner

from margtrack.cli import app

DOCS = Path(__file__).resolve().parents[1] / "docs"
SRC = Path(__file__).resolve().parents[1] / "src" / "margtrack"


def _python_blocks(path: Path) -> list[tuple[str, str]]:
    """(section heading, code) of every ```python block of a markdown file."""
    blocks, heading = [], ""
    text = path.read_text(encoding="utf-8")
    for match in re.finditer(r"^## ([^\n]+)$|^```python\n(.*?)^```", text, re.M | re.S):
        if match.group(1):
            heading = match.group(1)
        else:
            blocks.append((heading, match.group(2)))
    return blocks


FAQ_BLOCKS = _python_blocks(DOCS / "faq.md")


def test_every_faq_answer_has_a_checked_fix():
    text = (DOCS / "faq.md").read_text(encoding="utf-8")
    headings = re.findall(r"^## (.+)$", text, re.M)
    assert len(headings) >= 6
    assert {h for h, _ in FAQ_BLOCKS} == set(headings)
    for topic in ("deg/s", "milliseconds", "axes", "scalar-last", "ENU", "conjugate"):
        assert any(topic in h for h in headings), topic
    for _, code in FAQ_BLOCKS:
        assert "assert" in code  # each snippet checks its own fix


@pytest.mark.parametrize(("heading", "code"), FAQ_BLOCKS, ids=[h[:40] for h, _ in FAQ_BLOCKS])
def test_faq_fix_runs_and_does_what_it_says(heading, code):
    exec(compile(code, f"docs/faq.md: {heading}", "exec"), {"__name__": "faq"})


def test_a_wrong_fix_would_fail():
    """The snippets' checks can fail: break the axis fix and its assertion trips."""
    _, code = next(b for b in FAQ_BLOCKS if "axes" in b[0])
    broken = code.replace("q_fix = quat.from_matrix(P.T)", "q_fix = quat.identity()")
    assert broken != code
    with pytest.raises(AssertionError):
        exec(compile(broken, "broken", "exec"), {"__name__": "faq"})


def test_papers_md_cites_every_paper_number_the_code_uses():
    papers = (DOCS / "papers.md").read_text(encoding="utf-8")
    cited = set()
    for path in SRC.rglob("*.py"):
        cited |= set(re.findall(r"\b(00\d)(?:,)? (?:eqs?\.|Fig\.|Table|Appendix)",
                                path.read_text(encoding="utf-8")))
    assert cited and cited <= {"000", "001", "002", "003", "004"}, cited
    for number in sorted(cited):
        section = re.search(rf"^\*\*{number}\*\* — (.+?)(?:\n\n|\Z)", papers, re.M | re.S)
        assert section, f"no full citation for {number}"
        assert re.search(r"(19|20)\d\d", section.group(1)), f"{number} has no year"
    for needle in ("NPS-MV-01-003", "pp. 2003-2011", "10.1109/TIM.2007.911646",
                   "Riviere", "Symeonidis"):
        assert needle in papers


def test_help_texts_point_at_the_docs():
    runner = CliRunner()
    top = runner.invoke(app, ["--help"])
    assert top.exit_code == 0 and "docs/papers.md" in top.output and "docs/faq.md" in top.output
    listing = runner.invoke(app, ["methods"])
    assert listing.exit_code == 0 and "docs/papers.md" in listing.output
    one = runner.invoke(app, ["methods", "bachmann"])
    assert one.exit_code == 0 and "docs/papers.md" in one.output
