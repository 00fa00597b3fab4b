"""The documentation's examples run as written, the docs index names every page, and no file narrates history."""

import re
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def python_blocks(path: Path) -> list[str]:
    return re.findall(r"^```python\n(.*?)^```", path.read_text(encoding="utf-8"), re.S | re.M)


def test_every_example_of_the_guide_to_extending_runs(capsys):
    """docs/extending.md's blocks run in order in one namespace (later blocks use earlier definitions)."""
    blocks = python_blocks(ROOT / "docs" / "extending.md")
    assert len(blocks) == 4
    namespace: dict = {"__name__": "extending_example"}
    for i, code in enumerate(blocks):
        exec(compile(code, f"docs/extending.md block {i + 1}", "exec"), namespace)  # noqa: S102
    out = capsys.readouterr().out
    assert "step 0.05 N·m, sensor feedback" in out and "largest compensation" in out
    assert "load-cell torque" in out
    assert 0.5 < namespace["result"].gain < 1.5  # a stiff locked rig passes most of a 5 Hz command
    assert "refused: " in out and "length_m" in out


def test_the_docs_index_names_every_page_and_every_link_resolves():
    index = (ROOT / "docs" / "index.md").read_text(encoding="utf-8")
    pages = {p.name for p in (ROOT / "docs").glob("*.md")} - {"index.md"}
    linked = set(re.findall(r"\]\(([\w./-]+\.md)", index))
    assert pages <= {Path(link).name for link in linked}
    for link in linked:
        assert (ROOT / "docs" / link).resolve().exists(), link


# Code and docs describe what is; history goes to CHANGELOG.md. A line that names a work session, a tracker
# issue or a branch of the repository fails. Narrow on purpose: a hysteresis loop's "branch" and a "session" on
# the rig are prose.
HISTORY = re.compile("|".join([
    r"\b(sessions?|issues?)[\s-]*#?\d+",  # a numbered session or issue, also in a file name
    r"\bthe issue\b",  # the tracker's issue
    r"\b(this|next|previous|last|earlier|later) session\b",
    r"\bbranch(es)?\s+(`[^`]+`|[a-z][\w-]*\d[\w-]*\b)",  # a named branch
    r"\b(git|feature|development|topic)\s+branch",
    r"`[\w./-]+`\s+branch\b",
]), re.I)
# the keywords are assembled so that this file's own examples do not match
WORDS = {"i": "is" + "sue", "s": "ses" + "sion", "b": "bra" + "nch"}


def tracked_text_files() -> list[Path]:
    """The repository's .py, .md and .toml files (git's list; every such file outside hidden and output
    directories where git is unavailable), CHANGELOG.md excepted."""
    try:
        names = subprocess.run(["git", "ls-files", "-z", "*.py", "*.md", "*.toml"], cwd=ROOT, check=True,
                               capture_output=True, text=True).stdout.split("\0")
        paths = [ROOT / name for name in names if name]
    except (OSError, subprocess.CalledProcessError):
        paths = [p for p in ROOT.rglob("*") if p.suffix in {".py", ".md", ".toml"}
                 and not any(part.startswith(".") or part in {"out", "build", "__pycache__"}
                             for part in p.relative_to(ROOT).parts)]
    return [p for p in paths if p.relative_to(ROOT).as_posix() != "CHANGELOG.md" and p.is_file()]


def test_no_file_names_a_work_session_a_tracker_issue_or_a_branch():
    files = tracked_text_files()
    assert len(files) > 50 and ROOT / "sim" / "params.py" in files
    hits = [f"{path.relative_to(ROOT)}:{n}: {match.group(0)!r}"
            for path in files
            for n, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1)
            if (match := HISTORY.search(line))]
    assert not hits, "history belongs in CHANGELOG.md:\n" + "\n".join(hits)


@pytest.mark.parametrize("line", [
    "    * v0: initial version (torquebed {i} 5).",
    "1/(4β) = 16.7 N·m and cannot reach 18 N·m: docs/{i}4_figures.md, {s} 14.)",
    "1.0001x the smallest feasible one and 16 candidate rows ({s}-18 reviews); every fit",
    "## Plant speed ({i} 2)",
    "### After the per-tick Python was cut ({b} perf5)",
    "Prototypes are on the {b} `cogging`, not merged.",
    "the rule keeps 16. The {i} forbids buying speed that way",
    "Adopting it means a new field; not done this {s}.",
    "see {i} #12",
])
def test_the_history_check_catches_sessions_issues_and_branches(line):
    assert HISTORY.search(line.format(**WORDS))


@pytest.mark.parametrize("line", [
    "the ascending branch and the descending branch",
    "puts at least one {b} 0.056 N·m from the reference",
    "a sample belongs to the *ascending* {b} when the reference torque was last moving up",
    "tare_mask=rec.schedule.{b} == 0",
    "QP calibration on a second {s} of the same protocols",
    "the calibration {s}'s loading, 5 cycles each way",
    "{I} every warning MuJoCo gave since the last call",
    "a non-issue",
])
def test_the_history_check_passes_hysteresis_branches_rig_sessions_and_the_verb(line):
    assert not HISTORY.search(line.format(I="Is" + "sue", **WORDS))
