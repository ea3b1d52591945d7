"""How KinComp splits text into lines and puts compensated lines back (one definition for
the file readers): a line ends with ``\\r\\n``, ``\\n`` or a lone ``\\r`` (Python's universal
newlines); lines a move expands into all take the ending of the line they came from (``\\n``
for a last line that had none)."""

import re
from typing import List, Tuple

UNIVERSAL = re.compile(r"[^\r\n]*(?:\r\n|\r|\n)|[^\r\n]+\Z")


def split_ending(raw: str) -> Tuple[str, str]:
    if raw.endswith("\r\n"):
        return raw[:-2], "\r\n"
    if raw.endswith(("\n", "\r")):
        return raw[:-1], raw[-1]
    return raw, ""


def join_output(out: List[str], ending: str) -> str:
    """Replacement lines of one input line, each with the input line's ending."""
    nl = ending or "\n"
    text = nl.join(out)
    return text + ending if ending else text
