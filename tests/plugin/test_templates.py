"""The templates' links to the calibration tab (issue 25): the wizard and the settings page
link it with the class ``kincomp-open-tab``, which kincomp_navbar.js turns into one click
to the tab (tests/browser/test_first_hour.py clicks them in a real browser)."""

import os
import re

import jinja2
import pytest

from tests.support import ROOT

TEMPLATES = os.path.join(ROOT, "octoprint_kincomp", "templates")


def _render(name):
    # (OctoPrint finds a plugin's templates as plugin_<id>/<name>, as the includes say)
    files = jinja2.FileSystemLoader(TEMPLATES)
    env = jinja2.Environment(
        loader=jinja2.ChoiceLoader([files, jinja2.PrefixLoader({"plugin_kincomp": files})]),
        autoescape=True,
    )
    env.globals["_"] = lambda text, **kw: text
    from octoprint_kincomp.plugin.kincomp_plugin import KinCompPlugin

    # (as OctoPrint renders them: with the plugin's template variables, plugin_<id>_<key>)
    plugin_vars = {f"plugin_kincomp_{k}": v for k, v in KinCompPlugin().get_template_vars().items()}
    return env.get_template(name).render(**plugin_vars)


@pytest.mark.parametrize(
    "name", ["kincomp_wizard.jinja2", "kincomp_settings.jinja2", "kincomp_navbar.jinja2"]
)
def test_the_page_links_the_calibration_tab(name):
    html = _render(name)
    links = re.findall(r'<a [^>]*href="#tab_plugin_kincomp"[^>]*>', html)
    assert links and all("kincomp-open-tab" in a for a in links), links
    assert "KinComp" in html  # named as KinComp's


def test_the_navbar_entry_is_registered_and_its_script_loaded():
    from octoprint_kincomp.plugin.kincomp_plugin import KinCompPlugin

    p = KinCompPlugin()
    kinds = [c["type"] for c in p.get_template_configs()]
    assert "navbar" in kinds
    tab = next(c for c in p.get_template_configs() if c["type"] == "tab")
    assert "KinComp" in tab["name"]
    assert "js/kincomp_navbar.js" in p.get_assets()["js"]
