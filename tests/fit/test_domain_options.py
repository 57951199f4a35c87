"""Choosing what a fit covers: default_domain's keywords, a lens file's [fit] table (the
domain it declares, checked by lensdb/schema.json), a scene's own domain (scene_domain),
and the `lensfit fit` / `lensfit report` options that set them.

Nothing here fits a lens: the CLI cases are refused before sampling starts.
"""

from __future__ import annotations

import math
import tomllib
from pathlib import Path

import pytest

from lensfit.cli import main
from lensfit.codegen.scene import (
    SCENE_FIELD_MARGIN,
    SCENE_FOCUS_MARGIN_MM,
    SCENE_IMAGE_MARGIN_MM,
    SCENE_WAVELENGTH_MARGIN_NM,
    Scene,
    SceneError,
    light_direction,
    scene_domain,
)
from lensfit.common.errors import LensError
from lensfit.paraxial import paraxial, stop_radius_for_f_number
from lensfit.paraxial.paraxial import image_distance
from lensfit.prescription import lens_from_dict, load_lens
from lensfit.psf.psf import geometric_image_point
from lensfit.sample.domain import (
    CLOSE_FOCUS_EFL,
    FULL_FRAME_HALF_DIAGONAL_MM,
    IMAGE_MARGIN,
    declared_fit,
    default_domain,
)

REPO = Path(__file__).resolve().parents[2]
LENS_2004 = REPO / "lensdb" / "2004-schneider-anamorphic.toml"


@pytest.fixture(scope="module")
def lens():
    return load_lens("0001")


@pytest.fixture(scope="module")
def anamorphic():
    return load_lens("2004")


def efl(lens, meridian: str = "y") -> float:
    return abs(paraxial(lens, meridian=meridian).efl_mm)


# --- default_domain's keywords ---------------------------------------------------------------


def test_each_keyword_sets_its_part_and_leaves_the_rest(lens):
    base = default_domain(lens)
    f = efl(lens)
    assert base.sensor_radius_mm == pytest.approx(FULL_FRAME_HALF_DIAGONAL_MM, rel=1e-12)
    assert base.close_focus_mm == pytest.approx(CLOSE_FOCUS_EFL * f, rel=1e-12)

    # The field narrows the image circle with it: the real image of its edge (the chief
    # ray, farthest of 450, 550 and 650 nm: psf's own trace here) plus IMAGE_MARGIN
    d = default_domain(lens, field_deg=5.0)
    assert (d.field_deg, d.field_y_deg) == (5.0, None)
    real = max(math.hypot(*geometric_image_point(lens, (-5.0, 0.0), math.inf, lam))
               for lam in (450.0, 550.0, 650.0))
    assert d.sensor_radius_mm == pytest.approx(IMAGE_MARGIN * real, rel=1e-9)
    assert real == pytest.approx(f * math.tan(math.radians(5.0)), rel=0.02)  # paraxial
    assert d.with_(field_deg=base.field_deg, sensor_radius_mm=base.sensor_radius_mm) == base
    # ... but never beyond the frame's
    assert default_domain(lens, field_deg=30.0).sensor_radius_mm == base.sensor_radius_mm

    d = default_domain(lens, image_circle_mm=5.0)
    assert d == base.with_(sensor_radius_mm=5.0)
    d = default_domain(lens, field_deg=5.0, image_circle_mm=12.0)  # outright wins
    assert (d.field_deg, d.sensor_radius_mm) == (5.0, 12.0)

    d = default_domain(lens, wavelengths_nm=(500.0, 600.0))
    assert d == base.with_(wavelength_min_nm=500.0, wavelength_max_nm=600.0)

    d = default_domain(lens, focus_mm=(0.1, 0.3))
    assert d == base.with_(focus_min_mm=0.1, focus_max_mm=0.3)

    # The close focus sets the sensor travel: from infinity focus to its image, with a
    # margin of 1% of the focal length both ways
    margin = 0.01 * f
    d = default_domain(lens, close_focus_mm=2000.0)
    travel = image_distance(lens, 2000.0) - image_distance(lens, math.inf)
    assert 0 < travel < base.focus_max_mm
    assert d.with_(focus_max_mm=base.focus_max_mm) == base.with_(close_focus_mm=2000.0,
                                                                focus_min_mm=-margin)
    assert d.focus_max_mm == pytest.approx(travel + margin, rel=1e-12)
    d = default_domain(lens, close_focus_mm=math.inf)
    assert (d.close_focus_mm, d.inverse_distance_max) == (math.inf, 0.0)
    assert (d.focus_min_mm, d.focus_max_mm) == pytest.approx((-margin, margin), rel=1e-12)
    # focus_mm outright wins over the close focus's travel
    d = default_domain(lens, close_focus_mm=math.inf, focus_mm=(-0.5, 2.0))
    assert (d.focus_min_mm, d.focus_max_mm) == (-0.5, 2.0)

    d = default_domain(lens, 8.0)
    assert d == base.with_(stop_radius_mm=stop_radius_for_f_number(lens, 8.0))


@pytest.mark.parametrize(("kw", "message"), [
    ({"field_deg": 0.0}, "field = 0.0 degrees: expected an angle in (0, 90)"),
    ({"field_deg": 90.0}, "field = 90.0 degrees"),
    ({"field_deg": -5.0}, "field = -5.0 degrees"),
    ({"field_deg": math.nan}, "field = nan degrees"),
    ({"image_circle_mm": 0.0}, "image circle = 0.0 mm: expected a positive radius"),
    ({"image_circle_mm": -1.0}, "image circle = -1.0 mm"),
    ({"image_circle_mm": math.inf}, "image circle = inf mm"),
    ({"close_focus_mm": 0.0}, "close focus = 0.0 mm: expected a positive distance"),
    ({"close_focus_mm": -100.0}, "close focus = -100.0 mm"),
    ({"close_focus_mm": math.nan}, "close focus = nan mm"),
    ({"focus_mm": (0.3, 0.1)}, "domain: focus_min_mm = 0.3 must be below focus_max_mm"),
    ({"wavelengths_nm": (600.0, 500.0)}, "domain: wavelength_min_nm = 600.0 must be"),
    ({"wavelengths_nm": (-1.0, 500.0)}, "domain: wavelength_min_nm = -1.0 must be positive"),
])
def test_bad_keywords_are_refused_naming_the_option(lens, kw, message):
    with pytest.raises(ValueError, match=f"^{_re(message)}"):
        default_domain(lens, **kw)


def _re(text: str) -> str:
    import re

    return re.escape(text)


# --- a lens's declared domain ([fit] in its TOML) --------------------------------------------


def test_a_declared_domain_is_the_default(anamorphic, lens):
    """2004 declares f/4 and a 24 degree half field in x ([fit], with the reason): its
    default domain is that; y's field follows the squeeze (the ratio of the two focal
    lengths, about 13 degrees) and the image circle the wider meridian's image plus 10%
    (15.4 mm). Keywords still win over the declaration. 0001 declares nothing."""
    fit = declared_fit(anamorphic)
    assert (fit["f_number"], fit["field_deg"]) == (4.0, 24.0) and fit["reason"]
    assert declared_fit(lens) == {}
    d = default_domain(anamorphic)
    ex, ey = efl(anamorphic, "x"), efl(anamorphic, "y")
    t = math.tan(math.radians(24.0))
    assert d.stop_radius_mm == pytest.approx(stop_radius_for_f_number(anamorphic, 4.0),
                                             rel=1e-12)
    assert d.field_deg == 24.0
    assert d.field_y_deg == pytest.approx(math.degrees(math.atan(t * ex / ey)), rel=1e-12)
    assert 12.0 < d.field_y_deg < 14.0
    assert d.sensor_radius_mm == pytest.approx(1.1 * ex * t, rel=1e-12)
    assert 15.0 < d.sensor_radius_mm < 16.0 < FULL_FRAME_HALF_DIAGONAL_MM
    mine = default_domain(anamorphic, 8.0, field_deg=10.0)
    assert mine.stop_radius_mm == pytest.approx(stop_radius_for_f_number(anamorphic, 8.0),
                                                rel=1e-12)
    assert mine.field_deg == 10.0


def lens_2004_with_fit(**change) -> dict:
    data = tomllib.loads(LENS_2004.read_text(encoding="utf-8"))
    for key, value in change.items():
        if value is None:
            data["fit"].pop(key)
        else:
            data["fit"][key] = value
    return data


@pytest.mark.parametrize(("change", "message"), [
    ({"reason": None}, "key 'fit.reason': missing required key"),
    ({"reason": ""}, "key 'fit.reason': '' should be non-empty"),
    ({"stop": 4.0}, "key 'fit.stop': unknown key (allowed: f_number, field_deg, reason)"),
    ({"field_deg": 95.0}, "key 'fit.field_deg': 95.0 is greater than or equal to the "
                          "maximum of 90"),
    ({"field_deg": 0.0}, "key 'fit.field_deg': 0.0 is less than or equal to the minimum"),
    ({"f_number": 0}, "key 'fit.f_number': 0 is less than or equal to the minimum of 0"),
    ({"f_number": "f/4"}, "key 'fit.f_number': expected number, found 'f/4'"),
])
def test_the_fit_table_is_checked_by_the_schema(change, message):
    assert lens_from_dict(lens_2004_with_fit(), file="2004.toml")  # as committed: fine
    with pytest.raises(LensError, match=f"^2004.toml: {_re(message)}"):
        lens_from_dict(lens_2004_with_fit(**change), file="2004.toml")


def test_a_fit_table_may_give_only_its_reason():
    lens = lens_from_dict(lens_2004_with_fit(f_number=None, field_deg=None), file="x.toml")
    assert set(declared_fit(lens)) == {"reason"}
    d = default_domain(lens)
    assert d.field_deg != 24.0  # the default field of the 36 x 24 mm frame


# --- a scene's domain ------------------------------------------------------------------------

SCENE = {
    "name": "two-lights",
    "wavelengths_nm": [450.0, 650.0, 550.0],
    "focus_offset_mm": 0.25,
    "f_number": 8.0,
    "light": [
        {"field_x_deg": 6.0, "field_y_deg": 4.0, "distance_mm": "inf"},
        {"field_x_deg": -3.0, "field_y_deg": 0.0, "distance_mm": 2000.0},
    ],
}


def test_scene_domain_covers_the_scene_with_its_margins(lens):
    """The disc of directions that holds the lights (5% more in direction cosine), their
    images plus 0.3 mm, the nearest light (2% nearer), the wavelengths plus 1 nm, the
    scene's stop and its focus plus 0.02 mm either side."""
    scene = Scene.from_dict(SCENE)
    assert scene.f_number == 8.0
    d = scene_domain(lens, scene)
    r = max(math.hypot(*light_direction(lt.field_x_deg, lt.field_y_deg))
            for lt in scene.lights)
    assert d.field_deg == pytest.approx(math.degrees(math.asin(SCENE_FIELD_MARGIN * r)),
                                        rel=1e-12)
    assert d.field_y_deg is None
    assert d.stop_radius_mm == pytest.approx(stop_radius_for_f_number(lens, 8.0), rel=1e-12)
    assert d.close_focus_mm == pytest.approx(0.98 * 2000.0, rel=1e-12)
    assert (d.wavelength_min_nm, d.wavelength_max_nm) == (
        450.0 - SCENE_WAVELENGTH_MARGIN_NM, 650.0 + SCENE_WAVELENGTH_MARGIN_NM)
    assert (d.focus_min_mm, d.focus_max_mm) == pytest.approx(
        (0.25 - SCENE_FOCUS_MARGIN_MM, 0.25 + SCENE_FOCUS_MARGIN_MM), rel=1e-12)
    images = [geometric_image_point(lens, (lt.field_x_deg, lt.field_y_deg), lt.distance_mm,
                                    550.0, 0.25) for lt in scene.lights]
    assert d.sensor_radius_mm == pytest.approx(
        max(math.hypot(*p) for p in images) + SCENE_IMAGE_MARGIN_MM, rel=1e-12)
    # Far narrower than the lens's default domain, and every light inside it
    base = default_domain(lens)
    assert d.field_deg < base.field_deg and d.sensor_radius_mm < base.sensor_radius_mm
    sx = math.sin(math.radians(d.field_deg))
    for lt in scene.lights:
        x, y = light_direction(lt.field_x_deg, lt.field_y_deg)
        assert math.hypot(x, y) < sx
        u = lt.inputs()["u_O"]
        assert 0.0 <= u <= d.inverse_distance_max


def test_scene_domain_defaults(lens):
    """No f_number: the lens's default stop; no focus: the travel of its nearest light;
    all lights at infinity: infinity only."""
    plain = {k: v for k, v in SCENE.items() if k not in ("f_number", "focus_offset_mm")}
    d = scene_domain(lens, Scene.from_dict(plain))
    ref = default_domain(lens, close_focus_mm=0.98 * 2000.0)
    assert d.stop_radius_mm == ref.stop_radius_mm == default_domain(lens).stop_radius_mm
    assert (d.focus_min_mm, d.focus_max_mm) == (ref.focus_min_mm, ref.focus_max_mm)
    far = {**plain, "light": [SCENE["light"][0]]}
    d = scene_domain(lens, Scene.from_dict(far))
    assert d.close_focus_mm == math.inf and d.inverse_distance_max == 0.0


@pytest.mark.parametrize("bad", [0, -8.0, "f/8", math.inf, math.nan, True])
def test_scene_f_number_is_checked(bad):
    with pytest.raises(SceneError, match=r"^s.toml: key 'f_number': expected a positive "
                                         "f-number"):
        Scene.from_dict({**SCENE, "f_number": bad}, "s.toml")


def test_scene_faster_than_the_lens_is_refused(lens):
    with pytest.raises(ValueError, match="f/1 is wider than"):
        scene_domain(lens, Scene.from_dict({**SCENE, "f_number": 1.0}))


# --- the command line ----------------------------------------------------------------------

NEW_OPTIONS = ["--field", "--image-circle", "--wavelengths", "--close-focus", "--focus",
               "--psf-target", "--method"]


@pytest.mark.parametrize("command", ["fit", "report"])
def test_help_lists_the_domain_and_target_options(command, capsys):
    with pytest.raises(SystemExit) as info:
        main([command, "--help"])
    assert info.value.code == 0
    out = capsys.readouterr().out
    for option in NEW_OPTIONS + ["--f-number", "--quick"]:
        assert option in out, option
    assert "LO,HI" in out and "tensor" in out and "pursuit" in out
    assert ("--scene" in out) == (command == "fit")


@pytest.mark.parametrize(("args", "message"), [
    (["--wavelengths", "700,400"],
     "--wavelengths = '700,400': expected finite numbers with LO < HI"),
    (["--wavelengths", "700"], "--wavelengths = '700': expected two numbers LO,HI"),
    (["--wavelengths", "400,nan"], "--wavelengths = '400,nan': expected finite numbers"),
    (["--focus", "1,0"], "--focus = '1,0': expected finite numbers with LO < HI"),
    (["--focus", "a,b"], "--focus = 'a,b': expected two numbers LO,HI"),
    (["--field", "95"], "field = 95.0 degrees: expected an angle in (0, 90)"),
    (["--image-circle", "-1"], "image circle = -1.0 mm: expected a positive radius"),
    (["--close-focus", "0"], "close focus = 0.0 mm: expected a positive distance"),
    (["--close-focus", "abc"], "close-focus"),
    (["--psf-target", "2"], "fit options: psf_target = 2.0: expected a relative error"),
    # a scene fit's domain is the scene's: an option that would be ignored is refused
    (["--scene", "scenes/demo.toml", "--field", "3"], "the scene sets the domain"),
])
def test_bad_option_values_exit_2_naming_the_option(tmp_path, capsys, args, message):
    """Exit status 2, a message naming the option, and nothing written: the values are
    checked before any ray is traced. lensfit's own checks print one line; argparse's
    (a typed option) its usage and one error line."""
    gen, report = tmp_path / "gen", tmp_path / "report"
    try:
        code = main(["fit", "0001", "--quick", "--no-timing", "--generated", str(gen),
                     "--report", str(report), *args])
        parser = False
    except SystemExit as e:
        code, parser = e.code, True
    err = capsys.readouterr().err
    assert code == 2
    last = err.rstrip("\n").split("\n")[-1]
    assert last.startswith("lensfit fit: error: " if parser else "lensfit: error: "), err
    assert message in last, err
    assert parser or err.count("\n") == 1
    assert not gen.exists() and not report.exists()


def test_bad_method_is_refused_by_the_parser(capsys):
    with pytest.raises(SystemExit) as info:
        main(["fit", "0001", "--method", "omp"])
    assert info.value.code == 2
    err = capsys.readouterr().err
    assert "--method" in err and "invalid choice: 'omp'" in err
