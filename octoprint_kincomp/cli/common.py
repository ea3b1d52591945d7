"""What every verb of the command line shares: the error that ends a command with one line
on stderr, and the readers of numbers and params files given on the command line."""

from __future__ import annotations

import sys
from typing import List, Optional

from ..core.params import Params, ParamsError

EXIT_OK = 0
EXIT_ERROR = 1
# ``analyze``: the result was computed but a check found an error (``trusted`` false); its
# findings say why (docs/trust-checks.md). 2 is argparse's usage error.
EXIT_UNTRUSTED = 3


class CliError(Exception):
    """A user-facing error: printed as ``kincomp: error: <message>``, exit status 1."""


def floats(text: str, n: int, what: str) -> List[float]:
    try:
        vals = [float(v) for v in text.split(",")]
    except ValueError:
        raise CliError(f"{what}: expected {n} comma-separated numbers, got {text!r}") from None
    if len(vals) != n:
        raise CliError(f"{what}: expected {n} comma-separated numbers, got {len(vals)}")
    return vals


def load_params(path: Optional[str]) -> Params:
    if path is None:
        raise CliError("--params is required (create one with: params --init > P.json)")
    try:
        return Params.load(path)
    except ParamsError as exc:
        raise CliError(f"invalid params file {path}: {exc}") from None


def read_text(path: str) -> str:
    """The UTF-8 text of ``path``; a missing, unreadable or binary file is a CliError
    naming it."""
    try:
        with open(path, encoding="utf-8") as f:
            return f.read()
    except UnicodeDecodeError as exc:
        raise CliError(f"{path}: not a UTF-8 text file (byte {exc.start})") from None
    except OSError as exc:
        raise CliError(f"{path}: {exc.strerror}") from None


def write_text(path: Optional[str], text: str) -> None:
    """``text`` into ``path`` (``-`` or None: standard output); a path that cannot be
    written is a CliError naming it."""
    if path in (None, "-"):
        sys.stdout.write(text)
        return
    try:
        with open(path, "w", encoding="utf-8") as f:
            f.write(text)
    except OSError as exc:
        raise CliError(f"{path}: {exc.strerror}") from None
