"""The Python client's test harness: starts the real clothd on 127.0.0.1 with ephemeral ports
(--port 0, --stream-port 0) and the CPU backend, as tests/server/harness.mjs does, and stops it
after, failing on a sanitizer report in its log.

The daemon is $CLOTHD_BIN (ctest sets it), else build/server/clothd of this source tree; the
tests that need one skip without it. ``--hide-numpy`` hides numpy from the import system before
clothd is imported, so the decoder's list path runs; tests marked ``both`` are the ones whose
results differ by it (ctest runs them a second time so: clients.python_nonumpy).
"""

import importlib.abc
import os
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import pytest

HERE = Path(__file__).resolve().parent
PACKAGE = HERE.parent            # clients/python
REPO = PACKAGE.parent.parent
sys.path.insert(0, str(PACKAGE))  # the source tree's clothd, with or without PYTHONPATH

CLOTHD = os.environ.get("CLOTHD_BIN") or str(REPO / "build" / "server" / "clothd")
SOURCE = Path(os.environ.get("CLOTHD_SOURCE") or REPO)
REPORT = re.compile(r"==\d+==ERROR: \w+Sanitizer|runtime error: |SUMMARY: \w+Sanitizer")
START_TIMEOUT = 60  # s: the sanitized build starts slowly


class Hidden(importlib.abc.MetaPathFinder):
    """Makes the named top-level packages unimportable."""

    def __init__(self, names):
        self.names = set(names)

    def find_spec(self, name, path=None, target=None):
        if name.split(".")[0] in self.names:
            raise ImportError("%s is hidden by the test (--hide-numpy)" % name)
        return None


def pytest_addoption(parser):
    parser.addoption("--hide-numpy", action="store_true", help="hide numpy from the import system")


def pytest_configure(config):
    config.addinivalue_line("markers", "both: a test whose results differ with and without numpy")
    if config.getoption("--hide-numpy"):
        for name in [m for m in sys.modules if m == "numpy" or m.startswith("numpy.")]:
            del sys.modules[name]
        sys.meta_path.insert(0, Hidden(["numpy"]))


def run_hidden(names, code, env=None):
    """Runs ``code`` in a fresh python3 with the named packages hidden; returns the process."""
    prelude = ("import sys, importlib.abc\n"
               "class H(importlib.abc.MetaPathFinder):\n"
               "    def find_spec(self, name, path=None, target=None):\n"
               "        if name.split('.')[0] in %r: raise ImportError(name + ' is hidden by the test')\n"
               "sys.meta_path.insert(0, H())\n"
               "sys.path.insert(0, %r)\n") % (list(names), str(PACKAGE))
    return subprocess.run([sys.executable, "-c", prelude + code], capture_output=True, text=True, timeout=120,
                          env=dict(os.environ, **(env or {})))


class Daemon:
    """A clothd started for a test: url, stream_port (after health), log, proc."""

    def __init__(self, flags=(), env=None):
        if not os.access(CLOTHD, os.X_OK):
            pytest.skip("no clothd at %s (build it: scripts/build.sh, or set CLOTHD_BIN)" % CLOTHD)
        self.dir = tempfile.mkdtemp(prefix="clothd-pytest-")
        args = [CLOTHD, "--port", "0", "--stream-port", "0", "--backend", "cpu", "--threads", "1",
                "--web-root", self.dir, *flags]
        base = {k: v for k, v in os.environ.items() if not k.startswith("CLOTHD_")}
        self.proc = subprocess.Popen(args, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                                     text=True, env=dict(base, OMP_WAIT_POLICY="passive", **(env or {})))
        self.lines = []
        self.url = None
        ready = threading.Event()

        def read():
            for line in self.proc.stderr:
                self.lines.append(line)
                m = re.search(r"listening on (http://[0-9.]+:\d+)", line)
                if m and not self.url:
                    self.url = m.group(1)
                    ready.set()
            ready.set()

        self.reader = threading.Thread(target=read, daemon=True)
        self.reader.start()
        ready.wait(START_TIMEOUT)
        if not self.url:
            self.proc.kill()
            self.proc.wait()
            self.reader.join(5)
            shutil.rmtree(self.dir, ignore_errors=True)
            raise RuntimeError("clothd did not start:\n" + self.log)

    @property
    def log(self):
        return "".join(self.lines)

    @property
    def port(self):
        return int(self.url.rsplit(":", 1)[1])

    def stop(self, sig=signal.SIGTERM):
        """Stops it and waits; fails on a sanitizer report. Returns the exit status."""
        if self.proc.poll() is None:
            self.proc.send_signal(sig)
        code = self.proc.wait(60)
        self.reader.join(10)
        shutil.rmtree(self.dir, ignore_errors=True)
        m = REPORT.search(self.log)
        if m:
            raise AssertionError("sanitizer report from clothd:\n" + self.log[m.start():])
        return code


@pytest.fixture
def start_daemon():
    """start_daemon(*flags) starts a clothd; every one is stopped after the test."""
    started = []

    def start(*flags, env=None):
        d = Daemon(flags, env)
        started.append(d)
        return d

    yield start
    for d in started:
        if d.proc.returncode is None:
            d.stop()


@pytest.fixture(scope="module")
def daemon():
    """One paused clothd without automatic drops for a test file."""
    d = Daemon(["--auto-drop-interval", "0", "--paused"])
    yield d
    d.stop()


@pytest.fixture
def client(daemon):
    import clothd
    c = clothd.Client(daemon.url)
    c.pause()
    return c


def until(what, fn, timeout=20.0, every=0.02):
    """Waits for a condition by polling it (a condition, not a guess at how long something takes)."""
    deadline = time.monotonic() + timeout
    while True:
        v = fn()
        if v:
            return v
        if time.monotonic() > deadline:
            raise AssertionError("timed out waiting for " + what)
        time.sleep(every)


def write_token(directory, name, token):
    path = Path(directory) / name
    path.write_text(token + "\n")
    return str(path)
