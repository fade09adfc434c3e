"""The README's first screen and the product text: the two commands verbatim, a short Quick start,
figures only by link, and no issue numbers anywhere in code, docs or tests."""
import re
import subprocess

from conftest import REPO

COMMANDS = (
    "./setup.sh && .venv/bin/cinetransfer transfer ../shared/data/sam2_juggle_1280x720.mp4 "
    "--scene open_country -o runs/juggle",
    "./setup.sh && .venv/bin/python -m pytest",
)


def _section(text: str, title: str) -> list[str]:
    lines = text.splitlines()
    start = next(i for i, ln in enumerate(lines) if ln.startswith(f"## {title}"))
    end = next((i for i in range(start + 1, len(lines)) if lines[i].startswith("## ")), len(lines))
    return lines[start + 1:end]


def test_first_screen_gives_the_two_commands_what_you_get_and_links():
    text = (REPO / "README.md").read_text()
    first = "\n".join(text.splitlines()[:30])
    for c in COMMANDS:
        assert c in first, f"the README's first screen lacks `{c}`"
    assert "report.html" in first and "docs/benchmarks.md" in first
    assert len(_section(text, "Quick start")) <= 25


def test_no_issue_numbers_in_the_product_text():
    files = subprocess.run(["git", "ls-files", "*.py", "*.md", "*.yaml", "*.toml", "*.sh", "*.html"], cwd=REPO,
                           capture_output=True, text=True, check=True).stdout.split()
    pattern = re.compile(r"\bissues? ?#?\d+|\bissue-\d+", re.IGNORECASE)
    found = [f"{f}:{n}: {ln.strip()[:80]}" for f in files if (REPO / f).is_file() and f != "tests/unit/test_readme.py"
             for n, ln in enumerate((REPO / f).read_text(errors="replace").splitlines(), 1) if pattern.search(ln)]
    assert not found, "name goals by what they measure, not by issue number:\n" + "\n".join(found)
