"""The README's two commands and CI stay in step."""

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
