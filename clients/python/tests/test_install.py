"""The package installs offline with pip and Debian's setuptools (README's command: a venv with
the system's packages, pip install --no-build-isolation, no index), and imports from the source
tree with PYTHONPATH; either way it decodes a frame and talks to clothd."""

import os
import shutil
import subprocess
import sys
import venv

import pytest

from conftest import PACKAGE

CHECK = ("import clothd, sys; print(clothd.__file__); print(clothd.__version__); "
         "print(clothd.Client(sys.argv[1]).health()['status'])")


def test_pip_installs_it_offline_into_a_venv(tmp_path, daemon):
    if subprocess.run([sys.executable, "-m", "pip", "--version"], capture_output=True).returncode != 0:
        pytest.skip("no pip for %s (apt install python3-pip)" % sys.executable)
    # A copy, so the build's files (build/, *.egg-info) go there and not into the source tree.
    src = tmp_path / "python"
    shutil.copytree(PACKAGE, src, ignore=shutil.ignore_patterns("__pycache__", "build", "*.egg-info"))
    env_dir = tmp_path / "venv"
    venv.EnvBuilder(system_site_packages=True, with_pip=False).create(env_dir)
    python = str(env_dir / "bin" / "python")
    # The venv sees the system's packages: its pip (python3-pip; with_pip would need ensurepip's
    # wheels) and setuptools (python3-setuptools), the build backend pip does not fetch then.
    env = dict(os.environ, PIP_NO_INDEX="1", PIP_DISABLE_PIP_VERSION_CHECK="1")
    p = subprocess.run([python, "-m", "pip", "install", "--no-build-isolation", "--no-index", str(src)],
                       capture_output=True, text=True, env=env, timeout=300)
    assert p.returncode == 0, p.stdout + p.stderr
    out = subprocess.run([python, "-c", CHECK, daemon.url], capture_output=True, text=True, cwd=str(tmp_path),
                         env={k: v for k, v in os.environ.items() if k != "PYTHONPATH"}, timeout=60)
    assert out.returncode == 0, out.stderr
    where, version, status = out.stdout.split()
    assert where.startswith(str(env_dir)) and "site-packages" in where
    assert (version, status) == ("0.1.0", "ok")
    # PEP 561: py.typed is installed, so a type checker reads the installed package's hints (without
    # it mypy calls clothd an untyped module); a consumer's wrong use is caught through them.
    assert os.path.exists(os.path.join(os.path.dirname(where), "py.typed"))
    if subprocess.run([python, "-c", "import mypy"], capture_output=True).returncode != 0:
        return  # the ctest clients.python_types says so where mypy is missing
    (tmp_path / "consumer.py").write_text(
        "import clothd\n"
        "c = clothd.Client('http://127.0.0.1:8080')\n"
        "frames: int = c.sim()['frame']\n"
        "sag: str = c.cloth_state_binary()\n")
    check = subprocess.run([python, "-m", "mypy", "--strict", "--no-incremental", "--cache-dir", os.devnull, "consumer.py"],
                           capture_output=True, text=True, cwd=str(tmp_path), timeout=120,
                           env={k: v for k, v in os.environ.items() if k != "PYTHONPATH"})
    assert check.returncode == 1, check.stdout + check.stderr
    assert check.stdout.count("error:") == 1, check.stdout
    assert '(expression has type "ClothState", variable has type "str")' in check.stdout, check.stdout


def test_it_runs_from_the_source_tree_with_pythonpath(tmp_path, daemon):
    out = subprocess.run([sys.executable, "-c", CHECK, daemon.url], capture_output=True, text=True, cwd=str(tmp_path),
                         env=dict(os.environ, PYTHONPATH=str(PACKAGE)), timeout=60)
    assert out.returncode == 0, out.stderr
    where, version, status = out.stdout.split()
    assert where == str(PACKAGE / "clothd" / "__init__.py") and status == "ok"
