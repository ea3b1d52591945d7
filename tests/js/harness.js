// Loads KinComp's web UI scripts into node with the libraries OctoPrint ships (lodash,
// knockout, sprintf: from the installed OctoPrint, KINCOMP_OCTOPRINT_LIB), gettext as the
// identity, and a window object: for the unit tests of the UI's logic (no browser, no DOM).
"use strict";
const path = require("node:path");
const vm = require("node:vm");
const fs = require("node:fs");

const LIB = process.env.KINCOMP_OCTOPRINT_LIB;
const STATIC = path.join(__dirname, "..", "..", "octoprint_kincomp", "static", "js");

function load(...files) {
    if (!LIB) throw new Error("KINCOMP_OCTOPRINT_LIB is not set (tests/release/test_js.py sets it)");
    const window = {};
    window.window = window;
    window.console = console;
    window.gettext = (text) => text;
    const context = vm.createContext(window);
    const run = (file) => vm.runInContext(fs.readFileSync(file, "utf8"), context, {filename: file});
    run(path.join(LIB, "lodash.min.js"));
    run(path.join(LIB, "knockout.js"));
    run(path.join(LIB, "sprintf.min.js"));
    window._.mixin({sprintf: window.sprintf});
    for (const f of files) run(path.join(STATIC, f));
    return window;
}

module.exports = {load};
