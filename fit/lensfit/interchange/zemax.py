"""Zemax OpticStudio sequential lens files (.zmx): import to lensfit's TOML, export from it.

The .zmx file is line-oriented text, UTF-16 LE with a byte-order mark (OpticStudio) or
plain ASCII/UTF-8 (older versions, other programs); both are read. Each line is a
keyword and its values; a ``SURF n`` line opens surface n (0 is the object, the last
is the image) and the indented lines after it describe that surface. Keyword meanings
follow the OpticStudio manual (surface types, parameter columns) and the files it
writes.

Mapped (each value kept exactly as written; lengths in lens units, see UNIT):

* ``SURF n`` (consecutive from 0), ``TYPE`` STANDARD, EVENASPH, TOROIDAL;
  ``CURV c`` (1/length): ``radius = 1/c`` (``radius_for``), c = 0 is a ``plane``;
  ``CONI k``: a non-zero conic makes a STANDARD surface an ``asphere``; ``DISZ``
  (thickness; ``INFINITY`` only on the object); ``STOP``; ``DIAM value solve ...`` (the
  semi-diameter, despite its name, and its solve type);
  ``CLAP 0 r`` / ``FLAP 0 r`` (a circular hard aperture: ``semi_diameter = r``, which
  is lensfit's meaning of a semi-diameter: rays beyond it are blocked). A surface
  without DIAM (or with DIAM 0: not computed) gets the paraxial estimate
  |y_marginal| + |y_chief| from FLOA/ENPD/FNUM and the largest angle field, with a note
  (``common.paraxial_semi_diameters``); without an aperture setting that is an error.
* Apertures and automatic semi-diameters (``lensfit.interchange.housings``): the stop's
  semi-diameter (whatever its solve), CLAP/FLAP and a fixed DIAM (solve type 1, "U" in
  the Lens Data Editor; a DIAM without a solve type, as typed by hand) are apertures
  and kept as written. DIAM solve type 0 (automatic: sized by OpticStudio to just pass
  its beam), 2 (pickup) and 3 (maximum), other solves, and the estimates are automatic:
  widened to pass, with a margin, every real ray of the design beam and of the default
  fit domain, ``aperture = "automatic"`` and the file's value as
  ``design_semi_diameter``. ``lensfit import`` prints one line per surface saying which
  it was and what was done.
* EVENASPH: ``PARM 1..8`` are alpha_1..alpha_8 on r^2..r^16. lensfit's asphere has no
  r^2 term, so PARM 1 must be 0; PARM 2..8 become ``aspheric = [A4, ..., A16]``
  (trailing zeros dropped), ``CONI`` the ``conic``.
* TOROIDAL (a y-z curve rotated about an axis parallel to y at the radius of rotation
  ``PARM 1``, 0 meaning infinite; PARM 2..8 polynomial terms on y^2..y^14; extra data
  ``XDAT 1`` the number of Zernike terms, ``XDAT 2`` their normalisation radius, ``PARM
  0`` their extrapolation flag: all inert without terms). Only exact cylinders and
  spheres are mapped:
  CURV c, PARM 1 = 0 -> ``cylinder-x`` (flat along x, power in y) of radius 1/c;
  CURV 0, PARM 1 = R -> ``cylinder-y`` (power in x) of radius R; PARM 1 = 1/c -> a
  ``sphere``; both zero -> ``plane``. A conic, a polynomial term or a Zernike term
  is an error.
* ``GLAS NAME ...``: a catalog glass, qualified by the ``GCAT`` catalogs in their
  order (``lensfit.interchange.common.resolve_glass``; an older HIKARI name is its
  current one, with a note); the nd/vd that follow a catalog name are ignored
  (OpticStudio stores placeholders there).
  ``GLAS ___BLANK 1 0 nd vd dPgF ...`` (a MODEL glass as OpticStudio writes it) and
  ``GLAS MODEL 1 0 nd vd dPgF ...`` (as Optiland's .zmx writer writes it, the same
  columns, dPgF always 0: ``optiland.fileio.zemax.writer.encoder``) -> ``nd``/``vd``
  and, when not 0, ``dpgf`` (the deviation of P_g,F from the normal line) with lensfit's
  Abbe model (lensdb/glass/README.md); ``vd 0`` (OpticStudio's medium without
  dispersion) -> the constant index ``material = { n = nd }`` (``nd 1 vd 0``: air); a
  note per surface. Optiland writes vd 99.99 for a medium without dispersion (its
  nF = nC): kept as written (Optiland reads it back so), with a note.
  nd outside 1-3 (above 3: an infrared medium such as germanium, opaque to the visible
  light lensfit traces), vd outside 5-150 (other than 0) or |dPgF| > 0.1 is an error.
  ``MIRROR`` is an error (no mirrors in lensfit).
* ``UNIT``: MM as is; CM, IN, METER are kept as written with ``[lens] scale`` = 10,
  25.4, 1000 (lensfit multiplies every length and scales the aspheric terms by it at
  load time: the exact conversion). Other units are an error.
* ``NAME`` -> ``[lens] name``; ``NOTE`` -> ``[lens] notes``; ``FNUM F`` -> ``f_number``;
  ``FTYP 0 ..`` (angles in degrees) with ``XFLN``/``YFLN`` (or ``XFLD``/``YFLD``) ->
  ``field_of_view_deg``, twice the largest field angle from the axis,
  atan(sqrt(tan^2 x + tan^2 y)); ``FLOA`` (aperture set by the stop size) is
  lensfit's model: the stop surface's semi-diameter is the aperture. ``ENPD D`` (or,
  without it, ``FNUM``) is the design's aperture: ``[fit] f_number`` = EFL / D at the d
  line (or the FNUM value), the aperture ``lensfit fit`` fits by default, unless the
  stop cannot open that wide (a note).

Errors (exit 2, nothing written, every problem listed, one line each naming the line
number): an unsupported surface type (COORDBRK, ODDASPHE, BICONICX, PARAXIAL, ...); a
mirror; non-sequential data (``MODE`` other than SEQ, ``NSOB``/``NSCT`` objects,
TYPE NONSEQCO); an unknown glass or catalog; a term that lensfit cannot represent
(see above); an aperture other than a centred circle (``SQAP``, ``ELAP``, ``OBSC``,
``OBDC`` offsets, an annular ``CLAP``); a tilt or decenter (``SCBD``); a curved image
surface; glass in front of the first surface; a malformed line (a bad number, a
missing value, a truncated or misnumbered ``SURF``, a surface without ``DISZ``); an
unknown keyword inside a surface (it may change the optics; one whose values are all
zero is a note); a lens lensfit's loader refuses (on the line of the surface it names,
and any other surface the loader's message names by its SURF number).

Notes (printed on stderr, the lens is written): wavelengths (``WAVM``, ``WAVL``,
``WWGT``, ``PWAV``), the object distance and object-surface curvature, the entrance
NA (``OBNA``; lensfit's aperture is the stop size), field types
other than angles, the image surface's size, comments (``COMM``), coatings (``COAT``:
the lens is written uncoated, ``[coating] default = "none"``, as OpticStudio traces a
surface without a coating), pickups, solves and variable flags (``PZUP``, ``PPAR``,
``MAZH``, ``VPAR``: the values they resolved to are in the file; ``MAZH h z`` is the
thickness solve on the marginal ray's height h at pupil zone z, OpticStudio's
"Marginal Ray Height", whose solved thickness is the surface's DISZ), environment
(``ENVD``), configurations (``MNUM``, ``MOFF``), unknown keywords outside surfaces; per
surface, what each MODEL glass became and an older HIKARI name taken as the current one.

Ignored without a note: pure user-interface, drawing, analysis, tolerancing and
optimiser settings (``IGNORED_TOP``, ``IGNORED_SURFACE``; a test keeps these lists and
this docstring the same). At the top level: VERS PFIL GFAC RAIM PUSH SDMA ROPD PICB
POLS GLRS GSTD NSCD COFN BLNK TOL OPDX LANG FWGN FWGT VANN VCXN VCYN VDXN VDYN ZVCX
ZVCY ZVDX ZVDY ZVAN HYPR IWDP LUID OMMA TRAC EERA EFLY REAX REAY DBDT ACOS AUTH GLCB
RCMF STUD WFNO DMFS EFFL SLAB MNCA MNEA MNCG MNEG MXCA MXCG RGLA TCMM PMAG TOTR POPS
FIMP WWGN WAVN CONF TCED (vignetting factors and field weights aim the analysis rays,
not the lens). In a surface: HIDE MIRR SLAB POPS MEMA OEMA FIMP SSID VDSZ VCON TCED
(hide flags, the drawing's mirror substrate, labels, physical-optics settings,
mechanical semi-apertures of the drawing, the optimiser's variable flags on the
thickness and the conic: the values are on DISZ and CONI). ``NSCD`` is on the list:
OpticStudio writes these non-sequential *ray-trace settings* into every sequential file;
non-sequential *objects* (``NSOB``) are errors.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from lensfit.common.errors import regular_file_problem
from lensfit.glass import MODEL_DPGF_MAX, MODEL_VD_RANGE, UnknownGlassError
from lensfit.interchange.common import (
    ImportProblems,
    ImportResult,
    Notes,
    file_surfaces,
    glass_message,
    index_range_problem,
    lens_table,
    paraxial_semi_diameters,
    resolve_glass,
    validate,
)
from lensfit.interchange.housings import FileAperture, size_housings

# Lens units: the factor to millimetres, written as [lens] scale (MM: none)
UNITS = {"MM": None, "CM": 10.0, "IN": 25.4, "INCH": 25.4, "METER": 1000.0, "METR": 1000.0,
         "M": 1000.0}
UNIT_NAMES = {None: "mm", 10.0: "cm", 25.4: "in", 1000.0: "m"}  # in lensfit import's lines
# DIAM's second value, the semi-diameter solve type (OpticStudio's summary of solves:
# 0 automatic, 1 fixed "U", 2 pickup, 3 maximum); 1 is an aperture, the rest automatic
DIAM_SOLVES = {0: "automatic", 1: "fixed", 2: "pickup", 3: "maximum"}

# Top-level keywords that only set up the user interface, drawings, analyses, tolerancing
# or the optimiser (and never the lens): ignored without a note.
IGNORED_TOP = frozenset({
    "VERS", "PFIL", "GFAC", "RAIM", "PUSH", "SDMA", "ROPD", "PICB", "POLS", "GLRS", "GSTD",
    "NSCD", "COFN", "BLNK", "TOL", "OPDX", "LANG", "FWGN", "FWGT", "VANN", "VCXN", "VCYN",
    "VDXN", "VDYN", "ZVCX", "ZVCY", "ZVDX", "ZVDY", "ZVAN", "HYPR", "IWDP", "LUID", "OMMA",
    "TRAC", "EERA", "EFLY", "REAX", "REAY", "DBDT", "ACOS", "AUTH", "GLCB", "RCMF", "STUD",
    "WFNO", "DMFS", "EFFL", "SLAB", "MNCA", "MNEA", "MNCG", "MNEG", "MXCA", "MXCG", "RGLA",
    "TCMM", "PMAG", "TOTR", "POPS", "FIMP", "WWGN", "WAVN", "CONF", "TCED",
})
# Surface keywords of the same kind: hide flags, the drawing's mirror substrate and
# label, physical-optics settings, mechanical (drawing) semi-apertures, import flags,
# and the optimiser's variable flags on the thickness and the conic (VDSZ; VCON, written
# without values as in RC_Lens.zmx of the corpus): the values are on DISZ and CONI.
IGNORED_SURFACE = frozenset({"HIDE", "MIRR", "SLAB", "POPS", "MEMA", "OEMA", "FIMP", "SSID",
                             "VDSZ", "VCON", "TCED"})

NOTED_TOP = {
    "WAVM": "wavelength not mapped (lensfit fits a wavelength range: lensfit fit "
            "--wavelengths)",
    "WAVL": "wavelengths not mapped (lensfit fits a wavelength range)",
    "WWGT": "wavelength weights not mapped",
    "PWAV": "primary wavelength not mapped (paraxial data are at the d line)",
    "OBNA": "object-space NA not mapped (lensfit's aperture is the stop surface's "
            "semi-diameter)",
    "ENVD": "temperature and pressure not mapped (catalog indices at their reference)",
    "MNUM": "configurations not mapped (the current configuration's values are used)",
    "MOFF": "multi-configuration operand not mapped (the current configuration is used)",
}
NOTED_SURFACE = {
    "COMM": "surface comment not mapped",
    "COAT": "coating not mapped (the lens is written uncoated)",
    "PZUP": "pickup not mapped (the value it resolved to is used)",
    "PPAR": "parameter pickup not mapped (the value it resolved to is used)",
    # OpticStudio's "Marginal Ray Height" thickness solve (MAZH height pupil-zone): the
    # thickness it solved to is the surface's DISZ
    "MAZH": "thickness solve on the marginal ray height not mapped (the thickness it "
            "solved to, DISZ, is used)",
    "VPAR": "variable flag not mapped (optimiser setting)",
}
ERROR_SURFACE = {
    "SQAP": "rectangular aperture: unsupported (lensfit's apertures are centred circles)",
    "ELAP": "elliptical aperture: unsupported (lensfit's apertures are centred circles)",
    "OBSC": "obscuration: unsupported (lensfit's apertures are centred circles)",
    "SCBD": "surface tilt or decenter: unsupported (lensfit's surfaces are centred)",
}
SURFACE_KEYWORDS = frozenset({"TYPE", "CURV", "CONI", "PARM", "XDAT", "DISZ", "GLAS",
                              "DIAM", "STOP", "CLAP", "FLAP", "OBDC"})
SUPPORTED_TYPES = ("STANDARD", "EVENASPH", "TOROIDAL")
MODEL_GLASS = "___BLANK"
# The wavelengths `lensfit export` writes (um): the d, F and C lines, d primary
EXPORT_WAVELENGTHS_UM = ("0.5875618", "0.4861327", "0.6562725")
# Optiland's .zmx writer names its model glasses MODEL, in the columns of ___BLANK
MODEL_GLASS_NAMES = (MODEL_GLASS, "MODEL")
# and writes this vd for a medium without dispersion (optiland.fileio.common,
# compute_abbe_number: 99.99 when nF - nC is below 1e-12)
OPTILAND_NO_DISPERSION_VD = 99.99


@dataclass
class _Surf:
    """One SURF block as read: each value with the line it came from."""

    number: int
    line: int
    values: dict[str, tuple[list[str], int]] = field(default_factory=dict)
    parm: dict[int, tuple[float, int]] = field(default_factory=dict)
    xdat: dict[int, tuple[float, int]] = field(default_factory=dict)

    def where(self) -> str:
        return f"{self.line}: SURF {self.number}"


def decode(raw: bytes) -> str:
    """The text of a .zmx file: UTF-16 (with its byte-order mark, as OpticStudio writes
    it, or LE without one when every other byte is zero), else UTF-8, else Latin-1
    (never fails: every byte is a Latin-1 character)."""
    if raw[:2] in (b"\xff\xfe", b"\xfe\xff"):
        try:
            return raw.decode("utf-16")
        except UnicodeDecodeError:
            pass
    elif len(raw) >= 4 and raw[1:4:2] == b"\0\0" and raw[0] and raw[2]:
        try:
            return raw.decode("utf-16-le")
        except UnicodeDecodeError:
            pass
    if raw[:3] == b"\xef\xbb\xbf":
        raw = raw[3:]
    try:
        return raw.decode("utf-8")
    except UnicodeDecodeError:
        return raw.decode("latin-1")


def read_zmx(path: str | Path, *, lens_id: str | None = None) -> ImportResult:
    """Read a .zmx file and convert it (see the module docstring); ImportProblems lists
    everything that stops the import."""
    p = Path(path)
    label = str(path)
    problem = regular_file_problem(p)
    if problem:
        raise ImportProblems([f"{label}: cannot read: {problem}"])
    try:
        raw = p.read_bytes()
    except OSError as e:
        raise ImportProblems([f"{label}: cannot read: {e.strerror or e}"]) from None
    return parse_zmx(decode(raw), label=label, lens_id=lens_id or p.stem)


def _number(tokens: list[str], i: int, lineno: int, problems: list[str], label: str,
            *, allow_inf: bool = False, what: str | None = None) -> float | None:
    """tokens[i] as a finite float, or None after listing the problem."""
    kw = what or tokens[0]
    if i >= len(tokens):
        problems.append(f"{label}:{lineno}: {kw}: missing value {i}")
        return None
    t = tokens[i]
    if allow_inf and t.upper() == "INFINITY":
        return math.inf
    try:
        v = float(t)
    except ValueError:
        problems.append(f"{label}:{lineno}: {kw}: expected a number, found {t!r:.40}")
        return None
    if not math.isfinite(v):
        problems.append(f"{label}:{lineno}: {kw}: expected a finite number, found {t!r:.40}")
        return None
    return v


def _integer(tokens: list[str], i: int, lineno: int, problems: list[str], label: str
             ) -> int | None:
    v = _number(tokens, i, lineno, problems, label)
    if v is None:
        return None
    if v != int(v) or abs(v) > 1e6:
        problems.append(f"{label}:{lineno}: {tokens[0]}: expected an integer, found "
                        f"{tokens[i]!r:.40}")
        return None
    return int(v)


def parse_zmx(text: str, *, label: str = "<zmx>", lens_id: str = "import") -> ImportResult:
    """Convert the text of a .zmx file to lensfit's TOML layout (validated by the loader).
    Raises ImportProblems listing every problem, one per line."""
    problems: list[str] = []
    notes = Notes(label)
    surfs: list[_Surf] = []
    top: dict[str, tuple[list[str], int]] = {}
    note_lines: list[str] = []
    xfld: tuple[list[float], int] | None = None
    yfld: tuple[list[float], int] | None = None
    current: _Surf | None = None

    for lineno, line in enumerate(text.splitlines(), start=1):
        tokens = line.split()
        if not tokens:
            continue
        kw = tokens[0]
        indented = line[:1] in (" ", "\t")
        if kw == "SURF":
            n = _integer(tokens, 1, lineno, problems, label)
            if n is not None and n != len(surfs):
                problems.append(f"{label}:{lineno}: SURF {n}: expected SURF {len(surfs)} "
                                "(surfaces are numbered in order from 0)")
            # Read on as the next surface, so that one bad line makes one problem
            current = _Surf(len(surfs), lineno)
            surfs.append(current)
            continue
        if current is not None and (indented or kw in SURFACE_KEYWORDS):
            _surface_line(current, kw, tokens, lineno, problems, notes, label)
            continue
        current = None
        # Top level
        if kw in IGNORED_TOP:
            continue
        if kw in NOTED_TOP:
            notes.add(str(lineno), kw, NOTED_TOP[kw])
            continue
        if kw == "MODE":
            if tokens[1:2] != ["SEQ"]:
                problems.append(f"{label}:{lineno}: MODE {' '.join(tokens[1:2])}: "
                                "non-sequential data: unsupported (only MODE SEQ is imported)")
            continue
        if kw in ("NSOB", "NSCT", "NSOA", "NSOD", "NSOO", "NSOP", "NSOQ", "NSOS", "NSOU",
                  "NSOV", "NSOW"):
            problems.append(f"{label}:{lineno}: {kw}: non-sequential object: unsupported "
                            "(not imported)")
            continue
        if kw == "NOTE":
            text_ = " ".join(tokens[2:] if len(tokens) > 2 and tokens[1].isdigit()
                             else tokens[1:])
            if text_:
                note_lines.append(text_)
            continue
        if kw in ("XFLN", "XFLD", "YFLN", "YFLD"):
            vals = [_number(tokens, i, lineno, problems, label) for i in range(1, len(tokens))]
            if any(v is None for v in vals):
                continue
            if kw[0] == "X":
                xfld = ([float(v) for v in vals if v is not None], lineno)
            else:
                yfld = ([float(v) for v in vals if v is not None], lineno)
            continue
        if kw in top:
            problems.append(f"{label}:{lineno}: {kw}: given twice (first on line "
                            f"{top[kw][1]})")
            continue
        if kw in ("NAME", "UNIT", "GCAT", "FTYP", "FNUM", "FLOA", "ENPD"):
            top[kw] = (tokens, lineno)
            continue
        notes.add(str(lineno), kw, "unknown keyword not mapped")

    scale = _unit(top, problems, label)
    makers = top["GCAT"][0][1:] if "GCAT" in top else []
    info_notes: list[str] = []
    surfaces, where = _surfaces(surfs, makers, problems, notes, label, info_notes)
    apertures = [_aperture_kind(s, problems, label) for s in surfs[1:-1]]
    if not surfs:
        problems.append(f"{label}: no SURF lines: not a sequential .zmx lens file")
    if problems:
        raise ImportProblems(_by_line(problems, label))

    name = " ".join(top["NAME"][0][1:]) if "NAME" in top else ""
    all_notes = [*note_lines, f"Imported by lensfit import from {Path(label).name}",
                 *info_notes]
    info = lens_table(lens_id=lens_id, name=name, source=f"Zemax file {Path(label).name}",
                      notes=all_notes)
    if scale is not None:
        info["scale"] = scale
    if "FNUM" in top:
        tokens, lineno = top["FNUM"]
        f = _number(tokens, 1, lineno, problems, label)
        if f is not None and f > 0:
            info["f_number"] = f
    fov = _field_of_view(top, xfld, yfld, notes, problems, label)
    if fov is not None:
        info["field_of_view_deg"] = fov
    if problems:
        raise ImportProblems(_by_line(problems, label))
    _estimate_semi_diameters(surfaces, where, surfs[0], top, fov, problems, notes, label)
    if problems:
        raise ImportProblems(_by_line(problems, label))
    data = {
        "schema_version": 1,
        "lens": info,
        "coating": {"default": "none", "design_wavelength_nm": 550.0},
        "surface": surfaces,
    }
    lens = validate(data, label, where)
    _design_aperture(data, lens, top, notes, label)
    # Automatic semi-diameters widened for the design beam and the domain lensfit fits by
    # default (with the [fit] aperture just found)
    _, sd_lines = size_housings(data, apertures, where, [f"{label}:{w}" for w in where],
                                label=label, half_field_deg=(fov or 0.0) / 2.0,
                                unit=UNIT_NAMES.get(scale, "mm"), lens=lens)
    return ImportResult(data, notes.lines(), sd_lines)


def _design_aperture(data: dict[str, Any], lens: Any, top: dict[str, tuple[list[str], int]],
                     notes: Notes, label: str) -> None:
    """The design's aperture as the aperture ``lensfit fit`` fits by default: ``ENPD D``
    (entrance pupil diameter, object at infinity) gives f/N = EFL / D at the d line,
    ``FNUM N`` f/N itself (``lens``: the validated lens of ``data``); written as ``[fit]
    f_number`` with the reason. FLOA (the stop
    size is the aperture) is lensfit's own model and needs nothing. An aperture wider
    than the stop's semi-diameter allows is a note (the fit then takes its default)."""
    from lensfit.paraxial import stop_radius_for_f_number
    from lensfit.paraxial import table as paraxial_table
    kw = next((k for k in ("ENPD", "FNUM") if k in top), None)
    if kw is None or "FLOA" in top:
        return
    tokens, lineno = top[kw]
    try:
        value = float(tokens[1])
    except (IndexError, ValueError):
        value = math.nan
    if not (math.isfinite(value) and value > 0):
        notes.add(str(lineno), kw, "aperture not mapped (not a positive number)")
        return
    efl = paraxial_table(lens)["efl_mm"]  # None: no finite focal length (afocal)
    if efl is None or not math.isfinite(efl) or efl == 0.0:
        notes.add(str(lineno), kw, "aperture not mapped (the lens has no finite focal "
                                   "length: an f-number means nothing)")
        return
    efl = float(efl)  # a Python float (the TOML writer takes no numpy scalar)
    f_number = abs(efl) / value if kw == "ENPD" else value
    try:
        stop_radius_for_f_number(lens, f_number)
    except ValueError as e:
        notes.add(str(lineno), kw, f"aperture f/{f_number:.4g} not mapped ({e})")
        return
    given = f"ENPD {value:g} mm, EFL {efl:.6g} mm at the d line" if kw == "ENPD" else \
        f"FNUM {value:g}"
    data["fit"] = {"f_number": f_number,
                   "reason": f"the design's aperture in {Path(label).name} line {lineno} "
                             f"({given})"}


def _estimate_semi_diameters(surfaces: list[dict[str, Any]], where: list[str], obj: _Surf,
                             top: dict[str, tuple[list[str], int]], fov: float | None,
                             problems: list[str], notes: Notes, label: str) -> None:
    """Surfaces without a DIAM (or with DIAM 0, not computed) get the paraxial estimate
    |y_marginal| + |y_chief| from the aperture setting (FLOA: the stop's DIAM; ENPD;
    FNUM) and the largest angle field, each with a note."""
    missing = [k for k, d in enumerate(surfaces) if "semi_diameter" not in d]
    if not missing:
        return
    ap_type, ap_value = None, None
    stop = next((d for d in surfaces if d.get("stop")), {})
    for kw, kind in (("FLOA", "float_by_stop_size"), ("ENPD", "EPD"), ("FNUM", "imageFNO")):
        if kw not in top:
            continue
        if kw == "FLOA":
            value = 2.0 * stop["semi_diameter"] if "semi_diameter" in stop else None
        else:
            tokens, lineno = top[kw]
            value = _number(tokens, 1, lineno, problems, label)
        ap_type, ap_value = kind, value
        break
    obj_d = _value(obj, "DISZ", [], label, default=math.inf, allow_inf=True)

    def bad(w: str, msg: str) -> None:
        problems.append(f"{label}:{w}: {msg}" if w else f"{label}: {msg}")

    def note(w: str, sd: float) -> None:
        notes.add(w.split(":")[0], w.split(": ", 1)[1] + " DIAM",
                  f"no semi-diameter in the file: {sd:g} from the paraxial marginal and "
                  "chief rays")

    paraxial_semi_diameters(surfaces, missing, where, ap_type, ap_value,
                            object_distance=math.inf if obj_d is None else obj_d,
                            half_field_deg=(fov or 0.0) / 2.0, bad=bad, note=note)


def _by_line(problems: list[str], label: str) -> list[str]:
    """Problems in the order of their line numbers (file-wide ones first)."""
    def key(p: str) -> int:
        rest = p[len(label) + 1:]
        num = rest.split(":", 1)[0]
        return int(num) if num.isdigit() else 0
    return sorted(problems, key=key)


def _is_zero(token: str) -> bool:
    try:
        return float(token) == 0.0
    except ValueError:
        return token == '""'


def _surface_line(s: _Surf, kw: str, tokens: list[str], lineno: int, problems: list[str],
                  notes: Notes, label: str) -> None:
    """File one line of a SURF block."""
    where = f"{lineno}: SURF {s.number}"
    if kw in IGNORED_SURFACE:
        return
    if kw in NOTED_SURFACE:
        notes.add(str(lineno), kw, NOTED_SURFACE[kw])
        return
    if kw in ERROR_SURFACE:
        problems.append(f"{label}:{where} {kw}: {ERROR_SURFACE[kw]} (not imported)")
        return
    if kw in ("PARM", "XDAT"):
        i = _integer(tokens, 1, lineno, problems, label)
        v = _number(tokens, 2, lineno, problems, label)
        if i is None or v is None:
            return
        table = s.parm if kw == "PARM" else s.xdat
        if i in table:
            problems.append(f"{label}:{where} {kw} {i}: given twice (first on line "
                            f"{table[i][1]})")
            return
        table[i] = (v, lineno)
        return
    if kw not in SURFACE_KEYWORDS:
        if len(tokens) > 1 and all(_is_zero(t) for t in tokens[1:]):
            # A setting whose values are all zero is off (a flag or an unused option)
            notes.add(str(lineno), f"SURF {s.number} {kw}", "unknown surface keyword with "
                      "zero values not mapped")
            return
        problems.append(f"{label}:{where} {kw}: unknown surface keyword: it may change the "
                        "optics (not imported)")
        return
    if kw in s.values:
        problems.append(f"{label}:{where} {kw}: given twice (first on line "
                        f"{s.values[kw][1]})")
        return
    s.values[kw] = (tokens, lineno)


def _unit(top: dict[str, tuple[list[str], int]], problems: list[str], label: str
          ) -> float | None:
    if "UNIT" not in top:
        return None
    tokens, lineno = top["UNIT"]
    unit = tokens[1].upper() if len(tokens) > 1 else ""
    if unit not in UNITS:
        problems.append(f"{label}:{lineno}: UNIT {unit or '(none)'}: unsupported lens unit "
                        f"(known: {', '.join(UNITS)})")
        return None
    return UNITS[unit]


def _surfaces(surfs: list[_Surf], makers: list[str], problems: list[str], notes: Notes,
              label: str, info_notes: list[str]) -> tuple[list[dict[str, Any]], list[str]]:
    """The lens surfaces (SURF 1 .. the one before the image) in the TOML layout, and for
    each the place it came from ("41: SURF 5")."""
    out: list[dict[str, Any]] = []
    where: list[str] = []
    if not surfs:
        return out, where
    if len(surfs) < 3:
        problems.append(f"{label}:{surfs[-1].line}: SURF {surfs[-1].number}: a lens needs an "
                        "object surface, at least one surface and an image surface (truncated "
                        "file?)")
        return out, where
    for end in (surfs[0], surfs[-1]):  # OpticStudio writes DISZ on every surface
        if "DISZ" not in end.values:
            problems.append(f"{label}:{end.line}: SURF {end.number}: no DISZ line (a truncated "
                            "file?)")
    _object_surface(surfs[0], problems, notes, label)
    _image_surface(surfs[-1], problems, notes, label)
    stops = [s for s in surfs if "STOP" in s.values]
    if not stops:
        problems.append(f"{label}: no STOP line: the aperture stop is not marked")
    for s in stops[1:]:
        problems.append(f"{label}:{s.values['STOP'][1]}: SURF {s.number} STOP: a second stop "
                        f"(the first is SURF {stops[0].number})")
    for s in surfs[1:-1]:
        d = _surface(s, makers, problems, notes, label, last=s is surfs[-2])
        if d is not None:
            out.append(d)
            where.append(s.where())
    return out, where


def _value(s: _Surf, kw: str, problems: list[str], label: str, *, default: float | None = None,
           allow_inf: bool = False) -> float | None:
    if kw not in s.values:
        return default
    tokens, lineno = s.values[kw]
    return _number(tokens, 1, lineno, problems, label, allow_inf=allow_inf,
                   what=f"SURF {s.number} {kw}")


def _object_surface(s: _Surf, problems: list[str], notes: Notes, label: str) -> None:
    curv = _value(s, "CURV", problems, label, default=0.0)
    disz = _value(s, "DISZ", problems, label, default=math.inf, allow_inf=True)
    if curv:
        notes.add(str(s.values["CURV"][1]), "SURF 0 CURV", "object surface curvature not "
                  "mapped (the scene is set at fit time)")
    if disz is not None and math.isfinite(disz):
        notes.add(str(s.values["DISZ"][1]), "SURF 0 DISZ", f"object distance {disz:g} not "
                  "mapped (lensfit's scene and focus are set at fit time)")
    if "GLAS" in s.values:
        name = s.values["GLAS"][0][1] if len(s.values["GLAS"][0]) > 1 else ""
        problems.append(f"{label}:{s.values['GLAS'][1]}: SURF 0 GLAS {name}: object space in "
                        "glass: unsupported (lensfit's object space is air)")
    if "STOP" in s.values:
        problems.append(f"{label}:{s.values['STOP'][1]}: SURF 0 STOP: the stop on the object "
                        "surface: unsupported")
    _check_type(s, problems, label, allowed=("STANDARD",))
    for kw in ("DIAM", "CONI", "CLAP", "FLAP", "OBDC"):
        tokens = s.values.get(kw, ([], 0))[0]
        if kw in s.values and any(t not in ("0", "0.0", '""') for t in tokens[1:]):
            notes.add(str(s.values[kw][1]), f"SURF 0 {kw}", "object surface setting not mapped")
    for _, lineno in sorted(s.parm.values()):
        notes.add(str(lineno), "SURF 0 PARM", "object surface setting not mapped")


def _image_surface(s: _Surf, problems: list[str], notes: Notes, label: str) -> None:
    n = s.number
    curv = _value(s, "CURV", problems, label, default=0.0)
    if curv:
        problems.append(f"{label}:{s.values['CURV'][1]}: SURF {n} CURV: a curved image "
                        "surface: unsupported (lensfit's sensor is a plane)")
    coni = _value(s, "CONI", problems, label, default=0.0)
    if coni and curv:
        problems.append(f"{label}:{s.values['CONI'][1]}: SURF {n} CONI: a curved image "
                        "surface: unsupported")
    _check_type(s, problems, label, allowed=("STANDARD", "EVENASPH", "TOROIDAL"))
    if "STOP" in s.values:
        problems.append(f"{label}:{s.values['STOP'][1]}: SURF {n} STOP: the stop on the image "
                        "surface: unsupported")
    for kw, reason in (("DIAM", "image semi-diameter not mapped (lensfit fits a sensor disc: "
                                "lensfit fit --image-circle)"),
                       ("GLAS", "image surface glass not mapped (nothing follows)"),
                       ("CLAP", "image aperture not mapped"),
                       ("FLAP", "image aperture not mapped")):
        if kw in s.values:
            notes.add(str(s.values[kw][1]), f"SURF {n} {kw}", reason)
    disz = _value(s, "DISZ", problems, label, default=0.0, allow_inf=True)
    if disz:
        notes.add(str(s.values["DISZ"][1]), f"SURF {n} DISZ", "image surface thickness not "
                  "mapped (nothing follows)")
    for v, lineno in sorted([*s.parm.values(), *s.xdat.values()]):
        if v:
            problems.append(f"{label}:{lineno}: SURF {n}: a shaped image surface: unsupported")


def _check_type(s: _Surf, problems: list[str], label: str, allowed: tuple[str, ...]) -> str:
    if "TYPE" not in s.values:
        return "STANDARD"
    tokens, lineno = s.values["TYPE"]
    typ = tokens[1] if len(tokens) > 1 else ""
    if typ not in allowed:
        why = ("non-sequential component" if typ == "NONSEQCO"
               else "unsupported surface type")
        problems.append(f"{label}:{lineno}: SURF {s.number} TYPE {typ or '(none)'}: {why} "
                        f"(not imported; supported: {', '.join(allowed)})")
        return ""
    return typ


def _surface(s: _Surf, makers: list[str], problems: list[str], notes: Notes, label: str,
             *, last: bool) -> dict[str, Any] | None:
    """One lens surface in the TOML layout, or None after listing its problems."""
    before = len(problems)
    n = s.number
    typ = _check_type(s, problems, label, SUPPORTED_TYPES)
    if not typ:
        return None  # an unsupported type: its other lines are not checked
    curv = _value(s, "CURV", problems, label, default=0.0)
    coni = _value(s, "CONI", problems, label, default=0.0)
    disz = _value(s, "DISZ", problems, label, allow_inf=False)
    if "DISZ" not in s.values:
        problems.append(f"{label}:{s.line}: SURF {n}: no DISZ (thickness) line")
    d: dict[str, Any] = {}

    # Shape
    if typ and curv is not None and coni is not None:
        shape = _shape(s, typ, curv, coni, problems, label, notes)
        if shape is not None:
            d.update(shape)
    if disz is not None:
        d["thickness"] = disz

    # Medium behind the surface
    if "GLAS" in s.values:
        d.update(_glass(s, makers, problems, notes, label))
    else:
        d["material"] = "air"

    # Semi-diameter: a circular hard aperture if there is one, else DIAM
    sd = _semi_diameter(s, problems, notes, label)
    if sd is not None:
        d["semi_diameter"] = sd
    if "STOP" in s.values:
        d["stop"] = True
    if len(problems) > before or not d.get("shape"):
        return None
    # Keys in the order lensdb files use
    order = ["shape", "radius", "thickness", "material", "nd", "vd", "dpgf", "glass_label",
             "semi_diameter", "conic", "aspheric", "stop"]
    return {k: d[k] for k in order if k in d}


def _shape(s: _Surf, typ: str, curv: float, coni: float, problems: list[str], label: str,
           notes: Notes) -> dict[str, Any] | None:
    n = s.number
    parm = {i: v for i, (v, _) in s.parm.items()}

    def bad(i: int, why: str) -> None:
        problems.append(f"{label}:{s.parm[i][1]}: SURF {n} {typ} PARM {i}: {why}")

    radius = radius_for(curv) if curv else None
    if typ != "TOROIDAL":
        for i, (v, lineno) in sorted(s.xdat.items()):
            if v:
                problems.append(f"{label}:{lineno}: SURF {n} {typ} XDAT {i}: extra data on "
                                f"a {typ} surface: not mapped (not imported)")
    if typ == "STANDARD":
        for i, (v, _) in sorted(s.parm.items()):
            if v:
                bad(i, "a parameter on a STANDARD surface: not mapped (not imported)")
        if coni:
            if radius is None:
                # A plane with a conic is still a plane: the conic multiplies c = 0
                return {"shape": "plane"}
            return {"shape": "asphere", "radius": radius, "conic": coni, "aspheric": []}
        return {"shape": "sphere", "radius": radius} if radius else {"shape": "plane"}
    if typ == "EVENASPH":
        for i in sorted(parm):
            if not 1 <= i <= 8:
                if parm[i]:
                    bad(i, "not an even-asphere coefficient (PARM 1..8)")
        if parm.get(1, 0.0):
            bad(1, f"an r^2 coefficient {parm[1]:g}: lensfit's asphere has none (its terms "
                   "start at r^4); not representable")
        terms = [parm.get(i, 0.0) for i in range(2, 9)]
        while terms and terms[-1] == 0.0:
            terms.pop()
        if radius is None and (coni or any(terms)):
            if not any(terms):
                return {"shape": "plane"}
            problems.append(f"{label}:{s.line}: SURF {n} EVENASPH: a flat asphere (CURV 0 "
                            "with aspheric terms): lensfit's asphere needs a radius; not "
                            "representable")
            return None
        if radius is None:
            return {"shape": "plane"}
        return {"shape": "asphere", "radius": radius, "conic": coni, "aspheric": terms}
    # TOROIDAL
    for i in sorted(parm):
        if i >= 2 and parm[i]:
            bad(i, "a polynomial term on the toroid's y curve: not representable (lensfit's "
                   "cylinders are circular)")
    zernike_terms = s.xdat.get(1, (0.0, 0))[0]
    for i, (v, lineno) in sorted(s.xdat.items()):
        if i == 1 and v:
            problems.append(f"{label}:{lineno}: SURF {n} TOROIDAL XDAT 1: {v:g} Zernike terms: "
                            "not representable")
        elif i >= 3 and v and not zernike_terms:
            notes.add(str(lineno), f"SURF {n} TOROIDAL XDAT {i}", "Zernike coefficient not "
                      "mapped (unused: XDAT 1 sets 0 terms)")
    rot = parm.get(1, 0.0)
    if coni and radius is not None:
        problems.append(f"{label}:{s.values['CONI'][1]}: SURF {n} TOROIDAL CONI: a conic "
                        "y curve: not representable (lensfit's cylinders are circular)")
        return None
    if radius is not None and rot == 0.0:
        return {"shape": "cylinder-x", "radius": radius}
    if radius is None and rot != 0.0:
        return {"shape": "cylinder-y", "radius": rot}
    if radius is None:
        return {"shape": "plane"}
    if rot == radius:
        return {"shape": "sphere", "radius": radius}
    problems.append(f"{label}:{s.values['CURV'][1]}: SURF {n} TOROIDAL: a toroid with radius "
                    f"{radius:g} in y and {rot:g} in x: not representable (lensfit has "
                    "spheres and cylinders)")
    return None


def _glass(s: _Surf, makers: list[str], problems: list[str], notes: Notes, label: str
           ) -> dict[str, Any]:
    tokens, lineno = s.values["GLAS"]
    n = s.number
    if len(tokens) < 2:
        problems.append(f"{label}:{lineno}: SURF {n} GLAS: missing glass name")
        return {}
    name = tokens[1]
    if name.upper() == "MIRROR":
        problems.append(f"{label}:{lineno}: SURF {n} GLAS MIRROR: a mirror: unsupported "
                        "(lensfit traces refracting lenses)")
        return {}
    if name in MODEL_GLASS_NAMES:
        return _model_glass(s, tokens, lineno, problems, notes, label)
    try:
        spec, outside = resolve_glass(name, makers)
    except UnknownGlassError as e:
        cats = f" (GCAT {' '.join(makers)})" if makers else ""
        problems.append(f"{label}:{lineno}: SURF {n} GLAS {name}{cats}: {glass_message(e)} "
                        "(not imported)")
        return {}
    if outside:
        notes.add(str(lineno), f"SURF {n} GLAS", outside)
    return spec


def _model_glass(s: _Surf, tokens: list[str], lineno: int, problems: list[str], notes: Notes,
                 label: str) -> dict[str, Any]:
    """``GLAS ___BLANK 1 0 nd vd dPgF ...`` (a MODEL glass; ``GLAS MODEL ...`` from
    Optiland's writer, the same columns): nd/vd(/dpgf) with lensfit's Abbe model, or
    with vd 0 (how OpticStudio writes a medium without dispersion) the constant index
    ``material = { n = nd }``; a note either way."""
    n = s.number
    nd = _number(tokens, 4, lineno, problems, label, what=f"SURF {n} GLAS MODEL nd")
    vd = _number(tokens, 5, lineno, problems, label, what=f"SURF {n} GLAS MODEL vd")
    dpgf = (_number(tokens, 6, lineno, problems, label, what=f"SURF {n} GLAS MODEL dPgF")
            if len(tokens) > 6 else 0.0)
    if nd is None or vd is None or dpgf is None:
        return {}
    head = f"{label}:{lineno}: SURF {n} GLAS MODEL nd {nd:g} vd {vd:g}"
    vd_lo, vd_hi = MODEL_VD_RANGE
    before = len(problems)
    nd_problem = index_range_problem(nd)
    if nd_problem:
        problems.append(f"{head}: {nd_problem} (not imported)")
    if vd != 0.0 and not vd_lo <= vd <= vd_hi:
        problems.append(f"{head}: expected {vd_lo:g} <= vd <= {vd_hi:g}, or vd 0 for a medium "
                        "without dispersion (not imported)")
    if abs(dpgf) > MODEL_DPGF_MAX:
        problems.append(f"{head} dPgF {dpgf:g}: expected |dPgF| <= {MODEL_DPGF_MAX:g}, the "
                        "deviation of P_g,F from the normal line (not imported)")
    if len(problems) > before:
        return {}
    where, what = str(lineno), f"SURF {n} GLAS MODEL"
    if vd == 0.0:
        if dpgf:
            notes.add(where, what, f"dPgF {dpgf:g} of a medium without dispersion (vd 0) "
                      "not mapped (it has no partial dispersion)")
        if nd == 1.0:
            notes.add(where, what, "nd 1 vd 0: air")
            return {"material": "air"}
        notes.add(where, what, f"nd {nd:g} vd 0: a medium without dispersion, n = {nd:g} at "
                  f"every wavelength (material = {{ n = {nd:g} }})")
        return {"material": {"n": nd}}
    extra = f" + dPgF {dpgf:g}" if dpgf else ""
    if tokens[1] != MODEL_GLASS:
        extra += " (GLAS MODEL: Optiland's .zmx writer's name for OpticStudio's ___BLANK)"
    if tokens[1] != MODEL_GLASS and vd == OPTILAND_NO_DISPERSION_VD:
        extra += (f"; vd {vd:g} is what Optiland writes for a medium without dispersion "
                  "(nF = nC): kept as written, as Optiland reads it back")
    notes.add(where, what, f"nd {nd:g} vd {vd:g}: lensfit's Abbe model (lensdb/glass/"
              f"README.md), P_g,F on the normal line{extra}")
    return {"nd": nd, "vd": vd, "dpgf": dpgf} if dpgf else {"nd": nd, "vd": vd}


def _semi_diameter(s: _Surf, problems: list[str], notes: Notes, label: str) -> float | None:
    n = s.number
    hard = None
    for kw in ("CLAP", "FLAP"):
        if kw in s.values:
            tokens, lineno = s.values[kw]
            rmin = _number(tokens, 1, lineno, problems, label)
            rmax = _number(tokens, 2, lineno, problems, label)
            if rmin is None or rmax is None:
                continue
            if rmin != 0.0:
                problems.append(f"{label}:{lineno}: SURF {n} {kw}: an annular aperture (inner "
                                f"radius {rmin:g}): unsupported")
                continue
            if hard is not None and rmax != hard:
                problems.append(f"{label}:{lineno}: SURF {n} {kw}: a second aperture of radius "
                                f"{rmax:g} (the first is {hard:g})")
                continue
            hard = rmax
    if "OBDC" in s.values:
        tokens, lineno = s.values["OBDC"]
        dx = _number(tokens, 1, lineno, problems, label)
        dy = _number(tokens, 2, lineno, problems, label)
        if dx or dy:
            problems.append(f"{label}:{lineno}: SURF {n} OBDC: a decentered aperture: "
                            "unsupported (lensfit's apertures are centred)")
    diam = _value(s, "DIAM", problems, label)
    if hard is not None:
        if diam is not None and diam != hard:
            notes.add(str(s.values["DIAM"][1]), f"SURF {n} DIAM",
                      f"semi-diameter {diam:g} replaced by the hard aperture {hard:g}")
        return hard
    if diam is None or diam == 0.0:
        return None  # none in the file (or not computed): estimated later, with a note
    if diam < 0:
        problems.append(f"{label}:{s.values['DIAM'][1]}: SURF {n} DIAM {diam:g}: expected a "
                        "positive semi-diameter")
        return None
    return diam


def _aperture_kind(s: _Surf, problems: list[str], label: str) -> FileAperture:
    """What the file says the surface's semi-diameter is (lensfit.interchange.housings):
    the stop's is its aperture; CLAP/FLAP and a fixed DIAM (solve type 1, or none given)
    are apertures; DIAM with another solve type is automatic; no DIAM (or DIAM 0: not
    computed) is estimated. A solve type that is not an integer is a problem."""
    what = "no DIAM"
    solve: int | None = None
    if "DIAM" in s.values:
        tokens, lineno = s.values["DIAM"]
        if len(tokens) > 2:
            try:
                v = float(tokens[2])
            except ValueError:
                v = math.nan
            if not (math.isfinite(v) and v == int(v) and 0 <= v <= 1e6):
                problems.append(f"{label}:{lineno}: SURF {s.number} DIAM: expected an integer "
                                f"semi-diameter solve type, found {tokens[2]!r:.40}")
                return FileAperture("fixed", "DIAM")
            solve = int(v)
        try:
            zero = float(tokens[1]) == 0.0 if len(tokens) > 1 else True
        except ValueError:
            zero = False  # _semi_diameter reports it
        if zero:
            what = "DIAM 0: not computed"
        elif solve is None:
            what = "DIAM without a solve type: fixed"
        else:
            what = f"DIAM solve {solve}: {DIAM_SOLVES.get(solve, 'computed')}"
    hard = [kw for kw in ("CLAP", "FLAP") if kw in s.values]
    if "STOP" in s.values:
        return FileAperture("stop", hard[0] if hard else what)
    if hard:
        return FileAperture("fixed", f"{hard[0]}: a circular aperture")
    if what in ("no DIAM", "DIAM 0: not computed"):
        return FileAperture("estimated", what)
    return FileAperture("fixed" if solve in (None, 1) else "automatic", what)


def _field_of_view(top: dict[str, tuple[list[str], int]], xfld, yfld, notes: Notes,
                   problems: list[str], label: str) -> float | None:
    """Twice the largest field angle (FTYP 0: angles in degrees), or None with a note."""
    if yfld is None and xfld is None:
        return None
    ftype, count = 0, None
    if "FTYP" in top:
        tokens, lineno = top["FTYP"]
        ftype = _integer(tokens, 1, lineno, problems, label)
        if len(tokens) > 3:
            count = _integer(tokens, 3, lineno, problems, label)
        if ftype is None:
            return None
    line = (yfld or xfld)[1]  # type: ignore[index]
    if ftype != 0:
        kinds = {1: "object heights", 2: "paraxial image heights", 3: "real image heights",
                 4: "theodolite angles"}
        notes.add(str(line), "fields", f"{kinds.get(ftype, f'type {ftype}')} not mapped "
                  "(lensfit's [lens] holds a field of view in degrees)")
        return None
    xs = xfld[0] if xfld else []
    ys = yfld[0] if yfld else []
    m = max(len(xs), len(ys))
    if count is not None and count >= 0:
        m = min(m, count)
    xs = (xs + [0.0] * m)[:m]
    ys = (ys + [0.0] * m)[:m]
    if not m:
        return None
    if any(abs(v) >= 90.0 for v in xs + ys):
        problems.append(f"{label}:{line}: fields: an angle of 90 degrees or more")
        return None
    worst = max(math.degrees(math.atan(math.hypot(math.tan(math.radians(x)),
                                                  math.tan(math.radians(y)))))
                for x, y in zip(xs, ys, strict=True))
    return 2.0 * worst if worst > 0 else None


# --- export --------------------------------------------------------------------------------

def _near(x: float, ulps: int = 4) -> list[float]:
    """x, then the floats 1, 2, ... ``ulps`` steps below and above it, nearest first."""
    out = [x]
    lo = hi = x
    for _ in range(ulps):
        lo, hi = math.nextafter(lo, -math.inf), math.nextafter(hi, math.inf)
        out += [lo, hi]
    return out


def curvature_for(radius: float) -> float:
    """A curvature c whose reciprocal is exactly ``radius`` in float64 when one exists
    next to 1/radius (so that CURV -> 1/CURV gives the table's radius back bit for bit);
    else 1/radius."""
    c = 1.0 / radius
    for cand in _near(c):
        if cand != 0.0 and 1.0 / cand == radius:
            return cand
    return c


def radius_for(curv: float) -> float:
    """The radius of a CURV value: 1/c, or among the floats within 4 ulp of it whose
    curvature (``curvature_for``) is c, the one with the shortest decimal form. All of
    them are 1/c to float64 rounding; the choice brings a typed radius (58.04, whose
    reciprocal has no exact float inverse) back bit for bit from an exported file."""
    r = 1.0 / curv
    same = [x for x in _near(r) if curvature_for(x) == curv]
    if not same:
        return r
    return min(same, key=lambda x: (len(repr(x)), abs(x - r)))


def _num(v: float) -> str:
    return repr(float(v))


def write_zmx(lens: Any) -> tuple[str, list[str]]:
    """The .zmx text (ASCII, sequential, lens units mm) of a loaded ``Lens``, and the
    notes on what the format does not hold (coatings, glass labels, provenance, a field
    of view of 180 degrees or more). The
    values are the loaded lens's own floats (scale applied), written with repr, so that
    importing the file gives the same lens. A semi-diameter is written as an aperture
    (fixed DIAM, solve 1, and CLAP) unless it is automatic (``aperture = "automatic"``):
    then as OpticStudio's automatic one (DIAM solve 0, no aperture) at its widened
    value, which importing keeps (it passes the same design beam)."""
    from lensfit.glass import catalog_glass

    notes: list[str] = []
    makers: list[str] = []
    coated: list[int] = []
    automatic: list[int] = []
    info = lens.provenance
    lines = ["MODE SEQ", f"NAME {lens.name}", "UNIT MM X W X CM MR CPMM", "FLOA"]
    if lens.raw and "fit" in lens.raw:
        notes.append("[fit] (the domain lensfit fits by default) not exported: the file's "
                     "aperture is FLOA, the stop's semi-diameter")
    if "f_number" in info:
        lines.append(f"FNUM {_num(info['f_number'])} 0")
    if "field_of_view_deg" in info:
        half = float(info["field_of_view_deg"]) / 2.0
        if half < 90.0:
            lines += ["FTYP 0 0 2 1 0 0 0", "XFLN 0 0", f"YFLN 0 {_num(half)}"]
        else:  # a fisheye's (0014 states 181 degrees): no angle field reaches 90 degrees
            notes.append(f"field of view {_num(2.0 * half)} degrees not exported (a .zmx "
                         "angle field is under 90 degrees from the axis)")
    # Design programs need wavelengths (Optiland refuses a file without a primary one):
    # the d, F and C lines in micrometres, d primary (lensfit's own range is the fit's)
    lines += [f"WAVM {k} {um} 1" for k, um in enumerate(EXPORT_WAVELENGTHS_UM, start=1)]
    lines.append("PWAV 1")
    body = ["SURF 0", "  TYPE STANDARD", "  CURV 0.0", "  DISZ INFINITY"]
    for i, (_, s, stop, thickness) in enumerate(file_surfaces(lens)):
        body.append(f"SURF {i + 1}")
        if stop:
            body.append("  STOP")
        if s.shape in ("sphere", "plane"):
            c = _num(curvature_for(s.radius_mm)) if s.shape == "sphere" else "0.0"
            body += ["  TYPE STANDARD", f"  CURV {c}"]
        elif s.shape == "asphere":
            if len(s.aspheric) > 7:
                raise ValueError(f"surface {i}: {len(s.aspheric)} aspheric terms; EVENASPH "
                                 "holds A4..A16 (7)")
            body += ["  TYPE EVENASPH", f"  CURV {_num(curvature_for(s.radius_mm))}",
                     f"  CONI {_num(s.conic)}", "  PARM 1 0"]
            terms = list(s.aspheric) + [0.0] * (7 - len(s.aspheric))
            body += [f"  PARM {j + 2} {_num(a)}" for j, a in enumerate(terms)]
        elif s.shape == "cylinder-x":
            body += ["  TYPE TOROIDAL", f"  CURV {_num(curvature_for(s.radius_mm))}",
                     "  PARM 1 0"]
        else:  # cylinder-y
            body += ["  TYPE TOROIDAL", "  CURV 0.0", f"  PARM 1 {_num(s.radius_mm)}"]
        body.append(f"  DISZ {_num(thickness)}")
        spec = s.material_spec
        inline = spec.get("material")
        if "nd" in spec:
            dpgf = _num(spec["dpgf"]) if spec.get("dpgf") else "0"
            body.append(f"  GLAS {MODEL_GLASS} 1 0 {_num(spec['nd'])} {_num(spec['vd'])} "
                        f"{dpgf} 0 0 0 0 0")
            if "glass_label" in spec:
                notes.append(f"surface {i}: glass label {spec['glass_label']!r} not exported "
                             "(a MODEL glass has no name)")
        elif isinstance(inline, dict) and set(inline) <= {"name", "n"} and "n" in inline:
            # A constant index: a MODEL glass with vd 0, OpticStudio's non-dispersive medium
            body.append(f"  GLAS {MODEL_GLASS} 1 0 {_num(inline['n'])} 0 0 0 0 0 0 0")
            if "name" in inline:
                notes.append(f"surface {i}: glass name {inline['name']!r} not exported "
                             "(a MODEL glass has no name)")
        elif isinstance(inline, dict):
            raise ValueError(f"surface {i}: an inline dispersion formula or table has no .zmx "
                             "form (a catalog name or a MODEL glass)")
        elif str(spec.get("material", "air")).lower() != "air":
            ref = str(spec["material"])
            maker, _, name = ref.rpartition(":")
            if not maker:
                try:
                    maker = str(catalog_glass(ref).maker)
                except UnknownGlassError:
                    maker = str(getattr(s.medium, "maker", ""))
            if maker and maker.upper() not in makers:
                makers.append(maker.upper())
            nd = getattr(s.medium, "nd", 1.5)
            vd = getattr(s.medium, "vd", 40.0)
            body.append(f"  GLAS {name} 0 0 {_num(nd)} {_num(vd)} 0 0 0 0 0 0")
        sd = _num(s.semi_diameter_mm)
        if s.aperture == "automatic" and not stop:
            # A housing sized to the beam: OpticStudio's automatic semi-diameter (solve
            # 0), no aperture; importing it keeps the value (it passes the same beam)
            body.append(f"  DIAM {sd} 0 0 0 1 \"\"")
            automatic.append(i)
        else:  # an aperture: fixed ("U", solve 1) and a circular aperture
            body += [f"  DIAM {sd} 1 0 0 1 \"\"", f"  CLAP 0 {sd} 0"]
        if not s.coating.bare:
            coated.append(i)
    body += [f"SURF {len(file_surfaces(lens)) + 1}", "  TYPE STANDARD", "  CURV 0.0",
             "  DISZ 0"]
    if coated:
        notes.append(f"coatings of surfaces {', '.join(map(str, coated))} not exported (a .zmx "
                     "names coatings from OpticStudio's coating file)")
    if automatic:
        notes.append(f"automatic semi-diameters of surfaces {', '.join(map(str, automatic))} "
                     "exported as OpticStudio's automatic ones (DIAM solve 0, no aperture) at "
                     "the widened housing; the design file's values (design_semi_diameter) "
                     "not exported")
    if makers:
        lines.insert(3, "GCAT " + " ".join(makers))
    return "\n".join(lines + body) + "\n", notes
