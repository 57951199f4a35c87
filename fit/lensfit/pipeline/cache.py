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
counts of the training rays. Each file is written atomically (:mod:`lensfit.common.atomic`),
carries the full key and a CRC-32 of its canonical text (:mod:`lensfit.codegen
.checked_json`); one that does not read back exactly, or names another key, is ignored
with a one-line note on stderr and the step is redone. The stage removes the folder once
the generated folder and the report are written.

A checksum only says the file is as some writer left it, so what it holds is checked as
well before it is used (issue 39): a system's held-out errors are computed again from
its polynomials and the held-out rays and must be the ones recorded (an edited
coefficient or ray changes them), every figure has its type and a finite value, and the
PSF check names the SHA-256 of the polynomials it judged (:func:`systems_digest`), so a
table's trust line always comes from a check of the polynomials written beside it.
"""

from __future__ import annotations

import base64
import dataclasses
import hashlib
import json
import math
import os
import shutil
import sys
from pathlib import Path
from typing import Any

import numpy as np

from lensfit.codegen.checked_json import checked_json_text, load_checked_json
from lensfit.common.atomic import write_files
from lensfit.common.errors import InputError
from lensfit.fitting.lens import SYSTEMS
from lensfit.fitting.results import OutputFit, SystemFit, error_metric
from lensfit.poly.polynomial import Input, System
from lensfit.sample.rays import Samples

FORMAT = "lensfit-fit-checkpoint 1"
ENV = "LENSFIT_FIT_CACHE"
DEFAULT_DIR = Path("build/fit-cache")
_PACKAGE = Path(__file__).resolve().parents[1]
# The sources whose change can change a fit or its PSF check (paths in lensfit/)
_CODE = ("fitting", "poly", "sample", "trace", "paraxial", "psf", "trust/check.py",
         "pipeline/cache.py")


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

    def load_system(self, name: str, inputs: tuple[Input, ...] | None = None
                    ) -> SystemFit | None:
        """The checkpointed fit of system ``name`` (over exactly ``inputs`` when given:
        names, units and domains), or None (absent or refused)."""
        if name not in self._loaded:
            doc = self._read(name)
            fit = None
            if doc is not None:
                try:
                    fit = _system_fit(doc)
                    if fit.system.name != name:
                        raise ValueError(f"it holds system {fit.system.name!r}")
                except (KeyError, TypeError, ValueError, AttributeError, IndexError,
                        OverflowError) as e:
                    self._note(f"{self._path(name)}: unreadable checkpoint ({e}): ignored; "
                               "the step is done again")
            self._loaded[name] = fit
        fit = self._loaded[name]
        if fit is not None and inputs is not None and fit.system.inputs != tuple(inputs):
            self._note(f"{self._path(name)}: a checkpoint over other inputs (names, units or "
                       "domains) than this fit's: ignored; the step is done again")
            self._loaded[name] = fit = None
        return fit

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

    def load_psf(self, systems: list[System]) -> dict[str, Any] | None:
        """The checkpointed PSF table (lensfit.trust.check.psf_vs_exact) of exactly these
        ``systems``, or None (absent, refused, or the check of other polynomials)."""
        digest = systems_digest(systems)
        if self._loaded.get("psf_of") != digest:
            doc = self._read("psf")
            table = None
            if doc is not None:
                try:
                    if doc.get("systems_sha256") != digest:
                        raise ValueError("it checked other polynomials than these")
                    table = check_psf_table(doc.get("table"))
                except (KeyError, TypeError, ValueError) as e:
                    self._note(f"{self._path('psf')}: unreadable checkpoint ({e}): ignored; "
                               "the PSF check is done again")
            self._loaded["psf"], self._loaded["psf_of"] = table, digest
        return self._loaded["psf"]

    def save_psf(self, table: dict[str, Any], systems: list[System]) -> None:
        digest = systems_digest(systems)
        self._write("psf", {"table": table, "systems_sha256": digest})
        self._loaded["psf"], self._loaded["psf_of"] = table, digest

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


def systems_digest(systems: list[System]) -> str:
    """The SHA-256 (hex) of the polynomials of ``systems`` (every input, exponent and
    coefficient, exactly): what a PSF check checkpoint names as what it judged."""
    doc = [s.to_dict() for s in systems]
    return hashlib.sha256(json.dumps(doc, sort_keys=True).encode()).hexdigest()


def _is(value: Any, kind: str, where: str) -> Any:
    """``value`` when it is a ``kind`` ("text", "count": an int >= 0, "real": a finite
    float or int, "flag": a bool), else ValueError naming ``where`` and the value."""
    ok = {"text": lambda v: isinstance(v, str),
          "count": lambda v: isinstance(v, int) and not isinstance(v, bool) and v >= 0,
          "real": lambda v: (isinstance(v, (int, float)) and not isinstance(v, bool)
                             and math.isfinite(v)),
          "flag": lambda v: isinstance(v, bool)}[kind](value)
    if not ok:
        raise ValueError(f"{where}: expected a {kind}, found {str(value)[:40]!r}")
    return value


def _dropped(d: Any, where: str) -> dict[str, int]:
    if not isinstance(d, dict):
        raise ValueError(f"{where}: expected an object of counts")
    return {_is(k, "text", where): _is(v, "count", f"{where}.{k}") for k, v in d.items()}


# OutputFit's fields by kind (the optional ones may also be null)
_OUTPUT_KINDS = {"system": "text", "name": "text", "unit": "text", "terms": "count",
                 "max_degree": "count", "rms": "real", "max": "real", "target": "real",
                 "reached": "flag", "piston_terms": "count"}
_OUTPUT_OPTIONAL = {"absolute_rms_um": "real", "limit": "text", "ns_per_eval_double": "real",
                    "ns_per_eval_float": "real"}


def _output(d: Any, i: int) -> OutputFit:
    """An OutputFit from its checkpointed dict, every field of its type."""
    where = f"outputs[{i}]"
    if not isinstance(d, dict) or set(d) != {f.name for f in dataclasses.fields(OutputFit)}:
        raise ValueError(f"{where}: expected the fields of an output's fit")
    for k, kind in _OUTPUT_KINDS.items():
        _is(d[k], kind, f"{where}.{k}")
    for k, kind in _OUTPUT_OPTIONAL.items():
        if d[k] is not None:
            _is(d[k], kind, f"{where}.{k}")
    for k, kind in (("path_terms", "count"), ("path_rms", "real")):
        if not isinstance(d[k], list):
            raise ValueError(f"{where}.{k}: expected a list")
        for v in d[k]:
            _is(v, kind, f"{where}.{k}")
    return OutputFit(**d)


# A held-out error computed again may differ from the recorded one by the rounding of
# another evaluation order (the fit sums the tensor form, this the monomials): ~1e-13
# relative, measured, and 1e-6 of the output's target where the error is itself at
# rounding level. A changed coefficient or ray moves it far more
_RECHECK_RELATIVE = 1e-6


def _recheck(system: System, outputs: list[OutputFit], test: Samples) -> None:
    """ValueError unless the held-out errors of ``system`` on ``test``'s rays that pass
    are the ones ``outputs`` record."""
    te = test.subset(test.passes)
    if len(te) == 0:
        raise ValueError("no held-out ray passes")
    with np.errstate(all="ignore"):
        pred = system.evaluate(te.inputs)
    for j, o in enumerate(outputs):
        err = error_metric(o.name, pred[:, j], te.outputs[:, j], te.group)
        rms = float(np.sqrt(np.mean(err * err)))
        if not abs(rms - o.rms) <= _RECHECK_RELATIVE * (abs(o.rms) + abs(o.target)):
            raise ValueError(f"{system.name} {o.name}: the polynomial's held-out error is "
                             f"{rms:.6g} {o.unit}, the record says {o.rms:.6g}")


# Each system's input names and (output, unit) pairs, as lensfit.fitting.lens fits them
_INPUTS = {"P_o": ["x_O", "y_O", "u_O", "x_a", "y_a", "lambda"],
           "P_s": ["x_S", "y_S", "z_S", "x_a", "y_a", "lambda"]}
_OUTPUTS = {name: [list(o) for o in outs] for name, outs in SYSTEMS}


def _system_fit(doc: dict[str, Any]) -> SystemFit:
    system = System.from_dict(doc["system"])
    if system.input_names != _INPUTS.get(system.name) \
            or [[p.output, p.unit] for p in system.outputs] != _OUTPUTS.get(system.name):
        raise ValueError(f"system {system.name[:20]!r}: not the inputs and outputs of a "
                         "lens system")
    if not all(math.isfinite(i.lo) and math.isfinite(i.hi) and i.lo < i.hi
               for i in system.inputs):
        raise ValueError("an input's domain is not finite lo < hi")
    if not isinstance(doc["outputs"], list):
        raise ValueError("outputs: expected a list")
    outputs = [_output(o, i) for i, o in enumerate(doc["outputs"])]
    if [o.name for o in outputs] != system.output_names:
        raise ValueError("outputs do not match the system")
    t = doc["test"]
    test = Samples(_is(t["system"], "text", "test.system"), _unarray(t["inputs"]),
                   _unarray(t["outputs"]), _unarray(t["group"]), _unarray(t["vignetting"]),
                   _is(t["requested"], "count", "test.requested"),
                   _dropped(t["dropped"], "test.dropped"))
    n = len(test)
    if (test.system != system.name or test.inputs.shape != (n, len(system.inputs))
            or test.outputs.shape != (n, len(system.outputs)) or test.group.shape != (n,)
            or test.vignetting.shape != (n,)):
        raise ValueError("held-out rays do not match the system")
    _recheck(system, outputs, test)
    tr = doc["train"]
    train = TrainSummary(_is(tr["n"], "count", "train.n"),
                         _is(tr["requested"], "count", "train.requested"),
                         _dropped(tr["dropped"], "train.dropped"))
    return SystemFit(system, outputs, train, test,  # type: ignore[arg-type]
                     float(_is(doc["seconds_sampling"], "real", "seconds_sampling")),
                     float(_is(doc["seconds_fitting"], "real", "seconds_fitting")))


# A PSF check cell's keys by kind (lensfit.trust.check.psf_vs_exact); "field_share" optional
_CELL_KINDS = {"stop": "text", "f_number": "real", "stop_radius_mm": "real", "field": "text",
               "wavelength_nm": "real", "focus_offset_mm": "real", "window_um": "real",
               "pixels": "count", "points": "count", "relative_l2": "real"}


def check_psf_table(table: Any) -> dict[str, Any]:
    """``table`` when it is a PSF check table of the kind lensfit.trust.check.psf_vs_exact
    makes (cells of the right types, positive where physical, ``worst`` the worst of
    them), else ValueError saying what is wrong."""
    if not isinstance(table, dict) or not isinstance(table.get("cells"), list) \
            or not table["cells"]:
        raise ValueError("table: expected an object with a list of cells")
    for i, c in enumerate(table["cells"]):
        where = f"cells[{i}]"
        if not isinstance(c, dict):
            raise ValueError(f"{where}: expected an object")
        for k, kind in _CELL_KINDS.items():
            _is(c.get(k), kind, f"{where}.{k}")
        for k in ("f_number", "stop_radius_mm", "wavelength_nm", "window_um"):
            if not c[k] > 0:
                raise ValueError(f"{where}.{k}: expected a positive value, found {c[k]!r}")
        if c["relative_l2"] < 0 or c["pixels"] < 1 or c["points"] < 1:
            raise ValueError(f"{where}: a negative error, or no pixel or stop point")
        field = c.get("field_deg")
        if not (isinstance(field, list) and len(field) == 2):
            raise ValueError(f"{where}.field_deg: expected two angles")
        for v in field:
            _is(v, "real", f"{where}.field_deg")
        if c.get("distance_mm") != "inf":
            _is(c.get("distance_mm"), "real", f"{where}.distance_mm")
        if "field_share" in c:
            _is(c["field_share"], "real", f"{where}.field_share")
    worst = max(table["cells"], key=lambda c: c["relative_l2"])
    if table.get("worst") != worst:
        raise ValueError("worst: not the worst of the cells")
    return table
