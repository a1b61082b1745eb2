"""The README is a front page that tells the truth: its two commands come first, every
``margtrack`` command and option it names exists, its Python example prints the figure it
states (the one ``margtrack evaluate`` gives), its tables agree with the docs they summarise,
and its links lead to files."""

from __future__ import annotations

import json
import os
import re
from pathlib import Path

import pytest
import typer.main
from typer.testing import CliRunner

from margtrack.cli import app

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
TEXT = README.read_text(encoding="utf-8")

#: CI (.ci/run) runs the second one: change neither without changing the other
INSTALL_AND_DEMO = (
    "python3 -m venv .venv && . .venv/bin/activate && pip install . && margtrack demo\n"
)
INSTALL_AND_TEST = (
    "python3 -m venv .venv && . .venv/bin/activate && pip install -e \".[dev,live]\" "
    "&& python -m pytest -q -n auto\n"
)


def _code_blocks(text: str) -> list[tuple[str, str]]:
    """(language, code) of every fenced block, in order."""
    return re.findall(r"^```(\w*)\n(.*?)^```", text, re.M | re.S)


def _links(text: str) -> list[str]:
    """Targets of the markdown links that are not web addresses."""
    return [t for t in re.findall(r"\]\(([^)\s]+)\)", text) if not re.match(r"\w+://", t)]


def _table_rows(text: str, first_cell: str) -> list[list[str]]:
    """Cells of every table row whose first cell starts with ``first_cell``."""
    rows = []
    for line in text.splitlines():
        if line.startswith("| " + first_cell):
            rows.append([c.strip() for c in line.strip().strip("|").split("|")])
    return rows


def test_the_two_commands_are_the_first_code_blocks():
    blocks = _code_blocks(TEXT)
    assert blocks[:2] == [("bash", INSTALL_AND_DEMO), ("bash", INSTALL_AND_TEST)]
    assert TEXT.index("```") < 200, "the commands are at the very top"
    ci = (ROOT / ".ci" / "run").read_text(encoding="utf-8")
    assert 'pip install --quiet -e ".[dev,live]"' in ci and "python -m pytest -q -n auto" in ci


def test_it_is_a_front_page():
    """At most 200 lines; no issue numbers, dates, load averages or measurement history."""
    assert len(TEXT.splitlines()) <= 200
    for pattern in (r"[Ii]ssue \d", r"#\d", r"\b20\d\d-\d\d-\d\d\b", r"load average",
                    r"\b\d\d:\d\d\b"):
        assert not re.search(pattern, TEXT), pattern
    for doc in ("tutorial", "conventions", "faq", "papers", "speed", "adding_a_method"):
        assert f"(docs/{doc}.md)" in TEXT, doc


def _named_commands(text: str) -> list[str]:
    """Every ``margtrack ...`` command line of the README: inline code and shell lines."""
    spans = re.findall(r"`(margtrack [^`]+)`", text)
    for lang, code in _code_blocks(text):
        if lang == "bash":
            spans += [line for line in code.splitlines() if line.startswith("margtrack ")]
    spans += re.findall(r"&& (margtrack [^\n]+)", text)
    return spans


NAMED = _named_commands(TEXT)


def test_the_readme_names_the_commands():
    named = {line.split()[1] for line in NAMED}
    top = typer.main.get_command(app)
    assert named == set(top.commands), "a command is missing from the README, or one too many"


@pytest.mark.parametrize("line", NAMED)
def test_every_named_command_and_option_exists(line):
    """``margtrack CMD [SUB] ... --opt``: the command, its subcommand and options exist."""
    words = line.split()
    command = typer.main.get_command(app)
    for word in words[1:]:
        if not hasattr(command, "commands") or not re.fullmatch(r"[a-z][a-z-]*", word):
            break
        assert word in command.commands, f"{line!r}: no command {word!r}"
        # resolving loads a lazy command (margtrack.cli.LazyGroup)
        _, command, _ = command.resolve_command(command.context_class(command), [word])
    options = {o for p in command.params for o in (*p.opts, *p.secondary_opts)}
    for word in words:
        flag = word.split("=")[0].strip("[](),.")
        if flag.startswith("-") and flag not in ("-", "--"):
            assert flag in options, f"{line!r}: {flag} is not an option of {command.name}"


def test_the_python_example_prints_what_margtrack_evaluate_gives(broad_folder, tmp_path,
                                                                  capsys):
    """The example, run as written, prints the figure the README states, and that figure
    is the one ``margtrack evaluate`` prints for the same trial and method."""
    code = next(c for lang, c in _code_blocks(TEXT) if lang == "python")
    assert len(code.strip().splitlines()) <= 12, "a short example"
    stated = re.search(r"# prints (\d+\.\d\d) deg", code)
    assert stated, "the example says what it prints"
    trial = re.search(r'mt\.io\.read\("([^"]+)"\)', code).group(1)
    method = re.search(r'mt\.create\("([\w-]+)"\)\.run', code).group(1)
    assert "mt.score(est, rec)" in code, "scored over the movement samples, as evaluate does"

    cwd = os.getcwd()
    os.chdir(ROOT)
    try:
        exec(compile(code, "README.md", "exec"), {"__name__": "readme"})
    finally:
        os.chdir(cwd)
    assert capsys.readouterr().out.strip() == f"{stated.group(1)} deg"

    out = tmp_path / "evaluate.json"
    result = CliRunner().invoke(app, ["evaluate", str(ROOT / trial), "-m", method,
                                      "--json", str(out)])
    assert result.exit_code == 0, result.output
    total = json.loads(out.read_text())["mean"]["total_rmse_deg"]
    assert f"{total:.2f}" == stated.group(1)
    assert f"prints the same {stated.group(1)}°" in TEXT  # the prose says the same


def test_the_methods_table_agrees_with_docs_methods():
    """Each margtrack method's figures are the full table's in docs/methods.md (total and
    cross-validated) and its paragraph on unseen trials."""
    docs = (ROOT / "docs" / "methods.md").read_text(encoding="utf-8")
    unseen = " ".join(docs[docs.index("## On unseen trials"):].split())
    methods = [r for r in _table_rows(TEXT, "`") if len(r) == 6 and r[2].endswith("°")]
    assert {r[0] for r in methods} >= {"`robust` (default)", "`gradient`", "`ekf`"}
    for name, _, total, cv, by_kind, new in methods:
        full = _table_rows(docs, name)
        assert full, f"{name} is not in docs/methods.md's table"
        assert full[0][2] == total, name
        assert cv == "–" or full[0][-1].startswith(cv.split(" ")[0]), name
        if by_kind != "–" and "no grid" not in by_kind:
            assert f"leave one kind out {by_kind}" in full[0][-1], name
        if new != "–":
            assert f"{name.split()[0]} {new}" in unseen, name


def test_the_speed_table_is_the_latest_measurement_in_docs_speed():
    """Every figure of the README's speed table is in the same row of docs/speed.md's
    current figures."""
    speed = (ROOT / "docs" / "speed.md").read_text(encoding="utf-8")
    latest = speed[speed.index("## Current figures"):speed.index("## Offline kernels")]
    rows = _table_rows(TEXT[TEXT.index("## Speed"):], "`")
    assert len(rows) >= 5
    for row in rows:
        full = _table_rows(latest, row[0])
        assert full, row[0]
        assert set(row[1:]) <= set(full[0][1:]), (row, full[0])


@pytest.mark.parametrize("target", sorted(set(_links(TEXT))))
def test_every_link_leads_to_a_file(target):
    path = target.split("#")[0]
    assert (ROOT / path).is_file(), f"README links to {target}, which is not a file"


def test_import_margtrack_does_not_load_numba():
    import subprocess
    import sys

    code = "import sys, margtrack; print('numba' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"


def test_unknown_attribute_is_an_attribute_error():
    import margtrack

    with pytest.raises(AttributeError, match="no attribute 'nope'"):
        margtrack.nope  # noqa: B018
