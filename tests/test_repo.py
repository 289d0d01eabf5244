"""The README's two commands and CI stay in step; the docs' links lead somewhere."""

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def readme_commands():
    return re.findall(r"^    (python3 -m venv .*)$", (ROOT / "README.md").read_text(), re.M)


def test_readme_opens_with_main_job_and_test_commands():
    main_job, tests = readme_commands()[:2]
    assert main_job.endswith("wtml pipeline") and "-c constraints.txt" in main_job
    assert tests.endswith("python -m pytest")


def test_ci_runs_exactly_the_readme_test_command():
    ci = (ROOT / ".ci" / "run").read_text()
    assert readme_commands()[1] in ci.splitlines()
    assert "-eq 5" in ci  # pytest's "no tests collected" is a failure
    assert (ROOT / "constraints.txt").read_text().split() == ["torch==2.13.0"]


LINK = re.compile(r"\]\(([^)\s]+)\)")


def heading_slugs(path: Path) -> set[str]:
    """GitHub's anchors for a markdown file's headings (lower case, punctuation but ``-`` and
    ``_`` dropped, spaces as ``-``; a repeated heading's anchor gets ``-1``, ``-2``, ...)."""
    found, seen, fence = set(), {}, False
    for line in path.read_text().splitlines():
        if line.startswith("```"):
            fence = not fence
        elif not fence and re.match(r"^#{1,6} ", line):
            base = re.sub(r"[^\w\- ]", "", line.lstrip("#").strip().lower()).replace(" ", "-")
            n = seen.get(base, 0)
            seen[base] = n + 1
            found.add(base if n == 0 else f"{base}-{n}")
    return found


def test_relative_links_in_the_docs_resolve():
    """Every relative link in README.md, docs/*.md and configs/README.md names a file that
    exists and, with an anchor, one of that file's headings (the README's journal lives in
    docs/, and a moved section must not leave a dead link)."""
    pages = [ROOT / "README.md", ROOT / "configs" / "README.md",
             *sorted((ROOT / "docs").glob("*.md"))]
    broken, checked = [], 0
    for page in pages:
        fence = False
        for n, line in enumerate(page.read_text().splitlines(), 1):
            if line.startswith("```"):
                fence = not fence
                continue
            for target in [] if fence else LINK.findall(line):
                if re.match(r"^[a-z]+:", target):  # http:, https:, mailto:
                    continue
                checked += 1
                path, _, anchor = target.partition("#")
                dest = (page.parent / path).resolve() if path else page
                if not dest.exists() or (anchor and dest.suffix == ".md"
                                         and anchor not in heading_slugs(dest)):
                    broken.append(f"{page.relative_to(ROOT)}:{n}: {target}")
    assert checked > 20 and not broken, broken
