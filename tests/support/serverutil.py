"""Helpers for tests against a real OctoPrint server (the ``server`` fixture in
tests/conftest.py): settings and status through KinComp's API, serial.log ``Send:`` lines,
the offline reference compensation, and a cookie/CSRF browser-like session."""

import dataclasses
import os
import re
import time
import uuid

from octoprint_kincomp.service.printing.queue import QueueCompensator, command_of
from octoprint_kincomp.service.settings.schema import engine_config
from tests.support import DATA as DATA

# commands OctoPrint sends by itself (polls, handshake): not part of what a test sent
# the motion codes as a stream spells them (what KinComp rewrites)
MOTION = ("G0", "G1", "G2", "G3", "G00", "G01", "G02", "G03")
AUTOMATIC = {"M105", "M27", "M155", "M110", "M115", "M20", "M21", "M400", "M114", "M503"}
_SEND = re.compile(r" - Send: (?:N\d+ )?(.*?)(?:\*\d+)?$")
_SEND_N = re.compile(r" - Send: N(\d+) ")


def rationed(srv, method, path, body=None, key="admin", timeout=60.0):
    """``srv.request``, asked again as a 429's ``Retry-After`` says (KinComp rations its
    requests while a print runs: service/request_gate.py)."""
    deadline = time.time() + timeout
    while True:
        code, resp = srv.request(method, path, body, key=key)
        if code != 429 or time.time() > deadline:
            return code, resp
        time.sleep(1.0)


def settings(srv, **values):
    """POST /plugin/kincomp/settings (admin), applied at once; returns the new settings."""
    status, body = rationed(srv, "POST", "/plugin/kincomp/settings", dict(values, apply_now=True))
    assert status == 200, body
    return body["settings"]


def status(srv):
    code, body = rationed(srv, "GET", "/plugin/kincomp/status")
    assert code == 200, body
    return body


_POSITION = re.compile(r"Recv: (?:ok )?X:(-?[\d.]+) Y:(-?[\d.]+) Z:(-?[\d.]+)")


def home_reports(srv, after: str):
    """The positions (x, y, z in mm) the printer answered to the ``M114`` lines sent after
    the line ``after``, in order: where KinComp learned an unknown home. (The virtual
    printer homes at once, without waiting for the moves it still simulates, so the answer
    after a ``G28`` right behind a move can be that move's end, not 0.)"""
    log = srv.serial_log()
    lines = log[log.rindex("Send: " + after) :].splitlines()
    out = []
    for i, line in enumerate(lines):
        send = _SEND.search(line)
        if send and send.group(1) == "M114":
            found = next((m for m in map(_POSITION.search, lines[i + 1 : i + 40]) if m), None)
            assert found is not None, line
            out.append(tuple(float(v) for v in found.groups()))
    return out


def offline(srv, lines, reports=None):
    """What the plugin should send for ``lines`` (comment-stripped commands) from a fresh
    compensator with the server's current settings: the reference for the Send: lines.
    ``reports`` (from :func:`home_reports`): the printer's answers to the M114 KinComp
    sends after a G28 whose home is not set, each taken right behind its G28 as the plugin
    takes it; without them the home is taken where the virtual printer homes (0, 0, 0)."""
    st = status(srv)
    limits = tuple(st["limits"]) if st["limits"] else None
    params, options = engine_config(st["settings"], limits)
    if reports is None:
        options = dataclasses.replace(
            options, home_mm=tuple(0.0 if h is None else h for h in options.home_mm)
        )
    queue = QueueCompensator(params, options, enabled=True)
    answers = iter(reports or ())
    out = []
    for line in lines:
        res = queue.handle(line)
        for r in [line] if res is None else res:
            if not isinstance(r, str):  # KinComp's M114: answered now
                queue.home_query_sent(r[2])
                assert queue.home_reported(dict(zip("xyz", next(answers))))
            out.append(command_of(r))
    return out


def marker(srv) -> str:
    """Send a unique M117 and wait until it is in serial.log; returns it."""
    text = f"M117 kincomp-e2e-{uuid.uuid4().hex[:8]}"
    code, _ = srv.request("POST", "/api/printer/command", {"commands": [text]})
    assert code == 204
    wait_for_send(srv, text)
    return text


def wait_for_send(srv, text, timeout=30.0):
    deadline = time.time() + timeout
    while time.time() < deadline:
        if any(text == s for s in sent(srv)):
            return
        time.sleep(0.1)
    raise AssertionError(f"{text!r} never sent")


def sent(srv, after: str = None, until: str = None, automatic=False):
    """The commands of serial.log's Send: lines (line numbers and checksums removed),
    resends dropped (a repeated line number), OctoPrint's own polls dropped unless
    ``automatic``; only those after the line ``after`` and before ``until``."""
    out, seen_n = [], set()
    for line in srv.serial_log().splitlines():
        m = _SEND.search(line)
        if not m:
            continue
        cmd = m.group(1)
        n = _SEND_N.search(line)
        if cmd.startswith("M110"):
            seen_n.clear()  # line numbers start again
        elif n:
            if n.group(1) in seen_n:
                continue  # a resend: the same bytes again, not a new command
            seen_n.add(n.group(1))
        out.append(cmd)
    if after is not None:
        out = out[len(out) - out[::-1].index(after) :]
    if until is not None:
        out = out[: out.index(until)]
    if not automatic:
        out = [c for c in out if c.split(" ", 1)[0] not in AUTOMATIC]
    return out


class BrowserSession:
    """Cookie-based client like the web UI: session cookie after login, CSRF double
    cookie (the X-CSRF-Token header must echo the csrf_token cookie), no API key."""

    def __init__(self, srv):
        import http.cookiejar
        import urllib.request

        self.srv = srv
        self.jar = http.cookiejar.CookieJar()
        self.opener = urllib.request.build_opener(urllib.request.HTTPCookieProcessor(self.jar))
        self.open("GET", "/")  # sets the CSRF cookie

    def csrf(self):
        for c in self.jar:
            if c.name.startswith("csrf_token"):
                return c.value
        return None

    def open(self, method, path, body=None, csrf=True, raw=None, content_type=None):
        import urllib.error
        import urllib.request

        from octoprint_kincomp.tools.devserver import request_body

        headers = {}
        data = request_body(headers, body, raw, content_type)
        token = self.csrf()
        if csrf and token:
            headers["X-CSRF-Token"] = token
        req = urllib.request.Request(self.srv.url + path, data=data, method=method, headers=headers)
        try:
            with self.opener.open(req, timeout=60) as resp:
                return resp.status, resp.read().decode("utf-8", "replace")
        except urllib.error.HTTPError as exc:
            return exc.code, exc.read().decode("utf-8", "replace")

    def login(self, user, password):
        code, text = self.open(
            "POST", "/api/login", {"user": user, "pass": password, "remember": False}
        )
        assert code == 200, text
        return self


def half_upload(srv, path, size, key="admin"):
    """Starts a multipart upload of ``size`` bytes to ``path`` and sends half of it; returns
    the open socket (the server is writing the upload's temporary file meanwhile: a test
    kills it then)."""
    import socket

    boundary = "kincomphalf"
    head = (
        f'--{boundary}\r\nContent-Disposition: form-data; name="file"; filename="half.csv"\r\n'
        "Content-Type: text/csv\r\n\r\n"
    ).encode()
    total = len(head) + size + len(f"\r\n--{boundary}--\r\n")
    sock = socket.create_connection(("127.0.0.1", srv.port))
    sock.sendall(
        (
            f"POST {path} HTTP/1.1\r\nHost: 127.0.0.1\r\n"
            f"X-Api-Key: {srv.logins[key]['apikey']}\r\n"
            f"Content-Type: multipart/form-data; boundary={boundary}\r\n"
            f"Content-Length: {total}\r\n\r\n"
        ).encode()
        + head
        + b"t,x\n" * (size // 8)
    )
    return sock


# -- the shared server's printer settings ------------------------------------------------------

# the commands that change the virtual printer's settings (its EEPROM in memory): steps,
# feed and acceleration limits, jerk, home offset, probe offset, and storing them
_SETTINGS_SENT = re.compile(r" - Send: (?:N\d+ )?M(?:92|20[1-6]|500|502|566|851)(?![\d.])")


def _serial_log_path(srv) -> str:
    return os.path.join(srv.basedir, "logs", "serial.log")


def serial_log_size(srv) -> int:
    try:
        with open(_serial_log_path(srv), "rb") as f:
            return f.seek(0, 2)
    except FileNotFoundError:
        return 0


def settings_sent_since(srv, offset: int) -> bool:
    """Whether a command that changes the printer's settings went out after ``offset`` (bytes
    of serial.log): a printed slicer file's M201/M203/M204/M205 stay in the virtual printer
    after the print, as on a real Marlin, for every later test on the same server."""
    try:
        with open(_serial_log_path(srv), "rb") as f:
            f.seek(offset)
            tail = f.read().decode("utf-8", "replace")
    except FileNotFoundError:
        return False
    return _SETTINGS_SENT.search(tail) is not None


def motion_limits(srv, timeout=60.0):
    """``status.motion_limits`` once KinComp has read the printer's M503 answer."""
    deadline = time.monotonic() + timeout
    while True:
        ml = status(srv)["motion_limits"]
        if ml["stated"]["source"] == "m503":
            return ml
        assert time.monotonic() < deadline, f"no M503 answer stored: {ml}"
        time.sleep(0.2)


def printer_limits(srv, timeout=60.0):
    """KinComp's reading of the printer's M503 answer (``status.motion_limits.read``)."""
    return motion_limits(srv, timeout)["read"]


def printer_eeprom_path(srv) -> str:
    """The virtual printer's EEPROM file (made with its defaults when it first starts)."""
    return os.path.join(srv.basedir, "data", "virtual_printer", "eeprom.json")


def put_back_printer_settings(srv, eeprom: bytes, wanted, timeout=120.0):
    """The virtual printer's settings back as they were (``eeprom``: its EEPROM file then;
    a printed file may have stored its own with M500, as the A1 start code does), read
    again with M501, and KinComp's reading of them with it (``POST /limits/read``; ``wanted``:
    that reading then), once the printer is idle."""
    srv.wait_state("Operational", timeout)
    with open(printer_eeprom_path(srv), "wb") as f:
        f.write(eeprom)
    code, body = srv.request("POST", "/api/printer/command", {"commands": ["M501"]})
    assert code == 204, body
    code, body = rationed(srv, "POST", "/plugin/kincomp/limits/read", {})
    assert code == 202, body
    deadline = time.monotonic() + timeout
    while printer_limits(srv) != wanted:
        assert time.monotonic() < deadline, (
            f"the printer's settings did not come back: {printer_limits(srv)} != {wanted}"
        )
        time.sleep(0.3)
