#!/usr/bin/env bash
# Translations: extract every gettext string (Python N_/gettext, Jinja _(), JS gettext) into
# translations/messages.pot, merge it into translations/<locale>/LC_MESSAGES/messages.po,
# compile, and bundle .po (OctoPrint builds the browser's catalog from it) and .mo (Jinja
# and Python) into octoprint_kincomp/translations/.
#   scripts/translations.sh            extract + update + compile + bundle
#   scripts/translations.sh compile    compile + bundle only
set -euo pipefail
cd "$(dirname "$0")/.."
PY=${PY:-.venv/bin/python}
BABEL="$PY -m babel.messages.frontend"
if [ "${1:-}" != "compile" ]; then
    $BABEL extract -F babel.cfg -k N_ -k gettext -k Msg -o translations/messages.pot \
        --project KinComp --version "$($PY -c 'import octoprint_kincomp; print(octoprint_kincomp.__version__)')" \
        --msgid-bugs-address "" --no-location --omit-header --sort-output . >/dev/null
    $BABEL update -i translations/messages.pot -d translations --no-fuzzy-matching --ignore-obsolete --width 100 >/dev/null
fi
$BABEL compile -d translations --statistics
for po in translations/*/LC_MESSAGES/messages.po; do
    locale=$(basename "$(dirname "$(dirname "$po")")")
    dest=octoprint_kincomp/translations/$locale/LC_MESSAGES
    mkdir -p "$dest"
    cp "$po" "$dest/messages.po"
    cp "${po%.po}.mo" "$dest/messages.mo"
done
