"""Refreshes the pictures in docs/ from the browser tests' screenshots, so that the manual
shows the UI as the tests last saw it:

    ./test.sh tests/browser            # (or the whole suite) writes test-artifacts/screenshots
    .venv/bin/python scripts/docs_screenshots.py [--from DIR]

Each docs picture and the screenshot it is a copy of: ``tests/support/browser.DOCS_SHOTS``.
A screenshot that is missing (its test did not run) leaves its picture as it was, and says so.
"""

from __future__ import annotations

import argparse
import os
import shutil
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)

from tests.support.browser import DOCS_SHOTS, SHOTS  # noqa: E402


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--from", dest="source", default=SHOTS, help="the screenshots' folder")
    args = ap.parse_args(argv)
    missing = 0
    for picture, shot in sorted(DOCS_SHOTS.items()):
        src = os.path.join(args.source, shot)
        if not os.path.exists(src):
            print(f"kept docs/{picture}: no {shot} in {args.source}")
            missing += 1
            continue
        shutil.copyfile(src, os.path.join(ROOT, "docs", picture))
        print(f"docs/{picture} <- {shot}")
    return 1 if missing == len(DOCS_SHOTS) else 0


if __name__ == "__main__":
    sys.exit(main())
