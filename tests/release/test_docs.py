"""The README and the manual in docs/ (issue 25): a README a new user reads (at most 250
lines: what KinComp is with one picture, the two set-up commands, installation, the first
calibration in numbered steps with one screenshot, what to read next), the manual's pages
linked from it and from the plugin's settings page, and no link into nowhere."""

import os
import re

import pytest

from tests.support import ROOT

DOCS = os.path.join(ROOT, "docs")
PAGES = [
    "user-guide",
    "calibration",
    "live-capture",
    "command-line",
    "http-api",
    "firmware-export",
    "how-compensation-works",
    "architecture",
    "tests",
    "performance",
    "trust-checks",
    "motion-limits",
    "untrusted-results",
    "artifact",
    "reliability",
    "compensation-details",
    "printer-profiles",
    "travel-edges",
    "klipper",
    "marlin",
    "reprapfirmware",
]
LINK = re.compile(r"\]\(([^)\s]+)\)")


def _read(path):
    with open(path, encoding="utf-8") as f:
        return f.read()


def _anchors(text):
    """GitHub's heading anchors of a Markdown page (outside code blocks)."""
    out, fence = set(), False
    for line in text.splitlines():
        if line.startswith("```"):
            fence = not fence
        m = None if fence else re.match(r"^#{1,6} (.*)", line)
        if m:
            slug = re.sub(r"[^\w\- ]", "", m.group(1).strip().lower()).replace(" ", "-")
            out.add(slug)
    return out


def test_the_readme_is_short_and_has_what_a_new_user_needs():
    text = _read(os.path.join(ROOT, "README.md"))
    assert len(text.splitlines()) <= 250
    assert "./run.sh      # the main job" in text
    assert "./test.sh     # the whole test suite" in text
    steps = re.findall(
        r"^(\d+)\. ",
        text.split("## Your first calibration in 5 minutes")[1].split("\n## ")[0],
        re.M,
    )
    assert steps == [str(n) for n in range(1, len(steps) + 1)] and len(steps) >= 4
    assert len(re.findall(r"!\[[^\]]*\]\(docs/[^)]+\.png\)", text)) == 2  # picture + shot
    nxt = text.split("## What to read next")[1]
    for page in PAGES:
        assert f"(docs/{page}.md)" in nxt, page


@pytest.mark.parametrize("name", ["README.md"] + [f"docs/{p}.md" for p in PAGES])
def test_every_relative_link_and_anchor_resolves(name):
    path = os.path.join(ROOT, name)
    text = _read(path)
    for target in LINK.findall(text):
        if re.match(r"^[a-z]+:", target) or target.startswith("#") and not target[1:]:
            continue
        file, _, anchor = target.partition("#")
        dest = os.path.normpath(os.path.join(os.path.dirname(path), file)) if file else path
        assert os.path.exists(dest), f"{name}: {target}"
        if anchor and dest.endswith(".md"):
            assert anchor in _anchors(_read(dest)), f"{name}: {target}"


def test_the_settings_page_links_the_manual():
    js = _read(os.path.join(ROOT, "octoprint_kincomp", "static", "js", "kincomp_common.js"))
    listed = re.findall(r'\["([a-z-]+)", gettext\(', js)
    assert listed and all(p in PAGES for p in listed)
    for page in listed:
        assert os.path.exists(os.path.join(DOCS, page + ".md")), page


def test_every_picture_in_the_docs_is_a_browser_tests_screenshot():
    """docs/*.png are copies of screenshots the browser tests take (scripts/docs_screenshots.py
    refreshes them): each is listed with its screenshot, and that screenshot's name is written
    by a browser test."""
    from tests.support.browser import DOCS_SHOTS

    pictures = {n for n in os.listdir(DOCS) if n.endswith(".png")}
    assert pictures == set(DOCS_SHOTS)
    browser = os.path.join(ROOT, "tests", "browser")
    sources = "".join(
        _read(os.path.join(browser, n)) for n in os.listdir(browser) if n.endswith(".py")
    )
    for shot in DOCS_SHOTS.values():
        assert f'"{shot}"' in sources, shot
