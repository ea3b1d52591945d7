"""Errors of the compensator: a line that must not be sent as it would be written."""

from __future__ import annotations

from typing import Optional


class CompensationError(RuntimeError):
    """A line could not be compensated (the caller must not send the move uncompensated)."""

    def __init__(self, message: str, lineno: Optional[int] = None):
        self.lineno = lineno
        super().__init__(f"line {lineno}: {message}" if lineno else message)


class LimitError(CompensationError):
    """Policy ``error``: a compensated point falls outside the machine limits."""
