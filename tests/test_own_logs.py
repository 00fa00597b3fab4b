"""docs/own_logs.md holds what its worked examples give now (tests/own_log_examples.py makes and runs them)."""

from tests.own_log_examples import PAGE, examples, page_blocks, same


def test_the_own_logs_page_shows_what_its_examples_print_now(tmp_path):
    made = examples(tmp_path)
    page = page_blocks(PAGE.read_text(encoding="utf-8"))
    assert set(made) <= set(page), f"blocks missing from {PAGE.name}: {sorted(set(made) - set(page))}"
    stale = [name for name, body in made.items() if not same(page[name], body)]
    assert not stale, f"{PAGE.name} is stale in {stale}: run python -m tests.own_log_examples --write"
