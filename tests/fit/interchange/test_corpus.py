"""lensfit import of a corpus of public lens files written by other programs
(tests/fit/fixtures/corpus/: .zmx and Optiland JSON files from open projects, their
sources and licences in the README.md of each folder). Issue 36, deliverable 6.

Each file is imported through the command line in-process (``lensfit import FILE -o
OUT``), and its outcome is compared with the table ``CASES`` below:

* ``Imports``: exit 0, the TOML written, and three facts of the lens it loads to: the
  number of surfaces of the file (object and image left out; a stop plane the loader
  inserts for a stop on a curved surface is not counted), the stop's index among them,
  and the paraxial EFL at the d line from lensfit's paraxial module. The EFL is compared
  with the one Optiland 0.6.3 computes from the same file (``optic.paraxial.f2()`` with
  the single wavelength 587.5618 nm; for a .zmx file read by its own Zemax reader), an
  independent program reading the file its own way; the counts are the file's
  (Optiland's ``num_surfaces - 2`` and ``stop_index - 1``).
* ``Refused``: exit 2, nothing written, every problem on one line that names the file,
  the place (a .zmx line number with its ``SURF n``, or an Optiland JSON path) and the
  reason; each pattern of ``lines`` must match one of those lines (test_outcome), and no
  other line may appear (test_no_other_refusal): a surface type or glass lensfit has must
  never be refused.

A file refused today only for a gap being closed may be listed in ``XFAIL`` with the
reason, for test_outcome and test_no_other_refusal: a strict xfail, which fails the suite
the day the file passes, and then the entry comes off. None is listed now: the gaps of
issue 36 that the corpus found (model glasses written ``GLAS MODEL`` by Optiland's .zmx
writer, non-dispersive media, Optiland's image surface of type ``Surface``, a catalog
glass whose maker is given apart from its name or only in its data file's path,
OpticStudio's MAZH solve and VCON flag) are closed, and each file states what the
importer does.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path

import pytest

from lensfit.cli import main
from lensfit.paraxial import table
from lensfit.prescription import load_lens

CORPUS = Path(__file__).resolve().parents[1] / "fixtures" / "corpus"
FOLDERS = ("zmx", "optiland")
MAX_FILE_BYTES = 200_000
MAX_CORPUS_BYTES = 2_000_000


@dataclass(frozen=True)
class Imports:
    surfaces: int  # surfaces of the file, object and image left out
    stop: int  # the stop's index among them
    efl_mm: float  # Optiland 0.6.3's paraxial f2 at 587.5618 nm
    rel: float = 1e-9  # the same glass data in both programs: rounding only


@dataclass(frozen=True)
class Refused:
    lines: tuple[str, ...]  # each must match one problem line (re.search)
    optional: tuple[str, ...] = field(default=())  # may match one, need not


_GLASS = r"unknown glass '{}'"
_MIRROR = r"a mirror: unsupported"
# lensfit's nd range, and why an index above it is refused (germanium, n 4.002)
_INFRARED = (r"expected 1 <= n(d)? <= 3; an index above 3 belongs to an infrared medium "
             r"\(germanium about 4\.0, silicon about 3\.4\), opaque to the visible light "
             r"\(380-780 nm\) lensfit traces")

# file -> expected outcome
CASES: dict[str, Imports | Refused] = {
    # --- .zmx, KBG0603/Optical-design (MIT) ---------------------------------------------
    "zmx/ColorCorrected.zmx": Imports(5, 1, 49.99999999999999),
    "zmx/DoubleGauss.zmx": Imports(12, 6, 49.99997959387362),
    "zmx/LandScape_Lens_F5.zmx": Imports(4, 1, 49.99999999999999),
    # N-LASF55 is in OpticStudio's SCHOTT catalog, not in the SCHOTT spreadsheet lensfit has
    "zmx/CookeTriplet.zmx": Refused((r":101: SURF 2 GLAS N-LASF55 .*"
                                     + _GLASS.format("N-LASF55"),)),
    # CaF2 is a crystal of OpticStudio's MISC catalog, which lensfit does not have
    "zmx/MicroscopeObjective_tolerence_ready.zmx": Refused((
        r":106: SURF 2 GLAS CAF2 .*" + _GLASS.format("CAF2"),
        r":190: SURF 8 GLAS CAF2 .*" + _GLASS.format("CAF2"),
    )),
    # VCON (no values, lines 106 and 124: the optimiser's flag on the conic, as VDSZ is
    # on the thickness) is ignored; the mirrors, the annulus and N-FK56 are refused
    "zmx/RC_Lens.zmx": Refused((
        r":102: SURF 2 GLAS MIRROR: " + _MIRROR,
        r":119: SURF 3 GLAS MIRROR: " + _MIRROR,
        r":108: SURF 2 CLAP: an annular aperture \(inner radius 21\): unsupported",
        r":136: SURF 4 GLAS N-FK56 .*" + _GLASS.format("N-FK56"),
    )),
    # --- .zmx, optiland/optiland tests/zemax_files (MIT) --------------------------------
    "zmx/lens1.zmx": Imports(7, 4, 24.990670494950276),
    # UNIT IN: Optiland's EFL is in inches, lensfit's in mm
    "zmx/circular_aperture_example_with_aperture.zmx": Imports(22, 10,
                                                               0.7300961053482348 * 25.4),
    # FLOA with a stop of 8.5 behind a biconvex lens of radius 20: the beam estimated at
    # surface 1 (no DIAM there) is wider than the sphere itself
    "zmx/lens_floa.zmx": Refused((
        r":13: SURF 1\b.*semi-diameter .* is larger than \|radius\| 20(\.0)? mm",)),
    "zmx/one_mirror_up_45deg.zmx": Refused((
        r":106: SURF 3 TYPE COORDBRK: unsupported surface type",
        r":134: SURF 4 GLAS MIRROR: " + _MIRROR,
        r":140: SURF 5 TYPE COORDBRK: unsupported surface type",
    )),
    "zmx/flat_transmission_grating.zmx": Refused((
        r":102: SURF 3 TYPE DGRATING: unsupported surface type",)),
    # --- .zmx, mjhoptics/ray-optics (BSD-3; lens-designs.com, MIT) ----------------------
    # MAZH 0 0.7 on the last lens surface (line 193) is OpticStudio's "Marginal Ray
    # Height" thickness solve (height 0 at pupil zone 0.7), whose solved value DISZ
    # holds: a note. Optiland 0.6.3 reads the same glasses (SCHOTT N-BAK1, N-BALF4)
    "zmx/US00583336-2-scaled.zmx": Imports(12, 6, 49.38897584676335),
    # its MAZH (line 186) is a note likewise; L-TIM28_MOLD is OHARA's L-TIM28 as
    # moulded, in no catalog lensfit has
    "zmx/US08427765-1.ZMX": Refused((
        r":93: SURF 3 GLAS L-TIM28_MOLD .*" + _GLASS.format("L-TIM28_MOLD"),
    )),
    # Model glasses (___BLANK) and their pickups are read; the flat corrector plates and
    # the mirrors are not representable
    "zmx/HoO-V2C18Ex27.zmx": Refused((
        r":70: SURF 1 EVENASPH: a flat asphere .*needs a radius",
        r":105: SURF 3 EVENASPH: a flat asphere .*needs a radius",
        r":134: SURF 4 GLAS MIRROR: " + _MIRROR,
        r":148: SURF 5 GLAS MIRROR: " + _MIRROR,
    )),
    # --- .zmx, singer-yang/DeepLens (Apache-2.0) -----------------------------------------
    # FLOA, and the stop has no DIAM: the file gives no aperture at all
    "zmx/ef35mm_f2.0.zmx": Refused((r"no semi-diameter on 59: SURF 6\b",)),
    # --- .zmx written by Optiland 0.6.3 --------------------------------------------------
    # Germanium (n 4.002) and ZnSe (n 2.4028) written GLAS MODEL n 99.99 (Optiland's vd of
    # a medium without dispersion): read as model glasses, the ZnSe is accepted, and
    # germanium is refused on its GLAS lines: out of lensfit's nd range, and why
    "zmx/optiland063_InfraredTriplet.zmx": Refused((
        r":33: SURF 1 GLAS MODEL nd 4\.002 vd 99\.99: " + _INFRARED,
        r":63: SURF 5 GLAS MODEL nd 4\.002 vd 99\.99: " + _INFRARED,
    )),
    # --- Optiland JSON, optiland/optiland docs/samples (MIT) -----------------------------
    # The makers are only in the filename (.../glass/hikari/SK16.yml, reference null).
    # Optiland reads its own HIKARI SK16 data (refractiveindex.info); lensfit has HIKARI's
    # spreadsheet (J-SK16): the indices differ by ~1e-6, the EFL by ~5e-6
    "optiland/Cooke_triplet.json": Imports(6, 3, 50.021596510291374, rel=1e-4),
    # E-LLF6 of Optiland's hikari folder has J-LLF6's index (1.53172 at d); the EFLs
    # differ by ~3e-5
    "optiland/heliar.json": Imports(9, 5, 10.00652933541452, rel=1e-4),
    # N-SK10 and FK3 (in the schott folder) are in neither SCHOTT's current catalog nor
    # any other lensfit has; SK15 and BASF2 of the hikari folder are HIKARI's J-SK15 and
    # J-BASF2 (notes)
    "optiland/reverse_telephoto.json": Refused((
        r": surface_group\.surfaces\[1\]\.material_post\.name: glass 'N-SK10' \(schott\): "
        + _GLASS.format("N-SK10"),
        r": surface_group\.surfaces\[7\]\.material_post\.name: glass 'FK3' \(schott\): "
        + _GLASS.format("FK3"),
    )),
    # --- Optiland JSON written by Optiland 0.6.3 (the image a plain "Surface") ------------
    "optiland/optiland063_CookeTriplet.json": Imports(6, 3, 50.021596510291374, rel=1e-4),
    "optiland/optiland063_CementedAchromat.json": Imports(3, 0, 20.0059952749227),
    "optiland/optiland063_DoubleGauss.json": Imports(11, 5, 100.00372050801042),
    "optiland/optiland063_AsphericSinglet.json": Refused((
        r": surface_group\.surfaces\[1\]\.geometry\.coefficients\[0\]: an r\^2 coefficient",
    )),
    # As the .zmx above (IdealMaterial here): ZnSe is accepted, germanium is refused
    "optiland/optiland063_InfraredTriplet.json": Refused((
        r": surface_group\.surfaces\[1\]\.material_post\.index: a constant index 4\.002: "
        + _INFRARED,
        r": surface_group\.surfaces\[5\]\.material_post\.index: a constant index 4\.002: "
        + _INFRARED,
    )),
    "optiland/optiland063_HubbleTelescope.json": Refused((
        r": surface_group\.surfaces\[4\]\.geometry: a curved image surface: unsupported",
        r": surface_group\.surfaces\[2\]\.interaction_model\.is_reflective: " + _MIRROR,
        r": surface_group\.surfaces\[3\]\.interaction_model\.is_reflective: " + _MIRROR,
        r": surface_group\.surfaces\[2\]\.aperture\.r_min: an annular aperture",
        # the obscuration's outer radius, inf in Optiland: a second line on that aperture
        r": surface_group\.surfaces\[2\]\.aperture\.r_max: expected a finite number",
    )),
}

# file -> (xfail reason of test_outcome, of test_no_other_refusal): gaps still open
XFAIL: dict[str, tuple[str | None, str | None]] = {}


def corpus_files() -> list[str]:
    return sorted(f"{folder}/{p.name}" for folder in FOLDERS
                  for p in (CORPUS / folder).iterdir() if p.name != "README.md")


def _params(which: int, kinds: tuple[type, ...]) -> list:
    out = []
    for name, expect in CASES.items():
        if not isinstance(expect, kinds):
            continue
        reason = XFAIL.get(name, (None, None))[which]
        marks = [pytest.mark.xfail(strict=True, reason=reason)] if reason else []
        out.append(pytest.param(name, expect, id=name, marks=marks))
    return out


# A problem line names the file and then a place: a .zmx line number with its surface
# ("FILE:12: SURF 3 ..." or, for several surfaces, "... on 59: SURF 6, ..."), or an
# Optiland JSON path ("FILE: surface_group.surfaces[2].aperture: ...")
ZMX_PLACE = re.compile(r"(?:^:|\s)\d+: SURF \d+\b")
JSON_PLACE = re.compile(r"^: (?:surface_group\.surfaces\[\d+\]|[a-z_]+)[.\[:]")


def run_import(name: str, tmp_path: Path, capsys) -> tuple[int, str, list[str], Path]:
    """``lensfit import`` of a corpus file into an empty folder: the exit status, stdout,
    the problem lines (the summary line left out) and the output path."""
    src = CORPUS / name
    out_dir = tmp_path / "out"
    out_dir.mkdir()
    out = out_dir / "lens.toml"
    rc = main(["import", str(src), "-o", str(out)])
    cap = capsys.readouterr()
    errors = [line.removeprefix("lensfit: error: ")
              for line in cap.err.splitlines() if line.startswith("lensfit: error: ")]
    if rc == 2:
        summary = errors.pop() if errors else ""
        assert re.fullmatch(rf"{len(errors)} problem\(s\); nothing written", summary), \
            cap.err
    return rc, cap.out, errors, out


def test_the_table_covers_the_corpus():
    assert corpus_files() == sorted(CASES)
    assert set(XFAIL) <= set(CASES)


@pytest.mark.parametrize("folder", FOLDERS)
def test_each_file_small_with_its_source_named(folder):
    readme = (CORPUS / folder / "README.md").read_text(encoding="utf-8")
    licences = {p.name for p in (CORPUS / "licenses").iterdir()}
    for name in corpus_files():
        if name.startswith(folder + "/"):
            file = name.split("/", 1)[1]
            assert (CORPUS / name).stat().st_size < MAX_FILE_BYTES, name
            assert f"`{file}`" in readme, f"{name} is not in {folder}/README.md"
    for named in re.findall(r"`([\w.-]+\.txt)`", readme):
        assert named in licences, f"{folder}/README.md names a missing licence {named}"
    total = sum(p.stat().st_size for p in CORPUS.rglob("*") if p.is_file())
    assert total < MAX_CORPUS_BYTES


@pytest.mark.parametrize(("name", "expect"), _params(0, (Imports, Refused)))
def test_outcome(name, expect, tmp_path, capsys):
    rc, out, errors, toml = run_import(name, tmp_path, capsys)
    label = str(CORPUS / name)
    if isinstance(expect, Imports):
        assert rc == 0, "\n".join(errors)
        assert f"wrote {toml}" in out
        lens = load_lens(toml)
        in_file = [s for s in lens.surfaces if not s.inserted]
        assert len(in_file) == expect.surfaces
        assert lens.stop_file_index == expect.stop
        assert table(lens)["efl_mm"] == pytest.approx(expect.efl_mm, rel=expect.rel)
        return
    assert rc == 2
    assert not any((tmp_path / "out").iterdir()), "a refused import wrote something"
    assert "wrote" not in out
    assert errors, "refused without a problem line"
    place = ZMX_PLACE if name.startswith("zmx/") else JSON_PLACE
    for line in errors:
        assert line.startswith(label), f"the line does not name the file: {line}"
        rest = line[len(label):]
        assert place.search(rest), f"the line names no line number or JSON path: {line}"
        assert "\n" not in line
    for pattern in expect.lines:
        assert any(re.search(pattern, line[len(label):]) for line in errors), \
            f"no line matches {pattern!r}:\n" + "\n".join(errors)


@pytest.mark.parametrize(("name", "expect"), _params(1, (Refused,)))
def test_no_other_refusal(name, expect, tmp_path, capsys):
    """A refused file is refused for what the table says and nothing else: not for a
    surface type, glass or keyword that lensfit has."""
    rc, _, errors, _ = run_import(name, tmp_path, capsys)
    assert rc == 2
    label = str(CORPUS / name)
    patterns = expect.lines + expect.optional
    stray = [line for line in errors
             if not any(re.search(p, line[len(label):]) for p in patterns)]
    assert not stray, "refused for more than the table says:\n" + "\n".join(stray)
