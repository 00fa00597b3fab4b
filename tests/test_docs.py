"""The documentation's examples run as written, and the docs index names every page."""

import re
from pathlib import Path

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
