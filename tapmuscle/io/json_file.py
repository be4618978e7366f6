"""Reading a JSON document from a file, every failure an error that names the file."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

__all__ = ["read_json"]


def read_json(path: str | Path, error: type[Exception], *, where: str, missing: str) -> Any:
    """The JSON document in ``path``.

    Raises
    ------
    error
        ``missing`` when there is no such file; ``where`` followed by the line and column of invalid
        JSON, or by why the file cannot be read (a folder, no permission, not UTF-8).
    """
    try:
        return json.loads(Path(path).read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise error(missing) from None
    except json.JSONDecodeError as exc:
        raise error(f"{where}: not valid JSON (line {exc.lineno}, column {exc.colno}): {exc.msg}") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise error(f"{where}: cannot read: {exc}") from None
