"""Each setting is declared once (service/settings/schema.py SETTINGS): the defaults, the
checks, what a printer profile keeps, the settings page's fields and the template are
derived from it."""

import os
import re

from octoprint_kincomp.service.settings import schema
from tests.support import ROOT

TEMPLATE = os.path.join(ROOT, "octoprint_kincomp", "templates", "kincomp_settings.jinja2")
SCRIPT = os.path.join(ROOT, "octoprint_kincomp", "static", "js", "kincomp_settings.js")


def test_everything_about_a_setting_comes_from_its_declaration():
    keys = [s.key for s in schema.SETTINGS]
    assert list(schema.defaults()) == keys
    assert list(schema.CHECKS) == keys
    assert set(schema.PER_PROFILE) == {"params", "home_mm", "motion_limits", "steps_per_mm"}
    assert set(schema.INTERNAL_KEYS) == {"profile", "profiles", "legacy_profile"}
    for s in schema.SETTINGS:  # every default passes its own check unchanged
        assert s.check(schema.defaults()[s.key], s.key) == s.default, s.key


def test_every_declared_field_is_a_setting_and_has_a_valid_default():
    fields = schema.form_fields()
    assert len({f["id"] for f in fields}) == len(fields)
    doc = schema.defaults()
    for f in fields:
        assert f["path"].split(".")[0] in schema.BY_KEY
        value = doc
        for key in f["path"].split("."):
            value = value[key]
        assert f["kind"] in ("bool", "choice", "number", "optional_number")
        if f["kind"] == "choice":
            assert value in [c["value"] for c in f["choices"]]


def test_the_page_renders_and_reads_the_declared_fields_only():
    """The template renders the declaration (no field written by hand into it), and the
    page's script names no plain setting of its own."""
    template = open(TEMPLATE, encoding="utf-8").read()
    assert "plugin_kincomp_settings_fields" in template
    script = open(SCRIPT, encoding="utf-8").read()
    for f in schema.form_fields():
        key = f["path"].split(".")[-1]
        assert f'id="{f["id"]}"' not in template, f["id"]
        assert not re.search(r"\bs\.%s\b|loaded\.%s\b" % (key, key), script), key


def test_the_rendered_page_has_every_declared_field_bound_to_its_path():
    from tests.plugin.test_templates import _render

    html = _render("kincomp_settings.jinja2")
    for f in schema.form_fields():
        element = re.search(r'<(?:input|select)[^>]*id="%s"[^>]*>' % f["id"], html)
        assert element, f["id"]
        assert "settingsForm.value[&#39;%s&#39;]" % f["path"] in element.group(0), f["id"]
