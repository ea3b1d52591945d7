"""The plugin repository entry extras/kincomp.md (issue 14): the front matter the OctoPrint
plugin repository reads (plugins.octoprint.org ``_plugins/<id>.md``), consistent with the
package (identifier, description, homepage, license, supported versions) and with screenshots
that exist in docs/."""

import datetime
import os
import re

import pytest
import yaml

import octoprint_kincomp

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
ENTRY = os.path.join(ROOT, "extras", "kincomp.md")
REQUIRED = (
    "layout",
    "id",
    "title",
    "description",
    "authors",
    "license",
    "date",
    "homepage",
    "source",
    "archive",
    "tags",
    "screenshots",
    "featuredimage",
    "compatibility",
    "attributes",
)
OS_VALUES = {"linux", "windows", "macos", "freebsd"}
ATTRIBUTES = {"cloud", "commercial", "free-tier", "ai-developed"}  # the repository's badges


@pytest.fixture(scope="module")
def entry():
    with open(ENTRY, encoding="utf-8") as f:
        text = f.read()
    m = re.match(r"---\n(.*?)\n---\n(.*)\Z", text, re.S)
    assert m, "front matter between two --- lines, then the long description"
    return yaml.safe_load(m.group(1)), m.group(2)


def _pyproject():
    with open(os.path.join(ROOT, "pyproject.toml"), encoding="utf-8") as f:
        return f.read()


def test_front_matter_has_the_keys_of_the_plugin_repository(entry):
    meta, body = entry
    assert [k for k in REQUIRED if k not in meta] == []
    assert meta["layout"] == "plugin"
    assert isinstance(meta["date"], datetime.date)
    assert isinstance(meta["authors"], list) and all(isinstance(a, str) for a in meta["authors"])
    assert meta["tags"] and all(isinstance(t, str) and t == t.lower() for t in meta["tags"])
    assert set(meta["attributes"]) <= ATTRIBUTES
    assert len(body.strip()) > 500


def test_entry_agrees_with_the_package(entry):
    meta, body = entry
    # the identifier OctoPrint registers the plugin under (the entry point's name)
    assert 'kincomp = "octoprint_kincomp"' in _pyproject() and meta["id"] == "kincomp"
    assert meta["title"] == octoprint_kincomp.__plugin_name__
    assert meta["description"] == octoprint_kincomp.__plugin_description__
    assert meta["license"] == octoprint_kincomp.__plugin_license__
    assert meta["authors"] == [octoprint_kincomp.__plugin_author__]
    url = octoprint_kincomp.__plugin_url__
    assert meta["homepage"] == url and meta["source"] == url
    assert meta["archive"] == url + "/archive/main.zip"
    assert url + "#readme" in body


def test_compatibility_is_what_the_package_claims_and_tests(entry):
    compat = entry[0]["compatibility"]
    assert compat["python"] == octoprint_kincomp.__plugin_pythoncompat__
    assert f'requires-python = "{compat["python"]}"' in _pyproject()
    (octoprint,) = compat["octoprint"]
    low = re.match(r">=(\d+\.\d+\.\d+)", octoprint).group(1)
    assert f'"OctoPrint>={low}"' in _pyproject()
    # the oldest line the compatibility test runs (tests/e2e/test_compat.py)
    from tests.e2e.test_compat import OLDEST

    assert low.startswith(OLDEST + ".")
    assert set(compat["os"]) <= OS_VALUES


def test_screenshots_exist_in_docs(entry):
    meta, _ = entry
    raw = (
        octoprint_kincomp.__plugin_url__.replace(
            "https://github.com/", "https://raw.githubusercontent.com/"
        )
        + "/main/"
    )
    urls = []
    for shot in meta["screenshots"]:
        assert set(shot) == {"url", "alt", "caption"} and shot["alt"] and shot["caption"]
        assert shot["url"].startswith(raw + "docs/") and shot["url"].endswith(".png")
        path = os.path.join(ROOT, shot["url"][len(raw) :])
        assert os.path.isfile(path), path
        with open(path, "rb") as f:
            assert f.read(8) == b"\x89PNG\r\n\x1a\n"
        urls.append(shot["url"])
    assert len(urls) == len(set(urls)) >= 3
    assert meta["featuredimage"] in urls
