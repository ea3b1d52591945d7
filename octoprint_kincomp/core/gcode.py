"""G-code line parsing and number formatting shared by the compensator and the simulator.

A line is ``[N<n>] <code> <words...> [*<checksum>] [; comment]``. Codes and words may be
lowercase, packed (``G1X10Y5``) or oddly spaced. Parsing never raises: a line that is not
well-formed G-code comes back as ``None`` from :func:`parse_words` and is passed through.
"""

from __future__ import annotations

import re
from typing import List, NamedTuple, Optional, Tuple

# ASCII only (re.ASCII): a firmware reads bytes, and "X١٢٣" (Arabic-Indic digits) or a
# no-break space is no number or separator to it, though Python's \d, \s and float() take
# them. Such a line is malformed and passes as written, as in the compiled kernel, which
# works on the bytes.
_LINENO = re.compile(r"\s*[Nn]\s*\d+\s*", re.ASCII)
_CODE = re.compile(r"\s*([GgMmTt])\s*(\d+)(?:\.(\d+))?", re.ASCII)
_WORD = re.compile(r"\s*([A-Za-z])\s*([-+]?(?:\d+\.?\d*|\.\d+))", re.ASCII)
# a body as slicers write it: words of a letter and a number (_WORD's), each after one space
_PLAIN_BODY = re.compile(r"(?: [A-Za-z][-+]?(?:\d+\.?\d*|\.\d+))*", re.ASCII)
_BARE_LETTER = re.compile(r"\s*([A-Za-z])(?=\s|$)", re.ASCII)
_CHECKSUM = re.compile(r"\*\s*\d*\s*$", re.ASCII)
# Larger numbers are no coordinate: a 309-digit one is inf, and from ~1e154 on the squares of
# path lengths overflow (float ** raises OverflowError). The compensator's fast path accepts at
# most 99 integer digits, which stays below this.
MAX_WORD_VALUE = 1e100


class Word(NamedTuple):
    letter: str  # upper case
    value: Optional[float]  # None for a bare letter ("G28 X")
    text: str  # the token as written, without surrounding spaces


class Command(NamedTuple):
    """A parsed command line.

    ``kind`` is the upper-case letter (G, M, T), ``number``/``sub`` the code (``G29.2`` ->
    29, 2; ``sub`` is None without a dot), ``code_text`` the code as written (``G01``, ``g1``),
    ``body`` the text after the code (words) without checksum, ``comment`` the trailing
    comment including ``;`` (or ``""``), ``numbered`` whether a line number or checksum was
    stripped.
    """

    kind: str
    number: int
    sub: Optional[int]
    code_text: str
    body: str
    comment: str
    numbered: bool


def split_comment(line: str) -> Tuple[str, str]:
    """(code part, comment part starting at ';' or '')."""
    idx = line.find(";")
    if idx < 0:
        return line, ""
    return line[:idx], line[idx:]


def parse_command(line: str) -> Optional[Command]:
    """Split a line into code, words text and comment; None for comments/blank/unknown."""
    code, comment = split_comment(line)
    numbered = False
    if code.lstrip()[:1] in ("N", "n"):  # (most lines carry no line number)
        m = _LINENO.match(code)
        if m:
            code = code[m.end() :]
            numbered = True
    star = code.rfind("*")
    if star >= 0 and _CHECKSUM.match(code, star):
        code = code[:star]
        numbered = True
    m = _CODE.match(code)
    if not m:
        return None
    kind, number, sub = m.groups()
    end = m.end()
    return Command(
        kind=kind.upper(),
        number=int(number),
        sub=int(sub) if sub is not None else None,
        code_text=code[:end].strip(),
        body=code[end:],
        comment=comment,
        numbered=numbered,
    )


def parse_words(body: str, allow_bare: bool = False) -> Optional[List[Word]]:
    """Words of a command body; None when the body is not clean G-code.

    A repeated letter, stray characters, a number beyond +-``MAX_WORD_VALUE`` or (unless
    ``allow_bare``) a letter without a number make the body malformed.
    """
    if _PLAIN_BODY.fullmatch(body):
        return _plain_words(body)
    return _scan_words(body, allow_bare)


def _scan_words(body: str, allow_bare: bool) -> Optional[List[Word]]:
    """:func:`parse_words` word by word (any body)."""
    words: List[Word] = []
    seen = set()
    pos = 0
    n = len(body)
    while pos < n:
        m = _WORD.match(body, pos)
        if m:
            letter = m.group(1).upper()
            value = float(m.group(2))
            if not abs(value) < MAX_WORD_VALUE:
                return None
            text = body[m.start(1) : m.end()]
        else:
            m = _BARE_LETTER.match(body, pos) if allow_bare else None
            if not m:
                if body[pos:].strip() == "":
                    break
                return None
            letter = m.group(1).upper()
            value = None
            text = m.group(1)
        if letter in seen:
            return None
        seen.add(letter)
        words.append(Word(letter, value, text))
        pos = m.end()
    return words


def _plain_words(body: str) -> Optional[List[Word]]:
    """:func:`parse_words` of a body as slicers write it (``_PLAIN_BODY``: each word one
    space, a letter and a number): its words are the body split on spaces, as the word by
    word scan finds them (the number is the whole rest of the word: nothing can follow it)."""
    words: List[Word] = []
    letters = ""  # the letters so far
    for text in body.split():
        value = float(text[1:])
        if not -MAX_WORD_VALUE < value < MAX_WORD_VALUE:
            return None
        letter = text[0].upper()
        if letter in letters:
            return None
        letters += letter
        words.append(Word(letter, value, text))
    return words


def fmt(value: float, decimals: int) -> str:
    """Shortest text of ``value`` rounded to ``decimals`` places, as slicers write numbers:
    no trailing zeros, no bare dot (``10.5``, ``10``), never ``-0`` and never exponents."""
    text = f"{value:.{decimals}f}"
    if decimals > 0:
        text = text.rstrip("0").rstrip(".")
    if text == "-0":
        return "0"
    return text


def decimals_of(text: str) -> int:
    """Number of decimals written in a numeric token ("E1.2345" -> 4, "E5" -> 0)."""
    dot = text.find(".")
    if dot < 0:
        return 0
    end = dot + 1
    while end < len(text) and "0" <= text[end] <= "9":
        end += 1
    return end - dot - 1


def checksum(command: str) -> int:
    """RepRap line checksum: XOR of all bytes of ``N<n> <command>``."""
    cs = 0
    for ch in command.encode("ascii", "replace"):
        cs ^= ch
    return cs
