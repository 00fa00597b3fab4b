"""The documentation's worked examples show what the current code gives (tests/doc_examples.py makes and runs
them; ``python -m tests.doc_examples --write`` rewrites them)."""

import pytest

from tests.doc_examples import DOCS, PAGES, page_blocks, same


@pytest.mark.parametrize("page", PAGES)
def test_a_pages_worked_examples_show_what_the_code_gives_now(page, tmp_path):
    made = PAGES[page](tmp_path)
    shown = page_blocks((DOCS / page).read_text(encoding="utf-8"))
    assert set(made) <= set(shown), f"blocks missing from docs/{page}: {sorted(set(made) - set(shown))}"
    stale = [name for name, body in made.items() if not same(shown[name], body)]
    assert not stale, f"docs/{page} is stale in {stale}: run python -m tests.doc_examples --write"
