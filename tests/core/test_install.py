"""``pip install .`` outside the checkout: the wheel carries the Hydra configs, and qr runs from any folder.

The wheel is built from this checkout and installed (no dependencies: this environment's are reached
through a ``.pth`` file) into a fresh venv; every command then runs in an empty folder under /tmp, where
no ``conf/`` exists and the checkout's ``src/`` is not on the path.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import sysconfig
import venv

import pytest

from conftest import ROOT


@pytest.mark.slow
def test_an_installed_qr_runs_from_any_folder(tmp_path):
    # built from a copy: setuptools writes build/ next to the sources, and the checkout stays as it is
    source = tmp_path / "source"
    for name in ("src", "conf"):
        shutil.copytree(ROOT / name, source / name, symlinks=True,
                        ignore=shutil.ignore_patterns("__pycache__", "*.egg-info"))
    for name in ("pyproject.toml", "README.md"):
        shutil.copy(ROOT / name, source / name)
    wheels = tmp_path / "wheels"
    subprocess.run([sys.executable, "-m", "pip", "wheel", "--quiet", "--no-deps", "--no-build-isolation",
                    "-w", str(wheels), str(source)], check=True, capture_output=True)
    env_dir = tmp_path / "venv"
    venv.EnvBuilder(with_pip=False).create(env_dir)  # this pip installs into it (--python): no ensurepip
    py = env_dir / "bin" / "python"
    site = subprocess.run([str(py), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
                          check=True, capture_output=True, text=True).stdout.strip()
    (tmp_path / "venv" / site.split(str(env_dir) + "/", 1)[1] / "deps.pth").write_text(
        sysconfig.get_paths()["purelib"] + "\n")
    subprocess.run([sys.executable, "-m", "pip", "--python", str(py), "install", "--quiet", "--no-deps",
                    "--no-index", str(next(wheels.glob("qr-*.whl")))], check=True, capture_output=True)

    work = tmp_path / "elsewhere"
    work.mkdir()
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "QR_CONF")}
    env.update(QR_TRACKING="off", QR_RESULTS=str(work / "results"))
    qr = str(env_dir / "bin" / "qr")

    def run(*args):
        r = subprocess.run(list(args), cwd=work, env=env, capture_output=True, text=True, timeout=600)
        assert r.returncode == 0, r.stderr
        return r

    where = run(str(py), "-c", "import qr, qr.config; print(qr.__file__); print(qr.config.CONF_DIR)").stdout.split()
    assert where[0].startswith(str(env_dir)) and where[1].startswith(str(env_dir))  # not the checkout's
    assert run(qr, "--version").stdout.strip() == "qr 0.1.0"
    run(qr, "synth", "--vehicle", "asctec_hummingbird", "--effect", "linear_drag:kx=0.3,ky=0.3,kz=0.15",
        "--duration", "40", "--seed", "1", "--out", "synth")
    run(qr, "diagnose", "synth/flight.csv", "--vehicle", "synth/vehicle.yaml", "--out", "diag")
    named = [e["name"] for e in json.loads((work / "diag" / "diagnosis.json").read_text())["effects"]]
    assert "linear_drag" in named
    run(str(py), "-m", "qr.filter", "filter.flight=synth/flight.csv", "filter.vehicle=synth/vehicle.yaml",
        "filter.out=states.parquet")
    assert (work / "states.parquet").exists()
