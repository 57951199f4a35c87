"""Checkpoints of `lensfit fit`, so that an interrupted fit resumes where it stopped.

After each system (P_o, then P_s) is sampled and fitted, and after the PSF check against
exact rays, the stage writes a checkpoint to a cache folder (default
``build/fit-cache/`` under the current directory, beside the default report folder
``build/report/``; ``$LENSFIT_FIT_CACHE`` names another):

    build/fit-cache/<lens folder>-<key: 16 hex digits>/P_o.json, P_s.json, psf.json

The key is the SHA-256 of everything that determines the result (:func:`fit_key`): the
lens as loaded (every surface, glass and coating with its numbers, and the lens file's
parsed content), the domain and the options (``to_dict``), the scene's PSF cells of a
scene fit, and the version of the code that computes them (lensfit's version and a hash
of the sources of fitting/, poly/, sample/, trace/, paraxial/, psf.py, trust.py and this
module). A rerun of the same command finds the same folder and takes each finished step
from it instead of sampling and fitting again; any other input gives another folder.

A system's checkpoint holds the fitted System (``System.to_dict``: coefficients as JSON
numbers, which round-trip float64 exactly), its OutputFit list, and of the samples only
what the report needs: the held-out rays (their arrays, bit for bit, base64) and the
counts of the training rays. Each file is written atomically (:mod:`lensfit.atomic`),
carries the full key and a CRC-32 of its canonical text (:mod:`lensfit.codegen
.checked_json`); one that does not read back exactly, or names another key, is ignored
with a one-line note on stderr and the step is redone. The stage removes the folder once
the generated folder and the report are written.
"""

from __future__ import annotations

import base64
import dataclasses
import hashlib
import json
import os
import shutil
import sys
from pathlib import Path
from typing import Any

import numpy as np

from lensfit.atomic import write_files
from lensfit.codegen.checked_json import checked_json_text, load_checked_json
from lensfit.errors import InputError
from lensfit.fitting.results import OutputFit, SystemFit
from lensfit.poly.polynomial import System
from lensfit.sample.rays import Samples

FORMAT = "lensfit-fit-checkpoint 1"
ENV = "LENSFIT_FIT_CACHE"
DEFAULT_DIR = Path("build/fit-cache")
_PACKAGE = Path(__file__).resolve().parent
# The sources whose change can change a fit or its PSF check
_CODE = ("fitting", "poly", "sample", "trace", "paraxial", "psf.py", "trust.py",
         "facts.py", "fit_cache.py")


def cache_root() -> Path:
    """The folder that holds the checkpoint folders: $LENSFIT_FIT_CACHE, else
    build/fit-cache under the current directory."""
    return Path(os.environ.get(ENV) or DEFAULT_DIR)


def code_version() -> str:
    """lensfit's version and a hash of the fitting code's sources."""
    try:
        from importlib.metadata import version

        v = version("lensfit")
    except Exception:  # noqa: BLE001  (not installed: the sources decide alone)
        v = "unknown"
    h = hashlib.sha256()
    for entry in _CODE:
        p = _PACKAGE / entry
        files = sorted(p.rglob("*.py")) if p.is_dir() else [p]
        for f in files:
            h.update(str(f.relative_to(_PACKAGE)).encode() + b"\0" + f.read_bytes() + b"\0")
    return f"{v}+{h.hexdigest()[:16]}"


def canonical(obj: Any) -> Any:
    """A JSON-ready form of ``obj`` that changes with every number in it: floats as
    their exact repr, arrays by hash, dataclasses by their compared fields."""
    if isinstance(obj, bool) or obj is None or isinstance(obj, (int, str)):
        return obj
    if isinstance(obj, float):
        return repr(obj)
    if isinstance(obj, np.ndarray):
        a = np.ascontiguousarray(obj)
        return {"array": str(a.dtype), "shape": list(a.shape),
                "sha256": hashlib.sha256(a.tobytes()).hexdigest()}
    if isinstance(obj, np.generic):
        return canonical(obj.item())
    if isinstance(obj, dict):
        return {str(k): canonical(v) for k, v in sorted(obj.items(), key=lambda kv: str(kv[0]))}
    if isinstance(obj, (list, tuple)):
        return [canonical(v) for v in obj]
    if isinstance(obj, (set, frozenset)):
        return sorted((canonical(v) for v in obj), key=repr)
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        d = {f.name: canonical(getattr(obj, f.name)) for f in dataclasses.fields(obj)
             if f.compare}
        return {"type": type(obj).__name__, **d}
    return {"type": type(obj).__name__, "repr": repr(obj)}


def lens_content(lens) -> dict[str, Any]:
    """The lens as loaded (surfaces with their glasses and coatings, name, variant) and
    the parsed lens file; not where the file lies."""
    d = canonical(lens)
    d["source_file"] = Path(lens.source_file).name
    return {"lens": d, "raw": canonical(lens.raw)}


def fit_key(lens, domain, options, psf_args: dict[str, Any] | None = None) -> str:
    """The SHA-256 (hex) of everything that determines a fit and its PSF check."""
    doc = {"format": FORMAT, "code": code_version(), "lens": lens_content(lens),
           "domain": canonical(domain.to_dict()), "options": canonical(options.to_dict()),
           "psf": canonical(psf_args or {})}
    return hashlib.sha256(json.dumps(doc, sort_keys=True).encode()).hexdigest()


def _array(a: np.ndarray) -> dict[str, Any]:
    a = np.ascontiguousarray(a)
    return {"dtype": a.dtype.str, "shape": list(a.shape),
            "base64": base64.b64encode(a.tobytes()).decode("ascii")}


_DTYPES = ("<f8", "<i8", "<i4", "|b1")


def _unarray(d: dict[str, Any]) -> np.ndarray:
    if d["dtype"] not in _DTYPES:
        raise ValueError(f"dtype {d['dtype']!r} not expected")
    a = np.frombuffer(base64.b64decode(d["base64"], validate=True), dtype=d["dtype"])
    return a.reshape([int(n) for n in d["shape"]]).copy()


@dataclasses.dataclass
class TrainSummary:
    """What the report reads of the training samples (their counts), standing in for
    them in a resumed fit."""

    n: int
    requested: int
    dropped: dict[str, int]

    def __len__(self) -> int:
        return self.n


class FitCache:
    """The checkpoints of one fit (one key) in ``root/<label>-<key[:16]>/``."""

    def __init__(self, key: str, label: str, root: Path | None = None,
                 note=None) -> None:
        self.key = key
        self.folder = Path(root if root is not None else cache_root()) / f"{label}-{key[:16]}"
        self._note = note or (lambda msg: print(f"lensfit: note: {msg}", file=sys.stderr))
        self._loaded: dict[str, Any] = {}

    def _path(self, step: str) -> Path:
        return self.folder / f"{step}.json"

    def _read(self, step: str) -> dict[str, Any] | None:
        path = self._path(step)
        if not path.is_file():
            return None
        try:
            doc = load_checked_json(path, "")
        except InputError as e:
            self._note(f"{e}: checkpoint ignored; the step is done again")
            return None
        if doc.get("format") != FORMAT or doc.get("key") != self.key or doc.get("step") != step:
            self._note(f"{path}: a checkpoint of another fit (format, key or step differ): "
                       "ignored; the step is done again")
            return None
        return doc

    def load_system(self, name: str) -> SystemFit | None:
        """The checkpointed fit of system ``name``, or None (absent or refused)."""
        if name not in self._loaded:
            doc = self._read(name)
            fit = None
            if doc is not None:
                try:
                    fit = _system_fit(doc)
                except (KeyError, TypeError, ValueError) as e:
                    self._note(f"{self._path(name)}: unreadable checkpoint ({e}): ignored; "
                               "the step is done again")
            self._loaded[name] = fit
        return self._loaded[name]

    def save_system(self, fit: SystemFit) -> None:
        doc = {
            "system": fit.system.to_dict(),
            "outputs": [o.to_dict() for o in fit.outputs],
            "train": {"n": len(fit.train), "requested": int(fit.train.requested),
                      "dropped": {k: int(v) for k, v in fit.train.dropped.items()}},
            "test": {"system": fit.test.system, "inputs": _array(fit.test.inputs),
                     "outputs": _array(fit.test.outputs), "group": _array(fit.test.group),
                     "vignetting": _array(fit.test.vignetting),
                     "requested": int(fit.test.requested),
                     "dropped": {k: int(v) for k, v in fit.test.dropped.items()}},
            "seconds_sampling": fit.seconds_sampling, "seconds_fitting": fit.seconds_fitting,
        }
        self._write(fit.system.name, doc)
        self._loaded[fit.system.name] = fit

    def load_psf(self) -> dict[str, Any] | None:
        """The checkpointed PSF table (lensfit.trust.psf_vs_exact), or None."""
        if "psf" not in self._loaded:
            doc = self._read("psf")
            table = doc.get("table") if doc is not None else None
            if doc is not None and not (isinstance(table, dict) and "cells" in table
                                        and "worst" in table):
                self._note(f"{self._path('psf')}: unreadable checkpoint: ignored; the PSF "
                           "check is done again")
                table = None
            self._loaded["psf"] = table
        return self._loaded["psf"]

    def save_psf(self, table: dict[str, Any]) -> None:
        self._write("psf", {"table": table})
        self._loaded["psf"] = table

    def _write(self, step: str, doc: dict[str, Any]) -> None:
        """Write a checkpoint atomically; one that cannot be written (a full disc, a
        number JSON cannot hold) is noted, and the fit goes on without it."""
        try:
            text = checked_json_text({"format": FORMAT, "key": self.key, "step": step, **doc})
            write_files(self.folder, {f"{step}.json": text})
        except (ValueError, InputError, OSError) as e:
            self._note(f"{self._path(step)}: checkpoint not written ({e})")

    def clear(self) -> None:
        """Remove the checkpoints (after the generated folder and report are written)."""
        shutil.rmtree(self.folder, ignore_errors=True)
        try:
            self.folder.parent.rmdir()  # build/fit-cache/ when it holds nothing else
        except OSError:
            pass


def _system_fit(doc: dict[str, Any]) -> SystemFit:
    system = System.from_dict(doc["system"])
    outputs = [OutputFit(**o) for o in doc["outputs"]]
    if [o.name for o in outputs] != system.output_names:
        raise ValueError("outputs do not match the system")
    t = doc["test"]
    test = Samples(str(t["system"]), _unarray(t["inputs"]), _unarray(t["outputs"]),
                   _unarray(t["group"]), _unarray(t["vignetting"]), int(t["requested"]),
                   {str(k): int(v) for k, v in t["dropped"].items()})
    if test.system != system.name or test.inputs.shape != (len(test), len(system.inputs)):
        raise ValueError("held-out rays do not match the system")
    tr = doc["train"]
    train = TrainSummary(int(tr["n"]), int(tr["requested"]),
                         {str(k): int(v) for k, v in tr["dropped"].items()})
    return SystemFit(system, outputs, train, test,  # type: ignore[arg-type]
                     float(doc["seconds_sampling"]), float(doc["seconds_fitting"]))
