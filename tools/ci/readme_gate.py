"""The fresh-machine gate: the README's two commands, as a newcomer runs them.

`.ci/run` runs this after the README's install step (venv + ``pip install -e ".[dev]"``) and
before the README's test command. It checks, and prints one PASS/FAIL line each:

1. the README still starts with the two commands, and `.ci/run` runs exactly the second one
   (the tests) and the install part of the first;
2. the first command's server — ``tcs-server`` with no arguments, as the README says — starts
   the simulated telescope from this venv, serves OpenTCI on 127.0.0.1:65432 with the login the
   README names, answers ``GET CONFIG.MOUNT`` and ``AZ.REALPOS``, serves Alpaca on :11111 and
   the status page's ``/metrics`` on :8088, and stops cleanly (exit 0, no traceback) on SIGTERM.

The server's state goes to a temporary ``XDG_STATE_HOME`` so a run leaves nothing behind. It
uses only the standard library and what the README's install step installed. Exit status 0
when every check passed, 1 otherwise (with the server's log).
"""

from __future__ import annotations

import os
import re
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
import urllib.request
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
PORT, ALPACA_PORT, WEB_PORT = 65432, 11111, 8088
START_TIMEOUT = 180.0  # a loaded 2-core machine may take a while; this is a hang guard only

failures: list[str] = []


def check(ok: bool, what: str, detail: str = "") -> bool:
    print(f"{'PASS' if ok else 'FAIL'}: {what}" + (f" ({detail})" if detail and not ok else ""), flush=True)
    if not ok:
        failures.append(what)
    return ok


def readme_commands() -> list[str]:
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    block = re.search(r"```sh\n(.*?)```", text, re.S)
    if block is None:
        return []
    return [line.split("#", 1)[0].strip() for line in block.group(1).splitlines() if line.strip()]


def check_commands() -> None:
    commands = readme_commands()
    check(len(commands) == 2 and commands[0].endswith("&& tcs-server")
          and commands[1].endswith("&& python -m pytest"),
          "the README starts with the two commands (start the simulated telescope; run the tests)",
          repr(commands))
    if len(commands) != 2:
        return
    install = commands[0].rsplit("&& tcs-server", 1)[0].strip()
    ci = (ROOT / ".ci" / "run").read_text(encoding="utf-8")
    check(install == commands[1].rsplit("&& python -m pytest", 1)[0].strip(),
          "both commands install the same way")
    check(install in ci, ".ci/run installs exactly as the README says", install)
    check(re.search(r"^python -m pytest\s*$", ci, re.M) is not None,
          ".ci/run runs the README's test command: python -m pytest")


def port_free(port: int) -> bool:
    with socket.socket() as s:
        try:
            s.bind(("127.0.0.1", port))
        except OSError:
            return False
    return True


def tpl2(sock_file, sock: socket.socket, line: str, cid: str) -> list[str]:
    sock.sendall(line.encode() + b"\n")
    lines = []
    while True:
        reply = sock_file.readline().decode().rstrip("\n")
        if not reply:
            raise ConnectionError("connection closed")
        if reply.startswith(f"{cid} "):
            lines.append(reply)
            if reply.startswith(f"{cid} COMMAND COMPLETE") or reply.startswith(f"{cid} COMMAND FAILED"):
                return lines


def check_server() -> None:
    deadline = time.monotonic() + 120  # another program's server may be ending
    while (busy := [p for p in (PORT, ALPACA_PORT, WEB_PORT) if not port_free(p)]) and time.monotonic() < deadline:
        time.sleep(1)
    if not check(not busy, "the README's ports are free on this machine", f"taken: {busy}"):
        return
    exe = shutil.which("tcs-server")
    if not check(exe is not None and Path(exe).resolve().is_relative_to(Path(sys.prefix).resolve()),
                 "tcs-server is the venv's script", str(exe)):
        return
    state = tempfile.mkdtemp(prefix="tcs-readme-gate-")
    env = dict(os.environ, XDG_STATE_HOME=state, PYTHONUNBUFFERED="1")
    log = Path(state) / "server.log"
    with open(log, "w") as out:
        proc = subprocess.Popen(["tcs-server"], env=env, stdout=out, stderr=subprocess.STDOUT, cwd=state)
    try:
        deadline = time.monotonic() + START_TIMEOUT
        sock = None
        while sock is None and time.monotonic() < deadline and proc.poll() is None:
            try:
                sock = socket.create_connection(("127.0.0.1", PORT), timeout=30)
            except OSError:
                time.sleep(0.2)
        if not check(sock is not None, "tcs-server serves OpenTCI on 127.0.0.1:65432"):
            return
        with sock, sock.makefile("rb") as f:
            greeting = f.readline().decode()
            check(greeting.startswith("TPL2 "), "the TPL2 greeting", greeting)
            sock.sendall(b'AUTH PLAIN "admin" "admin"\n')
            login = f.readline().decode().strip()
            while login.startswith("0 EVENT"):
                login = f.readline().decode().strip()
            check(login.startswith("AUTH OK"), "login admin / admin as the README says", login)
            mount = tpl2(f, sock, "1 GET CONFIG.MOUNT", "1")
            check('1 DATA INLINE CONFIG.MOUNT="AZ-ZD"' in mount, "GET CONFIG.MOUNT reads AZ-ZD", str(mount))
            deadline = time.monotonic() + START_TIMEOUT
            while True:  # the drives boot after the port is bound: wait for a fresh readback
                pos = tpl2(f, sock, "2 GET AZ.REALPOS", "2")
                if any("DATA INLINE AZ.REALPOS=" in x for x in pos) or time.monotonic() > deadline:
                    break
                time.sleep(0.5)
            check(any("DATA INLINE AZ.REALPOS=" in x for x in pos), "AZ.REALPOS reads a position", str(pos))
        try:
            with urllib.request.urlopen(f"http://127.0.0.1:{ALPACA_PORT}/management/apiversions",
                                        timeout=30) as r:
                body = r.read().decode()
            check('"Value"' in body, "ASCOM Alpaca answers on :11111", body)
        except OSError as exc:
            check(False, "ASCOM Alpaca answers on :11111", str(exc))
        try:
            with urllib.request.urlopen(f"http://127.0.0.1:{WEB_PORT}/metrics", timeout=30) as r:
                body = r.read().decode()
            check("tcs_build_info" in body, "the status page's /metrics answers on :8088", body[:200])
        except OSError as exc:
            check(False, "the status page's /metrics answers on :8088", str(exc))
    finally:
        if proc.poll() is None:
            proc.send_signal(signal.SIGTERM)
            try:
                code = proc.wait(120)
            except subprocess.TimeoutExpired:
                proc.kill()
                code = proc.wait()
            check(code == 0, "tcs-server stops cleanly on SIGTERM (exit 0)", f"exit {code}")
        else:
            check(False, "tcs-server kept running", f"exit {proc.returncode}")
        text = log.read_text(errors="replace")
        check("Traceback" not in text, "no traceback in the server's log")
        if failures:
            print("---- tcs-server's log ----\n" + text, flush=True)
        shutil.rmtree(state, ignore_errors=True)


def main() -> int:
    check_commands()
    check_server()
    print(f"README gate: {'all passed' if not failures else f'{len(failures)} failed'}", flush=True)
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
