"""Each route is declared once, where it is handled (``http.route`` on a piece's method),
with the permissions it needs; the plugin's blueprint serves exactly those, and the manual's
route tables list each with its permission."""

import os
import re

from octoprint_kincomp.plugin import http
from octoprint_kincomp.plugin.kincomp_plugin import KinCompPlugin
from tests.support import ROOT
from tests.support.blueprint import blueprint_client

DOC_NAMES = {http.PLUGIN_KINCOMP_ADMIN: "KINCOMP_ADMIN"}


def _shape(rule):
    return re.sub(r"<[^>]*>", "<>", rule)


def _declared(plugin):
    return [route for piece in plugin.routed_pieces() for route, _ in http.routes_of(piece)]


def test_the_blueprint_serves_the_declared_routes_and_no_forwards(tmp_path):
    ns = blueprint_client(str(tmp_path))
    try:
        served = {
            (_shape(r.rule[len("/plugin/kincomp") :]), m)
            for r in ns.app.url_map.iter_rules()
            if r.rule.startswith("/plugin/kincomp/") and r.endpoint != "kincomp.static"
            for m in r.methods - {"HEAD", "OPTIONS"}
        }
        declared = {(_shape(r.rule), r.method) for r in _declared(ns.plugin)}
        assert len(declared) >= 36
        assert served == declared
        forwards = [n for n in vars(KinCompPlugin) if n.startswith("api_") and "error" not in n]
        assert forwards == [], "routes are declared by their pieces, not forwarded"
    finally:
        ns.stop()


def test_every_route_is_in_the_manual_with_its_permissions(tmp_path):
    ns = blueprint_client(str(tmp_path))
    try:
        routes = _declared(ns.plugin)
    finally:
        ns.stop()
    rows = []
    for page in ("http-api.md", "live-capture.md"):
        with open(os.path.join(ROOT, "docs", page), encoding="utf-8") as f:
            rows += [line for line in f if line.startswith("| `")]
    missing = []
    for r in routes:
        call = f"{r.method} {_shape(r.rule)}"
        row = next((row for row in rows if call in _shape(row)), None)
        needs = [DOC_NAMES.get(n, n) for n in r.needs]
        if row is None or not all(n in row.split("|")[2] for n in needs):
            missing.append((call, needs))
    assert missing == []
