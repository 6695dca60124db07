"""ablate.reporting.blocks: the report as data. Tables are numbered in the blocks, in order, and one without a
caption takes its section's title; a table's columns align by what they hold."""

import pandas as pd

from ablate.reporting.blocks import Heading, Item, Items, Paragraph, Table, number_tables


def test_tables_are_numbered_in_order_and_named_after_their_section_unless_captioned():
    frame = pd.DataFrame([{"variant": "a", "seeds": 3}])
    blocks = [Heading("Claims", generated=True), Table(frame), Heading("Results", 3, True, "C"), Paragraph("x")]
    blocks += [Table(frame, "Episodes to solve"), Table(frame)]
    numbered = [b for b in number_tables(blocks) if isinstance(b, Table)]
    assert [(t.number, t.caption) for t in numbered] == [(1, "Claims"), (2, "Episodes to solve"), (3, "Results")]
    assert all(t.number == 0 for t in blocks if isinstance(t, Table))  # the blocks given are left as they were


def test_columns_of_words_align_left_and_of_numbers_and_intervals_right():
    table = Table(
        pd.DataFrame([{"variant": "deep", "seeds": 5, "IQM [95% CI]": "≥ 40 [36, 40]", "why": "reached max"}])
    )
    assert table.align == ["left", "right", "right", "left"]
    assert table.rows == [["deep", "5", "≥ 40 [36, 40]", "reached max"]]


def test_a_heading_says_its_letter_and_that_it_is_generated():
    assert Heading("Tuning", 3, True, "B").text == "B. Tuning (generated)"
    assert Heading("References").text == "References"
    assert Items.of(["a", Item("b", ("c",))]).items == (Item("a"), Item("b", ("c",)))
