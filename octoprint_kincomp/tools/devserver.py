"""A local OctoPrint with the virtual printer and KinComp: the README's main job and the
end-to-end tests' server.

``prepare`` writes a basedir (127.0.0.1 only, no first-run wizard, no online checks, the
virtual printer on, ``serial.log`` on, an admin and a non-admin user with API keys);
``DevServer`` starts ``octoprint serve`` on it and stops it again; ``python`` picks another
environment's OctoPrint (the compatibility test runs the oldest supported one).
``python -m octoprint_kincomp demo-server`` is the interactive version (demo mode on: the
virtual printer gets hidden SIMULATED errors and a virtual ballbar).
"""

from __future__ import annotations

import http.client
import json
import os
import secrets
import shutil
import signal
import socket
import subprocess
import sys
import time
import urllib.error
import urllib.request
from typing import Any, Dict, Optional, Sequence

import yaml

ADMIN = "admin"
VIEWER = "viewer"
# a test user who may change OctoPrint's settings but lacks KinComp's admin permission
SETTINGS_ONLY = "settingsonly"
# a test user of OctoPrint's read-only group (status, file list: may ask for dry runs)
READER = "reader"
# `octoprint user add` flags of the users a basedir can get
USER_FLAGS = {
    ADMIN: ["--admin"],
    VIEWER: [],
    SETTINGS_ONLY: ["-p", "SETTINGS", "-p", "SETTINGS_READ", "-p", "STATUS"],
    READER: ["-g", "readonly"],
}
SERVER_OUT = "server.out"  # OctoPrint's own output (stdout and stderr), in the basedir


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _octoprint_cmd(python: Optional[str] = None) -> list:
    """The ``octoprint`` command of the environment of ``python`` (default: this one)."""
    python = python or sys.executable
    exe = os.path.join(os.path.dirname(python), "octoprint")
    if os.path.exists(exe):
        return [exe]
    return [python, "-m", "octoprint"]


def prepare(
    basedir: str,
    port: int,
    kincomp: Optional[Dict[str, Any]] = None,
    throttle: float = 0.0,
    password: Optional[str] = None,
    extra_config: Optional[Dict[str, Any]] = None,
    users: Sequence[str] = (ADMIN, VIEWER),
    demo: Optional[bool] = None,
    python: Optional[str] = None,
) -> Dict[str, str]:
    """Create (or refresh) a basedir; returns the logins {user: (password, apikey)}.

    ``kincomp`` replaces KinComp's stored settings (a fresh test server); ``demo`` only
    switches demo mode and keeps everything else the user saved."""
    os.makedirs(basedir, exist_ok=True)
    cfg_path = os.path.join(basedir, "config.yaml")
    config: Dict[str, Any] = {}
    if os.path.exists(cfg_path):
        with open(cfg_path) as f:
            config = yaml.safe_load(f) or {}
    server = config.setdefault("server", {})
    server.update(
        {
            "host": "127.0.0.1",
            "port": port,
            "firstRun": False,
            "onlineCheck": {"enabled": False},
            "pluginBlacklist": {"enabled": False},
            "seenWizards": {"kincomp": 1, "corewizard": 4, "backup": None, "tracking": None},
        }
    )
    plugins = config.setdefault("plugins", {})
    plugins.setdefault("virtual_printer", {}).update({"enabled": True, "throttle": throttle})
    plugins["tracking"] = {"enabled": False}
    plugins["errortracking"] = {"enabled": False}
    # offline machine: no update checks, feeds or health checks that need the internet;
    # no achievement pop-ups covering the page in screenshots
    plugins["_disabled"] = [
        "announcements",
        "softwareupdate",
        "health_check",
        "tracking",
        "errortracking",
        "pluginmanager",
        "achievements",
    ]
    if kincomp is not None:
        plugins["kincomp"] = kincomp
    if demo is not None:
        plugins.setdefault("kincomp", {})["demo"] = {"enabled": demo}
    config.setdefault("serial", {}).update({"log": True, "autoconnect": False})
    config.setdefault("temperature", {})["profiles"] = []
    if extra_config:
        for k, v in extra_config.items():
            config.setdefault(k, {}).update(v)
    with open(cfg_path, "w") as f:
        yaml.safe_dump(config, f)

    logins_path = os.path.join(basedir, "kincomp-logins.json")
    if os.path.exists(logins_path):
        with open(logins_path) as f:
            logins = json.load(f)
    else:
        logins = {}
    env = dict(os.environ, PYTHONDONTWRITEBYTECODE="1")
    for user in users:
        flags = USER_FLAGS[user]
        if user in logins:
            continue
        pw = password if (password and user == ADMIN) else secrets.token_urlsafe(12)
        cmd = (
            _octoprint_cmd(python)
            + ["--basedir", basedir, "user", "add", user, "--password", pw]
            + flags
        )
        subprocess.run(cmd, check=True, capture_output=True, env=env)
        logins[user] = {"password": pw, "apikey": secrets.token_hex(16).upper()}
    users_path = os.path.join(basedir, "users.yaml")
    with open(users_path) as f:
        users = yaml.safe_load(f) or {}
    for user, info in logins.items():
        if user in users:
            users[user]["apikey"] = info["apikey"]
    with open(users_path, "w") as f:
        yaml.safe_dump(users, f)
    with open(logins_path, "w") as f:
        json.dump(logins, f)
    os.chmod(logins_path, 0o600)
    return logins


def request_body(
    headers: Dict[str, str],
    body: Any = None,
    raw: Optional[bytes] = None,
    content_type: Optional[str] = None,
) -> Optional[bytes]:
    """The bytes to send: ``body`` as JSON, else ``raw``; sets Content-Type in ``headers``."""
    if body is not None:
        headers["Content-Type"] = "application/json"
        return json.dumps(body).encode()
    if content_type:
        headers["Content-Type"] = content_type
    return raw


class DevServer:
    """``octoprint serve`` on a prepared basedir (127.0.0.1), stopped by ``stop()``."""

    def __init__(
        self,
        basedir: str,
        port: Optional[int] = None,
        kincomp: Optional[Dict[str, Any]] = None,
        throttle: float = 0.0,
        extra_config: Optional[Dict[str, Any]] = None,
        users: Sequence[str] = (ADMIN, VIEWER),
        demo: Optional[bool] = None,
        python: Optional[str] = None,
    ):
        self.basedir = basedir
        self.port = port or free_port()
        self.python = python  # None: this environment's OctoPrint
        self.logins = prepare(
            basedir,
            self.port,
            kincomp,
            throttle,
            extra_config=extra_config,
            users=users,
            demo=demo,
            python=python,
        )
        self.proc: Optional[subprocess.Popen] = None
        self.url = f"http://127.0.0.1:{self.port}"

    @property
    def admin_key(self) -> str:
        return self.logins[ADMIN]["apikey"]

    def start(self, timeout: float = 120.0, stdout=None) -> DevServer:
        home = os.path.join(self.basedir, "home")
        tmp = os.path.join(self.basedir, "tmp")
        os.makedirs(home, exist_ok=True)
        os.makedirs(tmp, exist_ok=True)
        env = dict(os.environ, HOME=home, TMPDIR=tmp, PYTHONDONTWRITEBYTECODE="1")
        cmd = _octoprint_cmd(self.python)
        args = cmd + [
            "serve",
            "--basedir",
            self.basedir,
            "--host",
            "127.0.0.1",
            "--port",
            str(self.port),
        ]
        if hasattr(os, "geteuid") and os.geteuid() == 0:
            args.insert(len(cmd) + 1, "--iknowwhatimdoing")
        log = stdout or open(os.path.join(self.basedir, SERVER_OUT), "wb")
        self.proc = subprocess.Popen(
            args, stdout=log, stderr=subprocess.STDOUT, env=env, start_new_session=True
        )
        deadline = time.time() + timeout
        while time.time() < deadline:
            if self.proc.poll() is not None:
                raise RuntimeError(
                    f"OctoPrint exited with {self.proc.returncode}; see {self.basedir}/server.out"
                )
            try:
                self.request("GET", "/api/version")
                return self
            except (urllib.error.URLError, ConnectionError, OSError, http.client.HTTPException):
                time.sleep(0.5)
        self.stop()
        raise RuntimeError("OctoPrint did not start in time")

    def stop(self) -> None:
        if self.proc is None:
            return
        if self.proc.poll() is None:
            try:
                os.killpg(self.proc.pid, signal.SIGTERM)
            except ProcessLookupError:
                pass
            try:
                self.proc.wait(timeout=20)
            except subprocess.TimeoutExpired:
                os.killpg(self.proc.pid, signal.SIGKILL)
                self.proc.wait(timeout=10)
        self.proc = None

    # -- HTTP helpers ------------------------------------------------------------------------
    def request(
        self,
        method: str,
        path: str,
        body: Any = None,
        key: Optional[str] = "admin",
        headers: Optional[Dict[str, str]] = None,
        raw: Optional[bytes] = None,
        content_type: Optional[str] = None,
    ):
        """(status, parsed JSON or text). ``key``: a user of :data:`USERS`, None or an API
        key."""
        hdrs = dict(headers or {})
        if key in self.logins:
            hdrs["X-Api-Key"] = self.logins[key]["apikey"]
        elif key:
            hdrs["X-Api-Key"] = key
        data = request_body(hdrs, body, raw, content_type)
        req = urllib.request.Request(self.url + path, data=data, method=method, headers=hdrs)
        try:
            with urllib.request.urlopen(req, timeout=60) as resp:
                status, text = resp.status, resp.read().decode("utf-8", "replace")
        except urllib.error.HTTPError as exc:
            status, text = exc.code, exc.read().decode("utf-8", "replace")
        try:
            return status, json.loads(text) if text else None
        except ValueError:
            return status, text

    def upload(
        self,
        path: str,
        filename: str,
        data: bytes,
        fields: Dict[str, str] = None,
        key: Optional[str] = "admin",
    ):
        boundary = "kincomp" + secrets.token_hex(8)
        parts = []
        for name, value in (fields or {}).items():
            parts.append(
                f'--{boundary}\r\nContent-Disposition: form-data; name="{name}"\r\n'
                f"\r\n{value}\r\n".encode()
            )
        parts.append(
            f'--{boundary}\r\nContent-Disposition: form-data; name="file"; '
            f'filename="{filename}"\r\nContent-Type: application/octet-stream\r\n'
            f"\r\n".encode()
            + data
            + b"\r\n"
        )
        parts.append(f"--{boundary}--\r\n".encode())
        return self.request(
            "POST",
            path,
            raw=b"".join(parts),
            key=key,
            content_type=f"multipart/form-data; boundary={boundary}",
        )

    def connect(self, timeout: float = 60.0) -> None:
        status, _ = self.request(
            "POST", "/api/connection", {"command": "connect", "port": "VIRTUAL", "baudrate": 115200}
        )
        if status != 204:
            raise RuntimeError(f"connect failed: {status}")
        self.wait_state("Operational", timeout)

    def state(self) -> str:
        _, data = self.request("GET", "/api/connection")
        return data["current"]["state"]

    def wait_state(self, wanted: str, timeout: float = 60.0) -> None:
        deadline = time.time() + timeout
        while time.time() < deadline:
            if self.state() == wanted:
                return
            time.sleep(0.2)
        raise RuntimeError(f"printer did not reach state {wanted!r} (is {self.state()!r})")

    def wait_print_done(self, timeout: float = 600.0) -> None:
        deadline = time.time() + timeout
        time.sleep(0.5)
        while time.time() < deadline:
            _, job = self.request("GET", "/api/job")
            if job["state"] in ("Operational",):
                return
            time.sleep(0.3)
        raise RuntimeError("print did not finish in time")

    def serial_log(self) -> str:
        path = os.path.join(self.basedir, "logs", "serial.log")
        if not os.path.exists(path):
            return ""
        with open(path, encoding="utf-8", errors="replace") as f:
            return f.read()

    def octoprint_log(self) -> str:
        path = os.path.join(self.basedir, "logs", "octoprint.log")
        with open(path, encoding="utf-8", errors="replace") as f:
            return f.read()


def main(argv=None) -> int:
    import argparse

    ap = argparse.ArgumentParser(prog="python -m octoprint_kincomp demo-server")
    ap.add_argument("--basedir", default=".octoprint-demo")
    ap.add_argument("--port", type=int, default=5000)
    ap.add_argument("--no-demo", action="store_true", help="no simulated errors / ballbar")
    ap.add_argument("--reset", action="store_true", help="start from a fresh basedir")
    args = ap.parse_args(argv)
    if args.reset and os.path.isdir(args.basedir):
        shutil.rmtree(args.basedir)
    fresh = not os.path.exists(os.path.join(args.basedir, "config.yaml"))
    # demo mode: on for a fresh basedir, off with --no-demo, else as the user left it
    demo = False if args.no_demo else (True if fresh else None)
    srv = DevServer(
        args.basedir,
        args.port,
        throttle=0.002,
        demo=demo,
        extra_config={"serial": {"port": "VIRTUAL", "baudrate": 115200, "autoconnect": True}},
    )
    with open(os.path.join(args.basedir, "config.yaml")) as f:
        stored = yaml.safe_load(f) or {}
    demo_on = bool(
        ((stored.get("plugins") or {}).get("kincomp") or {}).get("demo", {}).get("enabled")
    )

    def _terminate(signum, frame):
        raise KeyboardInterrupt

    signal.signal(signal.SIGTERM, _terminate)  # stop OctoPrint with us, not orphan it
    log_path = os.path.abspath(os.path.join(args.basedir, SERVER_OUT))
    print(
        f"starting OctoPrint + KinComp on {srv.url} (its output goes to {log_path}) ...", flush=True
    )
    try:
        try:
            srv.start()  # OctoPrint's output: into log_path, not over the login
        except RuntimeError as exc:
            print(f"kincomp: {exc}. The end of {log_path}:\n{_tail(log_path)}", file=sys.stderr)
            return 1
        print(banner(srv, demo_on, log_path), flush=True)  # the last thing printed
        while srv.proc is not None and srv.proc.poll() is None:
            time.sleep(0.5)
        if srv.proc is not None:
            print(
                f"kincomp: OctoPrint stopped (exit status {srv.proc.returncode}); see {log_path}",
                file=sys.stderr,
            )
    except KeyboardInterrupt:
        pass
    finally:
        srv.stop()
    return 0


def banner(srv: DevServer, demo_on: bool, log_path: str) -> str:
    """What ``run.sh`` shows once the server answers: where it is, the login, the logs."""
    admin = srv.logins[ADMIN]
    lines = [
        "=" * 72,
        f"OctoPrint + KinComp on {srv.url}  (connects to the virtual printer)",
        f"login: {ADMIN} / {admin['password']}    API key: {admin['apikey']}",
    ]
    if demo_on:
        lines.append(
            "demo mode: the virtual printer has hidden SIMULATED errors and a virtual ballbar"
        )
    lines += [
        f"OctoPrint's output: {log_path}",
        f"its logs: {os.path.abspath(os.path.join(srv.basedir, 'logs'))}",
        "open the URL, log in, then click 'KinComp' in the top bar; stop with Ctrl-C",
        "=" * 72,
    ]
    return "\n".join(lines)


def _tail(path: str, lines: int = 30) -> str:
    try:
        with open(path, encoding="utf-8", errors="replace") as f:
            return "".join(f.readlines()[-lines:])
    except OSError as exc:
        return f"(unreadable: {exc.strerror})"
