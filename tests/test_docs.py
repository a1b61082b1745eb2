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


def _anchor(heading: str) -> str:
    """GitHub's anchor of a heading: lower case, punctuation dropped, spaces to hyphens."""
    return re.sub(r"[^\w\- ]", "", heading.strip().lower()).replace(" ", "-")


DOC_LINKS = [
    (page.name, target)
    for page in sorted(DOCS.glob("*.md"))
    for target in re.findall(r"\]\(([^)\s]+)\)", page.read_text(encoding="utf-8"))
    if not re.match(r"\w+://", target)
]


@pytest.mark.parametrize(("page", "target"), DOC_LINKS, ids=[f"{p}->{t}" for p, t in DOC_LINKS])
def test_every_docs_link_leads_to_a_file_and_heading(page, target):
    """Links between the docs pages resolve; a #fragment names a heading of its page."""
    path, _, fragment = target.partition("#")
    file = (DOCS / path) if path else DOCS / page
    assert file.is_file(), f"docs/{page} links to {target}, which is not a file"
    if fragment:
        headings = re.findall(r"^#+ (.+)$", file.read_text(encoding="utf-8"), re.M)
        assert fragment in {_anchor(h) for h in headings}, f"docs/{page}: no heading #{fragment}"


API_BLOCKS = _python_blocks(DOCS / "api.md")


def test_the_api_page_example_runs(capsys):
    """docs/api.md's example (simulated data, no files needed) runs as written."""
    assert API_BLOCKS, "docs/api.md has no python example"
    for heading, code in API_BLOCKS:
        exec(compile(code, f"docs/api.md: {heading}", "exec"), {"__name__": "api"})
    assert re.search(r"^\d+\.\d\d deg$", capsys.readouterr().out, re.M)


def test_the_live_page_keeps_the_security_facts_and_the_line_format():
    """What the README only sums up about the live view is stated in full in docs/live.md."""
    live = " ".join((DOCS / "live.md").read_text(encoding="utf-8").split())
    for fact in ("127.0.0.1", "`Origin`", "--host 0.0.0.0", "token", "--udp-host 0.0.0.0",
                 "UDP has no authentication", "t,sensor,gx,gy,gz,ax,ay,az,mx,my,mz[,seq]",
                 "--fixed-root", "--no-mag", "--lever-arms", "Reset position"):
        assert fact in live, fact
