"""JSON documents: reading one from a file (every failure an error that names the file) and writing
one as every JSON reader takes it."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

__all__ = ["json_text", "read_json"]


class _RepeatedKeyError(ValueError):
    """A key given twice in one JSON object."""


def _unique_keys(pairs: list[tuple[str, Any]]) -> dict[str, Any]:
    seen: dict[str, Any] = {}
    for key, value in pairs:
        if key in seen:
            raise _RepeatedKeyError(key)
        seen[key] = value
    return seen


def read_json(path: str | Path, error: type[Exception], *, where: str, missing: str) -> Any:
    """The JSON document in ``path``.

    Parameters
    ----------
    path : str or Path
        The JSON file.
    error : type of Exception
        The exception raised on any problem.
    where : str
        How the messages name the file.
    missing : str
        The whole message when the file does not exist.

    Raises
    ------
    error
        ``missing`` when there is no such file; ``where`` followed by the line and column of invalid
        JSON, by a key given twice in one object (JSON readers keep the last, and a plant file's group
        written twice would lose the first's values without a word), or by why the file cannot be read (a
        folder, no permission, not UTF-8).
    """
    try:
        return json.loads(Path(path).read_text(encoding="utf-8"), object_pairs_hook=_unique_keys)
    except _RepeatedKeyError as exc:
        raise error(f"{where}: key {exc.args[0]!r} is given twice in one object; JSON keeps only the last, so "
                    "the first one's values would be lost: write them once") from None
    except FileNotFoundError:
        raise error(missing) from None
    except json.JSONDecodeError as exc:
        raise error(f"{where}: not valid JSON (line {exc.lineno}, column {exc.colno}): {exc.msg}") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise error(f"{where}: cannot read: {exc}") from None


def _finite_or_named(value: Any) -> Any:
    if isinstance(value, float) and not math.isfinite(value):
        return "nan" if math.isnan(value) else ("inf" if value > 0 else "-inf")
    if isinstance(value, dict):
        return {k: _finite_or_named(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_finite_or_named(v) for v in value]
    return value


def json_text(document: Any, **options: Any) -> str:
    """``document`` as strict JSON text (``json.dumps`` with ``options``), a newline at its end.

    A non-finite float (an unbounded box entry, ``-inf``) is written as the string ``"inf"``,
    ``"-inf"`` or ``"nan"``: Python's ``json`` would write ``Infinity``, which is not JSON (JavaScript's
    ``JSON.parse`` refuses it, jq turns it into 1.8e308). ``float()`` reads the strings back, and
    :func:`~tapmuscle.io.identification_file.read_identification` takes a box's ``"-inf"`` / ``"inf"`` as
    no bound. (The diagnosis reports, whose numbers are measured values, write null and a note instead:
    :func:`tapmuscle.diagnosis.report.json_text`.)

    Parameters
    ----------
    document : object
        The JSON-serialisable document.
    **options
        Keyword arguments of :func:`json.dumps` (``indent``, ``sort_keys``, ...; not
        ``allow_nan``).
    """
    return json.dumps(_finite_or_named(document), allow_nan=False, **options) + "\n"
