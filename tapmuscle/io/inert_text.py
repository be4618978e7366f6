"""Text from files one did not write (a scenario's name, a sweep's description, an error's message)
made inert where tapmuscle writes it into a document a program interprets.

* A spreadsheet evaluates a CSV cell that starts with ``=``, ``+``, ``-`` or ``@`` as a formula
  (``=HYPERLINK(...)`` sends data away; OWASP's "CSV injection"): :func:`inert_cell` puts a ``'``
  before such text, which the spreadsheet shows as text. A number (``-1.5``) is left as it is.
* A Markdown viewer renders raw HTML and links (``<img onerror=...>``, ``[x](javascript:...)``) and
  a ``|`` breaks a table's row: :func:`markdown_text` escapes them.
"""

from __future__ import annotations

import re

__all__ = ["inert_cell", "inert_csv_text", "markdown_text"]

_FORMULA_START = re.compile(r"[=+@\t\r]|-(?![0-9.])")


def inert_cell(text: str) -> str:
    """``text`` as a CSV cell no spreadsheet evaluates: with a ``'`` before it where it would start a
    formula (after any spaces); a number, or any other text, unchanged.

    Parameters
    ----------
    text : str
        The cell's text.
    """
    stripped = text.lstrip(" ")
    try:
        float(text)  # a number, also one a regular expression would not call one (-inf, +1e3)
        return text
    except ValueError:
        pass
    if stripped and _FORMULA_START.match(stripped):
        return text[:len(text) - len(stripped)] + "'" + stripped
    return text


def inert_csv_text(text: str) -> str:
    """``text`` that a CSV line holds unquoted (a ``# key: value`` header line of a recording), each
    of the cells a spreadsheet splits it into at its commas made inert (:func:`inert_cell`).

    Parameters
    ----------
    text : str
        The line's text.
    """
    first, *rest = text.split(",")
    return ",".join([first, *(inert_cell(piece) for piece in rest)])


_MARKDOWN_SPECIAL = re.compile(r"([\\`\[\]|])")


def markdown_text(text: str) -> str:
    """``text`` as literal Markdown on one line: HTML's ``& < >`` as entities, the characters that
    make links, code spans and table cells (``\\ ` [ ] |``) escaped, line breaks as spaces (emphasis,
    harmless, is left: ``ampc_servo`` stays readable in the file).

    Parameters
    ----------
    text : str
        The text to show literally.
    """
    text = " ".join(text.splitlines())
    text = text.replace("&", "&amp;").replace("<", "&lt;").replace(">", "&gt;")
    return _MARKDOWN_SPECIAL.sub(r"\\\1", text)
