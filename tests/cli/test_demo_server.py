"""``run.sh``'s demo server (tools/devserver.py main; issue 25): OctoPrint's own output goes
to a file whose path is printed, and the login banner is the last thing printed, once the
server answers (it was printed first and buried under OctoPrint's log)."""

import os

from octoprint_kincomp.tools import devserver


class FakeServer:
    """A DevServer whose "OctoPrint" writes a lot of colourful log, answers, then exits."""

    started_with = None

    def __init__(self, basedir, port=None, **kwargs):
        os.makedirs(basedir, exist_ok=True)
        with open(os.path.join(basedir, "config.yaml"), "w") as f:
            f.write("plugins:\n  kincomp:\n    demo:\n      enabled: true\n")
        self.basedir = basedir
        self.url = f"http://127.0.0.1:{port}"
        self.logins = {"admin": {"password": "pw-123", "apikey": "KEY456"}}
        self.proc = None
        self.events = []

    def start(self, timeout=120.0, stdout=None):
        FakeServer.started_with = stdout
        assert stdout is None  # (None: DevServer writes OctoPrint's output to server.out)
        with open(os.path.join(self.basedir, devserver.SERVER_OUT), "w") as f:
            f.write("\x1b[32m2026-11-27 INFO - Starting OctoPrint\x1b[0m\n" * 120)

        class Exited:
            returncode = 0

            def poll(self):
                return 0

        self.proc = Exited()
        return self

    def stop(self):
        self.proc = None


def test_the_login_is_the_last_thing_printed_and_octoprints_output_goes_to_a_file(
    tmp_path, monkeypatch, capsys
):
    monkeypatch.setattr(devserver, "DevServer", FakeServer)
    monkeypatch.setattr(devserver.signal, "signal", lambda *a: None)
    base = str(tmp_path / "demo")
    assert devserver.main(["--basedir", base, "--port", "5099"]) == 0
    out = capsys.readouterr().out
    log = os.path.abspath(os.path.join(base, devserver.SERVER_OUT))
    assert "Starting OctoPrint" not in out and "\x1b[" not in out  # not in the terminal
    lines = out.rstrip("\n").splitlines()
    # the banner closes the output: the login and the log file's path in it
    assert lines[-1] == "=" * 72
    start = len(lines) - 1 - lines[::-1][1:].index("=" * 72) - 1
    box = "\n".join(lines[start:])
    assert "login: admin / pw-123" in box and "http://127.0.0.1:5099" in box
    assert f"OctoPrint's output: {log}" in box
    assert "Starting OctoPrint" in open(log).read()


def test_a_server_that_does_not_start_shows_the_end_of_its_output(tmp_path, monkeypatch, capsys):
    class Broken(FakeServer):
        def start(self, timeout=120.0, stdout=None):
            with open(os.path.join(self.basedir, devserver.SERVER_OUT), "w") as f:
                f.write("Traceback: port 5099 in use\n")
            raise RuntimeError("OctoPrint exited with 1")

    monkeypatch.setattr(devserver, "DevServer", Broken)
    monkeypatch.setattr(devserver.signal, "signal", lambda *a: None)
    assert devserver.main(["--basedir", str(tmp_path / "demo"), "--port", "5099"]) == 1
    captured = capsys.readouterr()
    assert "login:" not in captured.out
    assert "port 5099 in use" in captured.err
