"""Translations: every user-facing string of the UI goes through gettext, the template
catalog is current, and the bundled German catalog is complete and compiled."""

import glob
import os
import re
import subprocess
import sys

import pytest
from babel.messages.mofile import read_mo
from babel.messages.pofile import read_po

from tests.support import ROOT

POT = os.path.join(ROOT, "translations", "messages.pot")
PO = os.path.join(ROOT, "translations", "de", "LC_MESSAGES", "messages.po")
BUNDLED = os.path.join(ROOT, "octoprint_kincomp", "translations", "de", "LC_MESSAGES")
PLACEHOLDER = re.compile(r"%\([a-z_]+\)s")
# what templates may show without gettext: axis/plane names, units' symbols, firmware names
ALLOWED_BARE = {
    "XY",
    "XZ",
    "YZ",
    "X",
    "Y",
    "Z",
    "AC",
    "BD",
    "AD",
    "+A",
    "−A",
    "+B",
    "−B",
    "Marlin",
    "Klipper",
    "RepRapFirmware",
}


def _ids(path, reader=read_po):
    with open(path, "rb") as f:
        return {m.id for m in reader(f) if m.id}


def test_template_catalog_is_current(tmp_path):
    out = tmp_path / "fresh.pot"
    subprocess.run(
        [
            sys.executable,
            "-m",
            "babel.messages.frontend",
            "extract",
            "-F",
            "babel.cfg",
            "-k",
            "N_",
            "-k",
            "gettext",
            "-k",
            "Msg",
            "-o",
            str(out),
            "--no-location",
            "--omit-header",
            ".",
        ],
        cwd=ROOT,
        check=True,
        capture_output=True,
    )
    fresh = _ids(out)
    assert len(fresh) > 100
    assert fresh == _ids(POT), "run scripts/translations.sh"


def test_german_catalog_is_complete_and_keeps_placeholders():
    with open(PO, "rb") as f:
        catalog = read_po(f, locale="de")
    assert not catalog.fuzzy
    ids = set()
    for m in catalog:
        if not m.id:
            continue
        ids.add(m.id)
        assert m.string, f"untranslated: {m.id!r}"
        assert "fuzzy" not in m.flags, m.id
        assert sorted(PLACEHOLDER.findall(m.id)) == sorted(PLACEHOLDER.findall(m.string)), m.id
    assert ids == _ids(POT)


# the informal address: its pronouns, and the du imperatives of the verbs the UI asks with
# (a sentence that starts with one of them without "Sie" after it)
_DU_WORDS = re.compile(r"\b(du|dich|dir|dein|deine|deinen|deinem|deiner|euch|euer)\b")
_DU_IMPERATIVE = re.compile(
    r"(?:^|[.:;!?]\s+|\(\s*)(Übernimm|Teste|Prüfe|Miss|Drück|Drücke|Wähl|Wähle|Lade|Lies|Gib|"
    r"Nimm|Schalte|Starte|Stell|Stelle|Setze|Öffne|Klick|Klicke|Speichere|Montiere|Entferne|"
    r"Warte|Plane|Trage|Halte|Sieh|Lass|Bestätige|Wiederhole|Vergleiche|Kalibriere|Verbinde|"
    r"Führe|Referenziere|Hake|Beginne|Tippe|Schließe|Ändere|Behalte)\b"
    r"(?!\s+Sie\b)"
)


def test_german_addresses_the_user_in_one_form():
    """Issue 35: "du" and "Sie" were mixed ("Übernimm ... teste dann erneut" in the wizard,
    "Teste erneut" after Apply). The UI says "Sie" throughout."""
    with open(PO, "rb") as f:
        catalog = read_po(f, locale="de")
    informal = [
        m.string
        for m in catalog
        if m.id and (_DU_WORDS.search(m.string) or _DU_IMPERATIVE.search(m.string))
    ]
    assert informal == []
    assert _DU_IMPERATIVE.search("Parameter übernommen. Teste erneut, um ...")  # (the check)
    assert _DU_IMPERATIVE.search("nicht zum aktiven: Verbinde diesen Drucker")
    assert not _DU_IMPERATIVE.search("Parameter übernommen. Testen Sie erneut.")


# units as text where the page writes symbols (a number or a placeholder before them)
_UNIT_AS_TEXT = re.compile(
    r"(?:\d|%\(\w+\)s) ?(?:um|deg)\b|(?<!%)\(um(?:/m)?\)|\+-|\^2|\s->\s|[<>]=|\bin um\b"
)


def test_messages_write_units_as_the_page_does():
    """Issue 35: analysis notes wrote "12 um", "+- 3", "1500 mm/s^2", "90 deg" and "<= 5"
    where the page shows µm, ±, mm/s², ° and words: no message of the catalog, English or
    German, does."""
    with open(PO, "rb") as f:
        catalog = read_po(f, locale="de")
    texts = [t for m in catalog if m.id for t in (m.id, m.string)]
    assert len(texts) > 1000
    assert [t for t in texts if _UNIT_AS_TEXT.search(t)] == []
    for bad in ("12 um rms", "(+- 3 ppm)", "1500 mm/s^2", "%(gap)s deg", "(um/m)", "a -> b"):
        assert _UNIT_AS_TEXT.search(bad), bad  # (the check)
    assert not _UNIT_AS_TEXT.search("Testen Sie erneut, um die Verbesserung zu sehen")


# one German term per thing: the term the catalog uses, and the variants it once mixed in
_ONE_TERM = {
    "Ballbar": ("Kugelstab",),
    "Prüfteil": ("Prüfkörper", "Pruefteil", "Pruefkoerper"),
    "erneut": ("Nachtest", "Wiederholungskampagne"),  # a re-test
}


def test_german_uses_one_term_per_thing():
    """Issue 35: "Kugelstab" and "Ballbar", "Pruefteil" and "Pruefkoerper" were both used."""
    with open(PO, "rb") as f:
        catalog = read_po(f, locale="de")
    german = "\n".join(m.string for m in catalog if m.id)
    for term, variants in _ONE_TERM.items():
        assert term in german, term
        for variant in variants:
            assert variant not in german, variant


def test_bundled_catalog_matches_the_sources():
    with open(PO, "rb") as a, open(os.path.join(BUNDLED, "messages.po"), "rb") as b:
        assert a.read() == b.read(), "run scripts/translations.sh compile"
    with open(PO, "rb") as f:
        po = {m.id: m.string for m in read_po(f, locale="de") if m.id}
    with open(os.path.join(BUNDLED, "messages.mo"), "rb") as f:
        mo = {m.id: m.string for m in read_mo(f) if m.id}
    assert mo == po


def test_jinja_renders_german():
    from babel.support import Translations

    t = Translations.load(os.path.join(ROOT, "octoprint_kincomp", "translations"), ["de"])
    assert t.gettext("KinComp calibration") != "KinComp calibration"
    assert t.gettext("Save KinComp settings") != "Save KinComp settings"


@pytest.mark.parametrize(
    "template",
    sorted(glob.glob(os.path.join(ROOT, "octoprint_kincomp", "templates", "*.jinja2"))),
    ids=os.path.basename,
)
def test_templates_have_no_bare_text(template):
    with open(template, encoding="utf-8") as f:
        text = f.read()
    text = re.sub(r"<!--.*?-->", " ", text, flags=re.S)
    text = re.sub(r"\{#.*?#\}", " ", text, flags=re.S)  # a Jinja comment is never shown
    text = re.sub(r"\{\{.*?\}\}", " ", text, flags=re.S)
    text = re.sub(r"\{%.*?%\}", " ", text, flags=re.S)
    text = re.sub(r"<[^>]*>", " ", text, flags=re.S)
    text = text.replace("&gt;", " ")
    bare = [w for w in re.split(r"[\s,.:;()/]+", text) if re.search(r"[A-Za-z]", w)]
    assert set(bare) <= ALLOWED_BARE, sorted(set(bare) - ALLOWED_BARE)


def test_core_messages_reach_the_user_in_german():
    """The core's errors and notes are English messages.Msg objects; with the bundled
    German catalog they come out German, placeholders and nested messages filled in."""
    from babel.support import Translations

    from octoprint_kincomp.calibration.ballbar.formats import TraceError, parse_summary
    from octoprint_kincomp.calibration.ballbar.program import ProgramError, TestSpec, check_bounds
    from octoprint_kincomp.core.messages import Msg, as_dict, error_message, translate
    from octoprint_kincomp.service.settings.schema import SettingsError, validate_settings

    de = Translations.load(os.path.join(ROOT, "octoprint_kincomp", "translations"), ["de"])
    with pytest.raises(SettingsError) as exc:
        validate_settings({"params": {"scale_ppm": {"y": 900000}}})
    assert str(exc.value).startswith("params.scale_ppm.y: 900000 is out of range")
    german = translate(error_message(exc.value), de.gettext)
    assert (
        german == "params.scale_ppm.y: 900000 liegt außerhalb des zulässigen Bereichs "
        "(zwischen -50000 und 50000)"
    )
    with pytest.raises(ProgramError) as exc:
        check_bounds(TestSpec(centre=(20, 100, 10), radius_mm=60), (0, 200, 0, 200, 0, 200))
    german = translate(error_message(exc.value), de.gettext)
    assert german.startswith("Der Kreis mit 60 mm Radius um 20,100,10 in XY passt nicht")
    assert "X erreicht -41.00 mm, unter der Grenze von 0 mm" in german
    with pytest.raises(TraceError) as exc:
        parse_summary(b"plane: XY\nsquareness_um_per_m: abc\n")
    assert "ist keine Zahl" in translate(error_message(exc.value), de.gettext)
    # what the browser gets: template and parameters, nested messages as such
    d = as_dict(Msg("%(first)s; %(rest)s", first=Msg("must be an object"), rest="x"))
    assert d["template"] == "%(first)s; %(rest)s"
    assert d["params"]["first"]["template"] == "must be an object"
    assert translate("plain text", de.gettext) == "plain text"
