"""The packages outside the checkout (issue 37, deliverable 4).

The fast tests check the lookup rules in this process: which lensrt library the binding
loads (lensrt_ctypes.find_library) and where lensfit finds lensdb and generated/
(lensfit.data_folder), with the errors that name the folder and the setting.

test_install_outside_checkout does what a user does: a plain venv (no system
site-packages), ``pip install runtime/python fit`` (the lensrt wheel built by
scikit-build-core with the library inside; the other packages at fit/requirements.lock's
versions, which `make setup` left in pip's cache), then, from a folder outside the
checkout with no repository on the path, ``import lensrt`` loading a table, ``lensfit
bank`` on a tiny spec with ``--generated``, and the bank read back with lensrt's Bank.
About a minute on 2 cores (55 s of it the venv and pip), so `make test` runs it.
"""

from __future__ import annotations

import os
import subprocess
import sys
import time
import tomllib
from pathlib import Path

import lensrt_ctypes
import pytest
from bank_specs import bank_spec

import lensfit
from lensfit import data_folder, missing_data_folder, require_data_folder
from lensfit.cli import main
from lensfit.common.errors import InputError

ROOT = Path(__file__).resolve().parents[2]
TABLE = ROOT / "generated" / "0001-angenieux-double-gauss" / "lens0001.table"
# The variables that would point an installed package back into the checkout
SETTINGS = ("PYTHONPATH", "PYTHONHOME", "LENSRT_LIBRARY", "LENSFIT_GENERATED",
            "LENSFIT_LENSDB", "LENSFIT_GLASS_CATALOG", "VIRTUAL_ENV")

# 2 x 1 field nodes, 2 wavelengths, 16 x 16 pixels: seconds to render
TINY_BANK = bank_spec("tiny", size_mm=0.04)


@pytest.fixture
def clean_env(monkeypatch: pytest.MonkeyPatch) -> pytest.MonkeyPatch:
    for name in ("LENSFIT_GENERATED", "LENSFIT_LENSDB", "LENSRT_LIBRARY"):
        monkeypatch.delenv(name, raising=False)
    return monkeypatch


# --- the rules, in this process ---------------------------------------------------------

def test_data_folder_rule_order(clean_env: pytest.MonkeyPatch, tmp_path: Path) -> None:
    """--generated, else $LENSFIT_GENERATED, else the checkout's, else the current
    directory's; the same for lensdb with $LENSFIT_LENSDB."""
    assert lensfit.checkout_root() == ROOT
    assert data_folder("generated") == ROOT / "generated"
    assert data_folder("lensdb") == ROOT / "lensdb"
    clean_env.setenv("LENSFIT_GENERATED", str(tmp_path / "env-gen"))
    clean_env.setenv("LENSFIT_LENSDB", str(tmp_path / "env-db"))
    assert data_folder("generated") == tmp_path / "env-gen"
    assert data_folder("lensdb") == tmp_path / "env-db"
    assert data_folder("generated", tmp_path / "opt") == tmp_path / "opt"
    clean_env.delenv("LENSFIT_GENERATED")
    clean_env.delenv("LENSFIT_LENSDB")
    # Installed (no checkout around the package): the current directory's
    clean_env.setattr(lensfit, "checkout_root", lambda: None)
    clean_env.chdir(tmp_path)
    assert data_folder("generated") == tmp_path / "generated"
    assert data_folder("lensdb") == tmp_path / "lensdb"
    # GENERATED_DIR follows the rule at each use
    from lensfit.codegen import generate

    assert generate.GENERATED_DIR == tmp_path / "generated"


def test_missing_folders_name_folder_and_setting(clean_env: pytest.MonkeyPatch,
                                                 tmp_path: Path) -> None:
    clean_env.setattr(lensfit, "checkout_root", lambda: None)
    clean_env.chdir(tmp_path)
    with pytest.raises(InputError) as e:
        require_data_folder("generated")
    for word in (str(tmp_path / "generated"), "current directory", "--generated",
                 "LENSFIT_GENERATED"):
        assert word in str(e.value)
    message = missing_data_folder("lensdb")
    for word in (str(tmp_path / "lensdb"), "LENSFIT_LENSDB", "schema.json"):
        assert word in message
    clean_env.setenv("LENSFIT_LENSDB", str(tmp_path / "nowhere"))
    assert "from $LENSFIT_LENSDB" in missing_data_folder("lensdb")


def test_cli_without_lensdb_names_the_setting(clean_env: pytest.MonkeyPatch, tmp_path: Path,
                                              capsys: pytest.CaptureFixture[str]) -> None:
    clean_env.setenv("LENSFIT_LENSDB", str(tmp_path / "no-lensdb"))
    assert main(["info", "0001"]) == 2
    err = capsys.readouterr().err
    assert str(tmp_path / "no-lensdb") in err and "LENSFIT_LENSDB" in err


def test_bank_generated_option(clean_env: pytest.MonkeyPatch, tmp_path: Path,
                               capsys: pytest.CaptureFixture[str]) -> None:
    """`lensfit bank --generated DIR` looks the spec's lens id up there; a missing folder
    is one line naming it and the settings."""
    spec = tmp_path / "tiny.toml"
    spec.write_text(TINY_BANK)
    missing = tmp_path / "no-generated"
    assert main(["bank", str(spec), "-o", str(tmp_path / "out"), "--workers", "0",
                 "--generated", str(missing), "--no-progress"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1
    for word in ("tiny.toml", "key 'lens'", str(missing), "from --generated",
                 "LENSFIT_GENERATED"):
        assert word in err[0], err[0]


def test_library_rule(clean_env: pytest.MonkeyPatch, tmp_path: Path) -> None:
    """$LENSRT_LIBRARY, else the package's liblensrt.so, else the checkout's build tree."""
    assert lensrt_ctypes.IN_CHECKOUT
    places = [p for p, _ in lensrt_ctypes.library_candidates()]
    assert places == [lensrt_ctypes.PACKAGE_LIBRARY, lensrt_ctypes.DEFAULT_LIBRARY]
    assert lensrt_ctypes.PACKAGE_LIBRARY.parent.name == "lensrt"
    checkout = Path(lensrt_ctypes.__file__).resolve().parents[2]  # runtime/python/..
    assert lensrt_ctypes.DEFAULT_LIBRARY == checkout / "build/runtime/runtime/liblensrt.so"
    installed = tmp_path / "lensrt" / "liblensrt.so"
    installed.parent.mkdir()
    installed.write_bytes(b"")
    clean_env.setattr(lensrt_ctypes, "PACKAGE_LIBRARY", installed)
    assert lensrt_ctypes.find_library() == installed  # the package's first
    clean_env.setattr(lensrt_ctypes, "IN_CHECKOUT", False)
    installed.unlink()
    assert lensrt_ctypes.find_library() == installed  # expected there, though missing
    with pytest.raises(FileNotFoundError) as e:
        lensrt_ctypes.Lensrt(installed)
    assert str(installed) in str(e.value) and "LENSRT_LIBRARY" in str(e.value)
    clean_env.setenv("LENSRT_LIBRARY", str(tmp_path / "other.so"))
    assert lensrt_ctypes.find_library() == tmp_path / "other.so"


def test_lensrt_package_reexports() -> None:
    import lensrt
    import lensrt_exr

    assert lensrt.Lensrt is lensrt_ctypes.Lensrt and lensrt.Bank is lensrt_ctypes.Bank
    assert lensrt.read_spectral_exr is lensrt_exr.read_spectral_exr
    assert set(lensrt.__all__) <= set(dir(lensrt))


def test_dependencies_declared() -> None:
    """fit depends on lensrt (built from runtime/python: not on PyPI), lensrt on what its
    modules import; the wheel carries the package and both modules."""
    fit = tomllib.loads((ROOT / "fit" / "pyproject.toml").read_text())["project"]
    rt = tomllib.loads((ROOT / "runtime" / "python" / "pyproject.toml").read_text())
    names = {d.split(";")[0].split("=")[0].split(">")[0].strip() for d in fit["dependencies"]}
    assert {"lensrt", "numpy", "scipy", "matplotlib", "dask", "distributed"} <= names
    assert {"numpy", "openexr"} <= set(rt["project"]["dependencies"])
    assert rt["build-system"]["build-backend"] == "scikit_build_core.build"
    assert rt["tool"]["scikit-build"]["wheel"]["packages"] == [
        "lensrt", "lensrt_ctypes.py", "lensrt_exr.py"]


# --- a fresh venv, outside the checkout -------------------------------------------------

def _run(cmd: list[str], cwd: Path, env: dict[str, str], timeout: float = 600
         ) -> subprocess.CompletedProcess[str]:
    done = subprocess.run(cmd, cwd=cwd, env=env, capture_output=True, text=True,
                          timeout=timeout, check=False)
    assert done.returncode == 0, (f"{' '.join(cmd)} exited {done.returncode}\n"
                                  f"{done.stdout[-4000:]}\n{done.stderr[-4000:]}")
    return done


READ_TABLE = """
import sys
import lensrt, lensrt_ctypes, lensrt_exr
rt = lensrt.Lensrt()
lens = rt.load(sys.argv[1])
print(lensrt.__file__); print(lensrt_ctypes.__file__); print(lensrt_exr.__file__)
print(rt.lib._name); print(rt.info(lens)["name"])
"""

READ_BANK = """
import sys
import numpy as np
import lensrt
rt = lensrt.Lensrt()
bank = lensrt.Bank(rt, sys.argv[1])
info = bank.info()
psf, chief = bank.psf(2.5, 0.0, 550.0)
assert info["n_nodes"] == 2 and info["width"] == 16, info
assert psf.shape == (16, 16) and np.isfinite(psf).all() and psf.sum() > 0
print(info["lens_name"], info["n_nodes"], float(psf.sum()))
"""


# About a minute (a venv and pip install of both packages from pip's cache): with the
# slow tests of `make bench`, so that `make test` keeps within its time (the lookup rules
# above are checked in `make test`)
@pytest.mark.slow
def test_install_outside_checkout(tmp_path: Path) -> None:
    venv = tmp_path / "venv"
    work = tmp_path / "work"  # the current directory: no lensdb/, generated/ or repo
    work.mkdir()
    env = {k: v for k, v in os.environ.items() if k not in SETTINGS}
    env["PATH"] = f"{venv / 'bin'}{os.pathsep}{env.get('PATH', '')}"
    env["PYTHONNOUSERSITE"] = "1"
    # The locked versions (the wheels pip has cached from `make setup`), the build
    # backend's too (pip's isolated build environment reads PIP_CONSTRAINT)
    env["PIP_CONSTRAINT"] = str(ROOT / "fit" / "requirements.lock")
    env["PIP_DISABLE_PIP_VERSION_CHECK"] = "1"
    t0 = time.perf_counter()
    _run([sys.executable, "-m", "venv", str(venv)], work, env)
    py = str(venv / "bin" / "python")
    _run([py, "-m", "pip", "install", "--quiet", str(ROOT / "runtime" / "python"),
          str(ROOT / "fit")], work, env, timeout=900)
    t1 = time.perf_counter()

    out = _run([py, "-c", READ_TABLE, str(TABLE)], work, env).stdout.splitlines()
    site = (venv / "lib").resolve()
    for path in out[:4]:  # lensrt, lensrt_ctypes, lensrt_exr and the library
        resolved = Path(path).resolve()
        assert resolved.is_relative_to(site), (path, site)
        assert not resolved.is_relative_to(ROOT), path
    assert Path(out[3]).name == "liblensrt.so" and Path(out[3]).parent.name == "lensrt"
    assert "Angenieux" in out[4]

    spec = work / "tiny.toml"
    spec.write_text(TINY_BANK)
    lensfit_bin = str(venv / "bin" / "lensfit")
    # No generated/ here: the error names the folder and the settings
    refused = subprocess.run([lensfit_bin, "bank", str(spec), "-o", "out", "--workers", "0"],
                             cwd=work, env=env, capture_output=True, text=True, timeout=300,
                             check=False)
    assert refused.returncode == 2, refused
    assert str(work / "generated") in refused.stderr and "--generated" in refused.stderr
    _run([lensfit_bin, "bank", str(spec), "-o", "out", "--workers", "0", "--no-progress",
          "--generated", str(ROOT / "generated")], work, env)
    read = _run([py, "-c", READ_BANK, str(work / "out" / "bank.index")], work, env).stdout
    assert read.split()[1] == "2", read
    # lensdb from the environment (no checkout to fall back on)
    listed = _run([lensfit_bin, "list"], work,
                  {**env, "LENSFIT_LENSDB": str(ROOT / "lensdb")}).stdout
    assert "0001" in listed
    print(f"venv and pip install (lensrt wheel built): {t1 - t0:.0f} s; "
          f"the rest {time.perf_counter() - t1:.0f} s")
