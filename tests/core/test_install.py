"""``pip install .`` outside the checkout: the wheel carries the Hydra configs, and qr runs from any folder.

The wheel is built from this checkout and installed (no dependencies: this environment's are reached
through a ``.pth`` file) into a fresh venv; every command then runs in an empty folder under /tmp, where
no ``conf/`` exists and the checkout's ``src/`` is not on the path.  numba's compiled kernels are carried
over from the checkout (the same sources; :func:`_carry_compiled_kernels`): this test is about the package.
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


def _carry_compiled_kernels(checkout, installed) -> int:
    """numba's cache of the checkout's compiled kernels, copied beside the installed (byte-identical) sources,
    whose time stamps are set to the checkout's: numba takes a cache whose source has the same time stamp
    and size, so the installed qr does not compile again what the checkout compiled (four fifths of this
    test's time; compiling is what every other test does).  Kernels the checkout has not compiled yet
    compile here as for a user.  Returns the cache files copied."""
    copied = 0
    for src in checkout.rglob("*.py"):
        dst = installed / src.relative_to(checkout)
        if not dst.exists() or dst.read_bytes() != src.read_bytes():
            continue
        cache = sorted((src.parent / "__pycache__").glob(f"{src.stem}.*.nb[ic]"))
        if cache:
            st = src.stat()
            os.utime(dst, ns=(st.st_atime_ns, st.st_mtime_ns))
            (dst.parent / "__pycache__").mkdir(exist_ok=True)
            for f in cache:
                shutil.copy2(f, dst.parent / "__pycache__" / f.name)
                copied += 1
    return copied


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
    _carry_compiled_kernels(ROOT / "src" / "qr", env_dir / site.split(str(env_dir) + "/", 1)[1] / "qr")

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
