"""What every verb of the command line shares: the error that ends a command with one line
on stderr, and the readers of numbers and params files given on the command line."""

from __future__ import annotations

from typing import List, Optional

from ..core.params import Params, ParamsError

EXIT_OK = 0
EXIT_ERROR = 1


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
