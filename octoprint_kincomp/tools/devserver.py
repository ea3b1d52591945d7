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
LOGINS_FILE = "kincomp-logins.json"  # the logins (password, API key) of a basedir's users
# a folder for the users made once and copied into every basedir (see users_template)
USERS_TEMPLATE_ENV = "KINCOMP_USERS_TEMPLATE"
# OctoPrint's own G-code analysis (gcodeAnalysis.runAt: never, idle or always) of the servers
# made here, when set; the test session sets "never": nothing of KinComp reads it, and it
# costs an analysis process for every file a test uploads
GCODE_ANALYSIS_ENV = "KINCOMP_GCODE_ANALYSIS"


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
    users_from: Optional[str] = None,
) -> Dict[str, str]:
    """Create (or refresh) a basedir; returns the logins {user: (password, apikey)}.

    ``kincomp`` replaces KinComp's stored settings (a fresh test server); ``demo`` only
    switches demo mode and keeps everything else the user saved. Missing users are copied
    from :func:`users_template` in ``users_from`` (default: the folder named by
    :data:`USERS_TEMPLATE_ENV`, if set), else added by one run of OctoPrint's user manager."""
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
            # file_check (OctoPrint's bundled File Check, wizard version 1): its "A full File
            # Check is suggested" dialog comes up over every page of a server that had a file
            # before its first page or wizard query (a session server a test uploaded to)
            "seenWizards": {
                "kincomp": 1,
                "corewizard": 4,
                "backup": None,
                "tracking": None,
                "file_check": 1,
            },
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
    if os.environ.get(GCODE_ANALYSIS_ENV):
        config.setdefault("gcodeAnalysis", {})["runAt"] = os.environ[GCODE_ANALYSIS_ENV]
    config.setdefault("temperature", {})["profiles"] = []
    if extra_config:
        for k, v in extra_config.items():
            config.setdefault(k, {}).update(v)
    with open(cfg_path, "w") as f:
        yaml.safe_dump(config, f)

    logins_path = os.path.join(basedir, LOGINS_FILE)
    logins = _read_json(logins_path)
    missing = [u for u in users if u not in logins]
    template = users_from or os.environ.get(USERS_TEMPLATE_ENV)
    if missing and template and not password:
        # the template's users (made once): copied, no OctoPrint process started
        folder = users_template(template, python)
        logins.update(_copy_users(folder, basedir, missing))
    elif missing:
        logins.update(add_users(basedir, missing, python, password))
    users_path = os.path.join(basedir, "users.yaml")
    with open(users_path) as f:
        stored = yaml.safe_load(f) or {}
    for user, info in logins.items():
        if user in stored:
            stored[user]["apikey"] = info["apikey"]
    with open(users_path, "w") as f:
        yaml.safe_dump(stored, f)
    with open(logins_path, "w") as f:
        json.dump(logins, f)
    os.chmod(logins_path, 0o600)
    return logins


# One OctoPrint process adds every user (OctoPrint's own user manager, as `octoprint user
# add` does it: the same groups, permissions and password hashing), instead of one
# `octoprint user add` process per user (each starts OctoPrint's command line: seconds).
_ADD_USERS = """
import json, sys
from octoprint import init_settings
from octoprint.access.groups import FilebasedGroupManager
from octoprint.access.users import FilebasedUserManager

settings = init_settings(sys.argv[1], None)
groups = FilebasedGroupManager()
manager = FilebasedUserManager(groups, settings=settings)
for name, password, apikey, group_ids, permissions, admin in json.loads(sys.argv[2]):
    member_of = list(group_ids) + ([groups.admin_group] if admin else [])
    manager.add_user(name, password, active=True, permissions=permissions, groups=member_of,
                     apikey=apikey, overwrite=True)
"""


def _user_spec(user: str, password: str, apikey: str) -> list:
    """``user``'s :data:`USER_FLAGS` as the user manager takes them."""
    flags = USER_FLAGS[user]
    groups = [flags[i + 1] for i, f in enumerate(flags) if f == "-g"]
    permissions = [flags[i + 1] for i, f in enumerate(flags) if f == "-p"]
    return [user, password, apikey, groups, permissions, "--admin" in flags]


def add_users(
    basedir: str, users: Sequence[str], python: Optional[str] = None, password: str = None
) -> Dict[str, Dict[str, str]]:
    """Adds ``users`` (of :data:`USER_FLAGS`) to ``basedir`` with fresh passwords (the admin's
    ``password`` if given) and API keys, in one run of that environment's OctoPrint; returns
    their logins {user: {password, apikey}}."""
    os.makedirs(basedir, exist_ok=True)
    logins = {
        u: {
            "password": password if (password and u == ADMIN) else secrets.token_urlsafe(12),
            "apikey": secrets.token_hex(16).upper(),
        }
        for u in users
    }
    spec = [_user_spec(u, i["password"], i["apikey"]) for u, i in logins.items()]
    env = dict(os.environ, PYTHONDONTWRITEBYTECODE="1")
    subprocess.run(
        [python or sys.executable, "-c", _ADD_USERS, basedir, json.dumps(spec)],
        check=True,
        capture_output=True,
        env=env,
    )
    return logins


def users_template(folder: str, python: Optional[str] = None) -> str:
    """A folder inside ``folder`` with every user of :data:`USER_FLAGS` (``users.yaml`` and
    their logins) for the OctoPrint of ``python``, made on the first call (by any process:
    under a lock) and then only found; :func:`prepare` copies users from it. The test
    session sets :data:`USERS_TEMPLATE_ENV` so that no test server creates its users."""
    import fcntl
    import hashlib

    key = hashlib.sha1(os.path.abspath(python or sys.executable).encode()).hexdigest()[:12]
    here = os.path.join(folder, "users-" + key)
    if os.path.exists(os.path.join(here, LOGINS_FILE)):
        return here
    os.makedirs(folder, exist_ok=True)
    with open(os.path.join(folder, ".lock-" + key), "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        if not os.path.exists(os.path.join(here, LOGINS_FILE)):
            tmp = here + ".tmp"
            shutil.rmtree(tmp, ignore_errors=True)
            logins = add_users(tmp, list(USER_FLAGS), python)
            with open(os.path.join(tmp, LOGINS_FILE), "w") as f:
                json.dump(logins, f)
            os.rename(tmp, here)
    return here


def _copy_users(template: str, basedir: str, users: Sequence[str]) -> Dict[str, Dict[str, str]]:
    """``users`` copied from the folder :func:`users_template` made into ``basedir``'s
    ``users.yaml`` (beside any user it has); returns their logins."""
    with open(os.path.join(template, "users.yaml")) as f:
        made = yaml.safe_load(f)
    users_path = os.path.join(basedir, "users.yaml")
    stored = {}
    if os.path.exists(users_path):
        with open(users_path) as f:
            stored = yaml.safe_load(f) or {}
    for key in [k for k in made if k.startswith("_")]:
        stored.setdefault(key, made[key])  # the file format's version
    stored.update({u: made[u] for u in users})
    with open(users_path, "w") as f:
        yaml.safe_dump(stored, f)
    logins = _read_json(os.path.join(template, LOGINS_FILE))
    return {u: logins[u] for u in users}


def _read_json(path: str) -> dict:
    if not os.path.exists(path):
        return {}
    with open(path) as f:
        return json.load(f)


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


def multipart_body(filename: str, data: bytes, fields: Optional[Dict[str, str]] = None):
    """(body, content type) of a multipart/form-data upload of ``data`` as the form field
    ``file`` named ``filename``, after the plain ``fields``: as a browser sends it."""
    boundary = "kincomp" + secrets.token_hex(8)
    parts = [
        f'--{boundary}\r\nContent-Disposition: form-data; name="{k}"\r\n\r\n{v}\r\n'.encode()
        for k, v in (fields or {}).items()
    ]
    parts.append(
        f'--{boundary}\r\nContent-Disposition: form-data; name="file"; '
        f'filename="{filename}"\r\nContent-Type: application/octet-stream\r\n\r\n'.encode()
        + data
        + b"\r\n"
    )
    parts.append(f"--{boundary}--\r\n".encode())
    return b"".join(parts), f"multipart/form-data; boundary={boundary}"


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
        body, content_type = multipart_body(filename, data, fields)
        return self.request(
            "POST",
            path,
            raw=body,
            key=key,
            content_type=content_type,
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
