"""Loading and validating TOML prescriptions (lensfit.prescription.load).

Bad input must raise a LensError whose message names the file, the surface index and
the key; good input must load, round-trip, scale and get the documented coatings.
"""

from __future__ import annotations

import math
import tomllib
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from lensfit.common.errors import LensError
from lensfit.glass import AIR, catalog_glass
from lensfit.paraxial import paraxial
from lensfit.prescription import BARE, lens_from_dict, load_lens
from lensfit.prescription.model import Lens

LensWriter = Callable[..., Path]  # the fixtures of conftest.py

# A cemented doublet with an aspheric front, custom coating stacks and an nd/vd glass:
# surface 0 stop (air|air), 1 asphere (air|N-BK7), 2 cemented (N-BK7|nd-vd glass),
# 3 rear (glass|air). Edge sags at 10 mm: front 1.01 mm (conic term 0.84, A4 +0.20,
# A6 -0.03), cemented -1.27 mm, rear -0.33 mm: every gap stays above 2.9 mm.
DOUBLET_TOML = """\
schema_version = 1

[lens]
id = "9001"
name = "test doublet"
maker = "test"
year = 2024
source = "unit test"

[coating]
default = "mgf2"
design_wavelength_nm = 550.0

[[surface]]  # 0
shape = "plane"
thickness = 2.0
material = "air"
semi_diameter = 8.0
stop = true

[[surface]]  # 1
shape = "asphere"
radius = 60.0
conic = -0.5
aspheric = [2e-5, -3e-8]
thickness = 6.0
material = "N-BK7"
semi_diameter = 10.0

[[surface]]  # 2
shape = "sphere"
radius = -40.0
thickness = 2.0
nd = 1.6751
vd = 32.3
glass_label = "SF5"
semi_diameter = 10.0

[[surface]]  # 3
shape = "sphere"
radius = -150.0
thickness = 45.0
material = "air"
semi_diameter = 10.0
"""


def _error(path: Path) -> LensError:
    with pytest.raises(LensError) as info:
        load_lens(path)
    return info.value


def assert_names(err: LensError, path: Path, surface: int | None, key: str | None) -> None:
    """The error carries file, surface and key, and its message starts with them."""
    msg = str(err)
    assert err.file == str(path), msg
    assert msg.startswith(f"{path}: "), msg
    assert err.surface == surface, msg
    if surface is not None:
        assert f"{path}: surface {surface}: " in msg, msg
    assert err.key == key, msg
    if key is not None:
        assert f"key '{key}': " in msg, msg


def _line_of(text: str, fragment: str) -> int:
    return text[: text.index(fragment)].count("\n") + 1


# (case id, text to replace in the singlet, replacement, surface, key, message fragments)
BAD_CASES: list[tuple[str, str, str, int | None, str, tuple[str, ...]]] = [
    ("missing-thickness", "thickness = 5.0\n", "", 1, "thickness", ("missing",)),
    ("missing-lens-name", 'name = "test singlet"\n', "", None, "lens.name", ("missing",)),
    ("wrong-type", "radius = 50.0", 'radius = "abc"', 1, "radius", ("expected number", "'abc'")),
    ("unknown-key", "radius = 50.0", "radius = 50.0\nradiuss = 3.0", 1, "radiuss", ("unknown",)),
    (
        "unknown-lens-key",
        'maker = "test"',
        'maker = "test"\nfocal_length = 50.0',
        None,
        "lens.focal_length",
        ("unknown", "focal_length_mm"),  # the allowed keys are listed
    ),
    (
        "unknown-shape",
        'shape = "sphere"\nradius = 50.0',
        'shape = "toroid"\nradius = 50.0',
        1,
        "shape",
        ("'toroid'", "sphere"),
    ),
    # 1 mm centre thickness against edge sags of 1.01 + 0.91 mm: the surfaces cross
    ("crossing", "thickness = 5.0", "thickness = 1.0", 1, "thickness", ("cross",)),
    ("negative-gap", "thickness = 2.0", "thickness = -2.0", 0, "thickness", ("negative",)),
    ("unknown-glass", 'material = "N-BK7"', 'material = "N-BK77"', 1, "material", ("N-BK77",)),
    ("nan-radius", "radius = 50.0", "radius = nan", 1, "radius", ("finite", "nan")),
    ("inf-thickness", "thickness = 47.0", "thickness = inf", 2, "thickness", ("finite", "inf")),
    ("neg-inf-sd", "semi_diameter = 9.5", "semi_diameter = -inf", 2, "semi_diameter", ("-inf",)),
    (
        "nan-in-lens",
        'maker = "test"',
        'maker = "test"\nfocal_length_mm = nan',
        None,
        "lens.focal_length_mm",
        ("finite", "nan"),
    ),
    ("inf-scale", 'maker = "test"', 'maker = "test"\nscale = inf', None, "lens.scale", ("inf",)),
    ("no-stop", "stop = true\n", "", None, "stop", ("no aperture stop",)),
    (
        "two-stops",
        "semi_diameter = 9.5",
        "semi_diameter = 9.5\nstop = true",
        2,
        "stop",
        ("more than one",),
    ),
    ("nd-without-vd", 'material = "N-BK7"', "nd = 1.5168", 1, "vd", ("missing",)),
    (
        "nd-and-material",
        'material = "N-BK7"',
        'material = "N-BK7"\nnd = 1.5168\nvd = 64.17',
        1,
        "nd",
        ("material",),
    ),
    (
        "sd-beyond-radius",
        "semi_diameter = 10.0",
        "semi_diameter = 60.0",
        1,
        "semi_diameter",
        ("60", "radius"),
    ),
    (
        "last-surface-in-glass",
        'thickness = 47.0\nmaterial = "air"',
        'thickness = 47.0\nmaterial = "N-BK7"',
        2,
        "material",
        ("air",),
    ),
    ("no-sensor-distance", "thickness = 47.0", "thickness = 0.0", 2, "thickness", ("positive",)),
    ("zero-radius", "radius = 50.0", "radius = 0.0", 1, "radius", ("plane",)),
    ("radius-on-plane", 'shape = "plane"', 'shape = "plane"\nradius = 100.0', 0, "radius", ()),
    ("conic-on-sphere", "radius = 50.0", "radius = 50.0\nconic = -1.0", 1, "conic", ("asphere",)),
    (
        "coating-both-thicknesses",
        "semi_diameter = 9.5",
        'semi_diameter = 9.5\ncoating = { layers = [ { material = "MgF2", '
        "thickness_nm = 100.0, quarter_wave_nm = 550.0 } ] }",
        2,
        "coating.layers.0",
        ("thickness_nm", "quarter_wave_nm"),
    ),
    (
        "coating-unknown-material",
        "semi_diameter = 9.5",
        'semi_diameter = 9.5\ncoating = { layers = [ { material = "Unobtainium", '
        "thickness_nm = 100.0 } ] }",
        2,
        "coating.layers.0.material",
        ("Unobtainium",),
    ),
    (
        "coating-misspelt-key",
        "semi_diameter = 9.5",
        'semi_diameter = 9.5\ncoating = { layers = [ { material = "MgF2", thick_nm = 100.0 } ] }',
        2,
        "coating.layers.0.thick_nm",
        ("unknown", "thickness_nm"),
    ),
    # What a semi-diameter is (lensdb/README.md, `aperture`): the stop's is its aperture,
    # a design value belongs to an automatic one, an unknown kind is refused
    ("automatic-stop", "stop = true", 'stop = true\naperture = "automatic"', 0, "aperture",
     ("stop", "automatic")),
    ("design-sd-of-a-fixed-one", "semi_diameter = 9.5",
     "semi_diameter = 9.5\ndesign_semi_diameter = 9.0", 2, "design_semi_diameter",
     ("automatic",)),
    ("design-sd-negative", "semi_diameter = 9.5",
     'semi_diameter = 9.5\naperture = "automatic"\ndesign_semi_diameter = -1.0', 2,
     "design_semi_diameter", ("positive",)),
    ("aperture-unknown", "semi_diameter = 9.5", 'semi_diameter = 9.5\naperture = "floating"',
     2, "aperture", ("'floating'", "'automatic'")),
    (
        "coating-unknown-name",
        "semi_diameter = 9.5",
        'semi_diameter = 9.5\ncoating = "mgf3"',
        2,
        "coating",
        ("'mgf3'", "'mgf2'"),
    ),
]


@pytest.mark.parametrize(
    ("old", "new", "surface", "key", "fragments"),
    [pytest.param(*case[1:], id=case[0]) for case in BAD_CASES],
)
def test_bad_input_names_file_surface_and_key(
    singlet_variant: LensWriter,
    old: str,
    new: str,
    surface: int | None,
    key: str,
    fragments: tuple[str, ...],
) -> None:
    path = singlet_variant(old, new)
    err = _error(path)
    assert_names(err, path, surface, key)
    for fragment in fragments:
        assert fragment in str(err)


def test_malformed_toml_reports_the_line(singlet_variant: LensWriter, singlet_toml: str) -> None:
    path = singlet_variant("radius = 50.0", "radius = = 50.0")
    err = _error(path)
    assert_names(err, path, None, None)
    assert "malformed TOML" in str(err)
    assert f"line {_line_of(singlet_toml, 'radius = 50.0')}" in str(err)


def test_unknown_glass_is_never_air(singlet_variant: LensWriter) -> None:
    # A misspelt glass as the last medium would pass every other check if it fell
    # back to air; it must still be reported as an unknown glass.
    path = singlet_variant(
        'thickness = 47.0\nmaterial = "air"', 'thickness = 47.0\nmaterial = "ari"'
    )
    err = _error(path)
    assert_names(err, path, 2, "material")
    assert "unknown glass 'ari'" in str(err)


def test_asphere_semi_diameter_beyond_the_conic(singlet_variant: LensWriter) -> None:
    # The conic sag needs (1 + k) c² h² <= 1: with k = 3 and R = 50 mm the surface ends
    # at h = 25 mm. 24 mm must load, 30 mm must be refused.
    front = (
        'shape = "sphere"\nradius = 50.0\nthickness = 5.0\nmaterial = "N-BK7"\nsemi_diameter = 10.0'
    )

    def asphere(sd: float) -> str:
        return (
            f'shape = "asphere"\nradius = 50.0\nconic = 3.0\nthickness = 5.0\n'
            f'material = "N-BK7"\nsemi_diameter = {sd}'
        )

    load_lens(singlet_variant(front, asphere(24.0), name="inside"))
    path = singlet_variant(front, asphere(30.0), name="outside")
    err = _error(path)
    assert_names(err, path, 1, "semi_diameter")
    assert "30" in str(err)


def test_unknown_lens_name() -> None:
    with pytest.raises(LensError) as info:
        load_lens("nope")
    msg = str(info.value)
    assert "'nope'" in msg
    assert "0001-angenieux-double-gauss" in msg  # the known lenses are listed


def test_missing_toml_file(tmp_path: Path) -> None:
    path = tmp_path / "absent.toml"
    err = _error(path)
    assert err.file == str(path)
    assert "no such file" in str(err)


# ---------------------------------------------------------------- good input


def test_valid_singlet_loads(write_lens: LensWriter, singlet_toml: str) -> None:
    lens = load_lens(write_lens(singlet_toml))
    assert lens.name == "test singlet"
    assert [s.shape for s in lens.surfaces] == ["plane", "sphere", "sphere"]
    assert lens.stop_index == 0
    assert lens.stop_radius_max_mm == 8.0
    assert lens.surfaces[1].medium == catalog_glass("N-BK7")
    assert lens.surfaces[0].medium is AIR and lens.surfaces[2].medium is AIR
    assert lens.surfaces[1].radius_mm == 50.0 and lens.surfaces[2].radius_mm == -50.0
    assert lens.surfaces[0].curvature == 0.0
    assert lens.sensor_z == 2.0 + 5.0 + 47.0
    assert list(lens.vertex_z) == [0.0, 2.0, 7.0]


@pytest.mark.parametrize("which", ["singlet", "doublet"])
def test_round_trip_through_to_dict(write_lens: LensWriter, singlet_toml: str, which: str) -> None:
    text = singlet_toml if which == "singlet" else DOUBLET_TOML
    lens = load_lens(write_lens(text))
    assert lens.to_dict() == tomllib.loads(text)
    again = lens_from_dict(lens.to_dict())
    assert again.surfaces == lens.surfaces
    assert again.name == lens.name
    assert again.design_wavelength_nm == lens.design_wavelength_nm


def _scaled(text: str, scale: float) -> str:
    assert text.count('source = "unit test"') == 1
    return text.replace('source = "unit test"', f'source = "unit test"\nscale = {scale}')


def test_scale_multiplies_every_length(write_lens: LensWriter) -> None:
    s = 1.7
    base = load_lens(write_lens(DOUBLET_TOML, "base"))
    big = load_lens(write_lens(_scaled(DOUBLET_TOML, s), "big"))
    # A product of two doubles is correctly rounded: 1e-15 relative is a few ulp.
    for a, b in zip(base.surfaces, big.surfaces, strict=True):
        assert b.thickness_mm == pytest.approx(s * a.thickness_mm, rel=1e-15)
        assert b.semi_diameter_mm == pytest.approx(s * a.semi_diameter_mm, rel=1e-15)
        if math.isfinite(a.radius_mm):
            assert b.radius_mm == pytest.approx(s * a.radius_mm, rel=1e-15)
        assert b.conic == a.conic  # the conic constant is dimensionless
    assert big.sensor_z == pytest.approx(s * base.sensor_z, rel=1e-15)
    # Paraxial optics is linear in lengths, so the EFL scales exactly; 1e-12 leaves room
    # for rounding in ~30 matrix products (each a few ulp).
    for m in ("x", "y"):
        assert paraxial(big, meridian=m).efl_mm == pytest.approx(
            s * paraxial(base, meridian=m).efl_mm, rel=1e-12
        )
    assert paraxial(big).entrance_pupil.radius_mm == pytest.approx(
        s * paraxial(base).entrance_pupil.radius_mm, rel=1e-12
    )


def test_scale_keeps_the_asphere_shape(write_lens: LensWriter) -> None:
    # The scaled surface is the same shape enlarged: sag(s r) == s sag(r). The A4 and
    # A6 terms are 20% and 3% of the edge sag, so a wrong power of s in their scaling
    # would miss by tens of percent; 1e-12 relative is float rounding of the sum.
    s = 1.7
    a = load_lens(write_lens(DOUBLET_TOML, "base")).surfaces[1]
    b = load_lens(write_lens(_scaled(DOUBLET_TOML, s), "big")).surfaces[1]
    assert b.aspheric != a.aspheric
    r = np.linspace(0.0, a.semi_diameter_mm, 21)
    np.testing.assert_allclose(b.sag(s * r, 0.0), s * a.sag(r, 0.0), rtol=1e-12, atol=0.0)
    np.testing.assert_allclose(b.sag(0.0, s * r), s * a.sag(0.0, r), rtol=1e-12, atol=0.0)


def test_automatic_semi_diameter_is_kept_and_scaled(write_lens: LensWriter,
                                                     singlet_toml: str) -> None:
    """aperture = "automatic" (a housing sized to the beam, lensfit import) and the design
    file's value load with the surface, scaled like every length, and come back through
    to_dict; the default is "fixed" (an aperture). The tracer clips at semi_diameter
    either way, so neither key is part of the optics (two lenses that differ only in them
    compare equal)."""
    text = singlet_toml.replace(
        "semi_diameter = 9.5",
        'semi_diameter = 9.5\naperture = "automatic"\ndesign_semi_diameter = 9.25').replace(
        'source = "unit test"', 'source = "unit test"\nscale = 2.0')
    lens = load_lens(write_lens(text))
    back = lens.surfaces[2]
    assert (back.aperture, back.semi_diameter_mm, back.design_semi_diameter_mm) == \
        ("automatic", 19.0, 18.5)
    assert [s.aperture for s in lens.surfaces[:2]] == ["fixed", "fixed"]
    assert lens.surfaces[1].design_semi_diameter_mm is None
    assert back.to_dict()["aperture"] == "automatic"
    assert back.to_dict()["design_semi_diameter"] == 18.5
    assert "aperture" not in lens.surfaces[1].to_dict()
    assert lens_from_dict(lens.to_dict()).surfaces[2].aperture == "automatic"
    plain = load_lens(write_lens(singlet_toml.replace(
        'source = "unit test"', 'source = "unit test"\nscale = 2.0'), name="plain"))
    assert plain.surfaces == lens.surfaces


def test_scale_must_be_positive(write_lens: LensWriter, singlet_toml: str) -> None:
    path = write_lens(_scaled(singlet_toml, -1.0))
    err = _error(path)
    assert_names(err, path, None, "lens.scale")


def _quarter_wave_mgf2_nm(wavelength_nm: float) -> float:
    return wavelength_nm / (4.0 * float(catalog_glass("MgF2").n(wavelength_nm)))


def test_default_coating_on_glass_air_surfaces_only(write_lens: LensWriter) -> None:
    lens = load_lens(write_lens(DOUBLET_TOML))
    stop, front, cemented, rear = lens.surfaces
    assert stop.coating == BARE  # air on both sides
    assert cemented.coating == BARE  # glass on both sides
    # front and rear: one quarter-wave MgF2 layer at the 550 nm design wavelength
    t = _quarter_wave_mgf2_nm(550.0)
    # MgF2 has n = 1.378 at 550 nm, so a quarter wave is 99.7 nm: an independent check
    # of the catalog (n between 1.37 and 1.39 gives 98.9 nm to 100.4 nm).
    assert 98.9 < t < 100.4
    for s in (front, rear):
        (layer,) = s.coating.layers
        assert layer.medium == catalog_glass("MgF2")
        assert layer.thickness_nm == pytest.approx(t, rel=1e-12)  # same formula, rounding


def test_default_coating_follows_the_design_wavelength(write_lens: LensWriter) -> None:
    text = DOUBLET_TOML.replace("design_wavelength_nm = 550.0", "design_wavelength_nm = 500.0")
    lens = load_lens(write_lens(text))
    (layer,) = lens.surfaces[1].coating.layers
    assert layer.thickness_nm == pytest.approx(_quarter_wave_mgf2_nm(500.0), rel=1e-12)
    # and not the 550 nm thickness: they differ by 9%
    assert layer.thickness_nm < 0.95 * _quarter_wave_mgf2_nm(550.0)


def test_default_none_leaves_every_surface_bare(write_lens: LensWriter) -> None:
    text = DOUBLET_TOML.replace('default = "mgf2"', 'default = "none"')
    lens = load_lens(write_lens(text))
    assert all(s.coating.bare for s in lens.surfaces)


def test_coating_default_is_mgf2_without_coating_table(
    write_lens: LensWriter, singlet_toml: str
) -> None:
    lens = load_lens(write_lens(singlet_toml))  # the singlet has no [coating] table
    assert lens.surfaces[0].coating.bare
    for s in lens.surfaces[1:]:
        (layer,) = s.coating.layers
        assert layer.thickness_nm == pytest.approx(_quarter_wave_mgf2_nm(550.0), rel=1e-12)


def test_explicit_coatings(write_lens: LensWriter) -> None:
    stack = (
        'coating = { layers = [ { material = "SiO2", thickness_nm = 90.0 }, '
        "{ n = 2.0, quarter_wave_nm = 500.0 } ] }"
    )
    text = DOUBLET_TOML.replace(
        'material = "N-BK7"\nsemi_diameter = 10.0',
        f'material = "N-BK7"\nsemi_diameter = 10.0\n{stack}',
    ).replace(
        'glass_label = "SF5"\nsemi_diameter = 10.0',
        'glass_label = "SF5"\nsemi_diameter = 10.0\ncoating = "mgf2"',
    )
    text = text.replace(
        'material = "air"\nsemi_diameter = 10.0',
        'material = "air"\nsemi_diameter = 10.0\ncoating = "none"',
    )
    assert text.count("coating = ") == 3
    lens = load_lens(write_lens(text))
    front, cemented, rear = lens.surfaces[1:]
    (l1, l2) = front.coating.layers  # listed from the scene side
    assert l1.medium == catalog_glass("SiO2") and l1.thickness_nm == 90.0
    assert float(l2.medium.n(500.0)) == 2.0
    assert l2.thickness_nm == pytest.approx(500.0 / (4 * 2.0), rel=1e-15)
    # an explicit "mgf2" coats even a cemented surface; "none" leaves a glass-air one bare
    (layer,) = cemented.coating.layers
    assert layer.thickness_nm == pytest.approx(_quarter_wave_mgf2_nm(550.0), rel=1e-12)
    assert rear.coating.bare
    # the custom stack survives a round trip (equal media compare equal)
    assert lens_from_dict(lens.to_dict()).surfaces == lens.surfaces


def _cylinder_singlet(write_lens: LensWriter, text: str, shape: str) -> Lens:
    assert text.count('shape = "sphere"') == 2
    return load_lens(write_lens(text.replace('shape = "sphere"', f'shape = "{shape}"'), shape))


def test_cylinder_x_has_power_in_y_only(write_lens: LensWriter, singlet_toml: str) -> None:
    lens = _cylinder_singlet(write_lens, singlet_toml, "cylinder-x")
    assert lens.anamorphic
    front = lens.surfaces[1]
    assert front.curvature_xy == (0.0, 1.0 / 50.0)
    assert lens.surfaces[2].curvature_xy == (0.0, -1.0 / 50.0)
    # straight along x: the sag does not change with x at any height y ...
    x = np.linspace(-10.0, 10.0, 41)
    for y in (0.0, 3.0, 9.0):
        row = front.sag(x, np.full_like(x, y))
        assert np.all(row == row[0])
    assert np.all(front.sag(x, 0.0) == 0.0)
    # ... and a circle of radius 50 mm along y (closed form; 1e-12 is rounding)
    y = np.linspace(0.0, 10.0, 11)
    np.testing.assert_allclose(front.sag(0.0, y), 50.0 - np.sqrt(50.0**2 - y**2), rtol=1e-12)
    # Paraxially: no power in x, and in y the same EFL as the spherical singlet
    assert paraxial(lens, meridian="x").efl_mm == math.inf
    sphere = load_lens(write_lens(singlet_toml, "sphere"))
    assert paraxial(lens, meridian="y").efl_mm == pytest.approx(
        paraxial(sphere).efl_mm, rel=1e-14
    )  # identical matrices in y: only rounding could differ


def test_cylinder_y_is_cylinder_x_turned(write_lens: LensWriter, singlet_toml: str) -> None:
    lens = _cylinder_singlet(write_lens, singlet_toml, "cylinder-y")
    front = lens.surfaces[1]
    assert front.curvature_xy == (1.0 / 50.0, 0.0)
    t = np.linspace(0.0, 10.0, 11)
    cyl_x = _cylinder_singlet(write_lens, singlet_toml, "cylinder-x").surfaces[1]
    np.testing.assert_array_equal(front.sag(t, 0.0), cyl_x.sag(0.0, t))
    assert paraxial(lens, meridian="y").efl_mm == math.inf
