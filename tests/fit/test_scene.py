"""Scenes: parsing and validation, and specialised systems against the general ones."""

from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np
import pytest

from lensfit.codegen.scene import (
    Light,
    Scene,
    SceneError,
    load_scene,
    max_abs_difference,
    specialise,
    terms,
)
from lensfit.poly import Polynomial, System, monomials
from lensfit.sample import OUTPUTS_O, OUTPUTS_S, Domain

REPO = Path(__file__).resolve().parents[2]
DOMAIN = Domain(field_deg=20.0, close_focus_mm=500.0, stop_radius_mm=10.0,
                sensor_radius_mm=21.6, focus_min_mm=-1.0, focus_max_mm=10.0)
VALID = {
    "name": "test-scene_1",
    "wavelengths_nm": [450.0, 550, 650.0],
    "focus_offset_mm": 0.25,
    "clip": True,
    "transmittance": False,
    "flares": False,
    "light": [
        {"field_x_deg": 6.0, "field_y_deg": 4.0, "distance_mm": "inf"},
        {"field_x_deg": -3.0, "field_y_deg": 0, "distance_mm": 2000},
    ],
}


def scene_dict(scene: Scene) -> dict:
    """The TOML layout of a Scene (the inverse of Scene.from_dict)."""
    d = {"name": scene.name, "wavelengths_nm": list(scene.wavelengths_nm),
         "clip": scene.clip, "transmittance": scene.transmittance, "flares": scene.flares,
         "light": [{"field_x_deg": lt.field_x_deg, "field_y_deg": lt.field_y_deg,
                    "distance_mm": "inf" if math.isinf(lt.distance_mm) else lt.distance_mm}
                   for lt in scene.lights]}
    if scene.focus_offset_mm is not None:
        d["focus_offset_mm"] = scene.focus_offset_mm
    return d


def toml_text(d: dict) -> str:
    """Just enough TOML for scene files."""
    def value(v):
        if isinstance(v, bool):
            return "true" if v else "false"
        if isinstance(v, str):
            return f'"{v}"'
        if isinstance(v, list):
            return "[" + ", ".join(value(x) for x in v) + "]"
        return repr(v)

    lines = [f"{k} = {value(v)}" for k, v in d.items() if k != "light"]
    for lt in d.get("light", []):
        lines += ["", "[[light]]"] + [f"{k} = {value(v)}" for k, v in lt.items()]
    return "\n".join(lines) + "\n"


# --- parsing -------------------------------------------------------------------------------


def test_valid_scene_parses_and_round_trips(tmp_path):
    sc = Scene.from_dict(VALID, "memory.toml")
    assert sc.name == "test-scene_1"
    assert sc.wavelengths_nm == (450.0, 550.0, 650.0)
    assert sc.focus_offset_mm == 0.25
    assert (sc.clip, sc.transmittance, sc.flares) == (True, False, False)
    assert sc.lights == (Light(6.0, 4.0, math.inf), Light(-3.0, 0.0, 2000.0))
    assert Scene.from_dict(scene_dict(sc)) == sc
    path = tmp_path / "s.toml"
    path.write_text(toml_text(VALID), encoding="utf-8")
    loaded = load_scene(path)
    assert loaded == sc and loaded.source_file == str(path)


def test_defaults_and_the_committed_demo_scene():
    sc = Scene.from_dict({"name": "a", "wavelengths_nm": [550],
                          "light": [{"field_x_deg": 0, "field_y_deg": 0}]})
    assert sc.focus_offset_mm is None and sc.clip and sc.transmittance and not sc.flares
    assert sc.lights[0].distance_mm == math.inf
    demo = load_scene(REPO / "scenes" / "demo.toml")
    assert demo.name == "demo" and demo.wavelengths_nm == (450.0, 550.0, 650.0)
    assert demo.lights == (Light(-6.0, -4.0, math.inf),)


def test_light_inputs_are_the_direction_cosines_of_its_field_angles():
    inp = Light(6.0, -4.0, 250.0).inputs()
    z = math.sqrt(1.0 - inp["x_O"] ** 2 - inp["y_O"] ** 2)
    # Field angles are the angles of the chief ray's projections on the x-z, y-z planes;
    # (x_O, y_O) point the other way, from the lens to the light (designers' convention)
    assert math.degrees(math.atan2(-inp["x_O"], z)) == pytest.approx(6.0, rel=1e-13)
    assert math.degrees(math.atan2(-inp["y_O"], z)) == pytest.approx(-4.0, rel=1e-13)
    assert inp["u_O"] == 1.0 / 250.0
    assert Light(0.0, 0.0).inputs() == {"x_O": 0.0, "y_O": 0.0, "u_O": 0.0}


def _with(**changes):
    d = {k: (list(v) if isinstance(v, list) else v) for k, v in VALID.items()}
    d["light"] = [dict(lt) for lt in VALID["light"]]
    for k, v in changes.items():
        if v is KeyError:
            d.pop(k)
        else:
            d[k] = v
    return d


def _light0(**changes):
    d = _with()
    d["light"][0].update(changes)
    for k, v in changes.items():
        if v is KeyError:
            d["light"][0].pop(k)
    return d


@pytest.mark.parametrize(("doc", "key", "shown"), [
    (_with(colour="red"), "colour", "'red'"),
    (_with(wavelengths_nm=[]), "wavelengths_nm", "[]"),
    (_with(wavelengths_nm=[450.0, -550.0]), "wavelengths_nm", "-550.0"),
    (_with(wavelengths_nm=[0]), "wavelengths_nm", "[0]"),
    (_with(wavelengths_nm="550"), "wavelengths_nm", "'550'"),
    (_with(wavelengths_nm=KeyError), "wavelengths_nm", "None"),
    (_with(name="my scene"), "name", "'my scene'"),
    (_with(name=""), "name", "''"),
    (_with(light=[]), "light", "[]"),
    (_with(light=KeyError), "light", "None"),
    (_light0(field_y_deg=KeyError), "light[0]", "'field_x_deg': 6.0"),
    (_light0(field_x_deg="six"), "light[0]", "'six'"),
    (_light0(distance_mm="far"), "light[0]", "'far'"),
    # tan() would fold 180 degrees (behind the camera) onto the axis
    (_light0(field_x_deg=180.0), "light[0].field_x_deg", "180.0"),
    (_light0(field_y_deg=-90.0), "light[0].field_y_deg", "-90.0"),
    (_light0(field_y_deg=math.inf), "light[0].field_y_deg", "inf"),
    (_light0(distance_mm=-5.0), "light[0].distance_mm", "-5.0"),
    (_light0(distance_mm=0), "light[0].distance_mm", "0.0"),
    (_light0(distance_mm=math.nan), "light[0].distance_mm", "nan"),
    (_with(light=["oops"]), "light[0]", "'oops'"),
    (_with(focus_offset_mm="near"), "focus_offset_mm", "'near'"),
    (_with(focus_offset_mm=math.inf), "focus_offset_mm", "inf"),
    (_with(clip="yes"), "clip", "'yes'"),
    (_with(transmittance=1), "transmittance", "1"),
    (_with(flares="no"), "flares", "'no'"),
])
def test_bad_scene_names_file_key_and_value(doc, key, shown):
    with pytest.raises(SceneError) as e:
        Scene.from_dict(doc, "bad.toml")
    msg = str(e.value)
    assert msg.startswith(f"bad.toml: key '{key}': "), msg
    assert shown in msg, msg


def test_unreadable_scene_files(tmp_path):
    with pytest.raises(SceneError, match="missing.toml: cannot read scene"):
        load_scene(tmp_path / "missing.toml")
    bad = tmp_path / "bad.toml"
    bad.write_text("name = \n", encoding="utf-8")
    with pytest.raises(SceneError, match="bad.toml: cannot read scene"):
        load_scene(bad)


# --- specialisation ----------------------------------------------------------------------------


def random_system(name: str, inputs, outputs, seed: int) -> System:
    """Every output: 60 random monomials of degree <= 6 (the constant and pure-piston
    terms included) with coefficients of mixed sign and size."""
    rng = np.random.default_rng(seed)
    table = monomials(6, 6)
    outs = []
    for out, unit in outputs:
        rows = table[np.sort(rng.choice(len(table), 60, replace=False))]
        rows[0] = 0  # a constant term
        rows[1] = [2, 0, 1, 0, 0, 1]  # and a stop-independent one
        coef = rng.choice([-1.0, 1.0], 60) * 10.0 ** rng.uniform(-4, 2, 60)
        outs.append(Polynomial(out, unit, rows, coef))
    return System(name, inputs, tuple(outs))


@pytest.fixture(scope="module")
def general() -> list[System]:
    return [random_system("P_o", DOMAIN.inputs_o(), OUTPUTS_O, 1),
            random_system("P_s", DOMAIN.inputs_s(), OUTPUTS_S, 2)]


def scale(p: Polynomial) -> float:
    """sum |c|: bounds |p| on the domain (|xhat| <= 1), and its rounding scale."""
    return float(np.abs(p.coefficients).sum())


def grid(system: System, fixed: dict[str, float], n: int = 500, seed: int = 3) -> np.ndarray:
    """Raw inputs of ``system``: the free ones uniform in the domain, the fixed ones set."""
    rng = np.random.default_rng(seed)
    cols = [np.full(n, fixed[i.name]) if i.name in fixed else rng.uniform(i.lo, i.hi, n)
            for i in system.inputs]
    return np.column_stack(cols)


def check_equal_at_fixed(general: System, special: System, fixed: dict[str, float]) -> None:
    """special(free) == general(free, fixed) for every output, phi less its value at the
    stop centre (x_a = y_a = 0 normalise to 0, so that value is exactly the sum of the
    stop-independent terms). Folding multiplies each coefficient by a few powers and
    sums merged terms: rounding ~10 eps sum|c|; 1e-12 sum|c| leaves margin."""
    x = grid(general, fixed)
    free = [j for j, i in enumerate(general.inputs) if i.name not in fixed]
    assert special.input_names == [general.inputs[j].name for j in free]
    x0 = x.copy()
    x0[:, general.input_names.index("x_a")] = 0.0
    x0[:, general.input_names.index("y_a")] = 0.0
    want = general.select(special.output_names)
    full, piston = want.evaluate(x), want.evaluate(x0)
    got = special.evaluate(x[:, free])
    for j, p in enumerate(want.outputs):
        expect = full[:, j] - (piston[:, j] if p.output.startswith("phi") else 0.0)
        assert np.max(np.abs(got[:, j] - expect)) <= 1e-12 * scale(p), p.output
    # The library's own comparison agrees
    assert max_abs_difference(general, special, fixed) <= 1e-12 * max(
        scale(p) for p in want.outputs)


def test_specialised_systems_equal_the_general_ones(general):
    sc = Scene.from_dict(VALID)
    special = specialise(general, sc)
    assert [s.name for s in special] == ["P_o_light0", "P_o_light1", "P_s"]
    for i, light in enumerate(sc.lights):
        s = special[i]
        assert s.input_names == ["x_a", "y_a", "lambda"]  # three wavelengths: kept
        # transmittance = false drops tau; clip = true keeps the pupil positions
        assert s.output_names == ["x_o", "y_o", "phi_o"]
        assert s.info["scene"] == sc.name
        assert s.info["fixed"] == pytest.approx(light.inputs())
        check_equal_at_fixed(general[0], s, light.inputs())
    p_s = special[2]
    assert p_s.input_names == ["x_S", "y_S", "x_a", "y_a", "lambda"]  # z_S folded
    assert p_s.output_names == ["x_i", "y_i", "phi_i"]
    check_equal_at_fixed(general[1], p_s, {"z_S": 0.25})


def test_single_wavelength_and_free_focus(general):
    sc = Scene.from_dict(_with(wavelengths_nm=[587.5], focus_offset_mm=KeyError,
                               transmittance=True))
    special = specialise(general, sc)
    assert special[0].input_names == ["x_a", "y_a"]
    assert special[0].output_names == ["x_o", "y_o", "tau_o", "phi_o"]
    assert special[2].input_names == ["x_S", "y_S", "z_S", "x_a", "y_a"]
    check_equal_at_fixed(general[0], special[0], {**sc.lights[0].inputs(), "lambda": 587.5})
    check_equal_at_fixed(general[1], special[2], {"lambda": 587.5})
    # Folding 6 -> 2 inputs merges terms: far fewer of them
    assert terms(special[:1]) < terms(general[:1]) / 2


@pytest.mark.parametrize(("clip", "transmittance", "outputs"), [
    (True, True, ["x_o", "y_o", "tau_o", "phi_o"]),
    (False, True, ["tau_o", "phi_o"]),
    (True, False, ["x_o", "y_o", "phi_o"]),
    (False, False, ["phi_o"]),
])
def test_outputs_are_dropped_as_asked(general, clip, transmittance, outputs):
    sc = Scene.from_dict(_with(clip=clip, transmittance=transmittance))
    special = specialise(general, sc)
    assert special[0].output_names == outputs
    assert special[2].output_names == [o.replace("_o", "_i") for o in outputs]


def test_phase_keeps_only_stop_dependent_terms(general):
    special = specialise(general, Scene.from_dict(_with(wavelengths_nm=[550.0])))
    for s in special:
        phi = s.output("phi_o" if s.name.startswith("P_o") else "phi_i")
        ja, jb = s.input_names.index("x_a"), s.input_names.index("y_a")
        assert phi.terms > 0
        assert np.all(phi.exponents[:, ja] + phi.exponents[:, jb] > 0)
        x = grid(s, {"x_a": 0.0, "y_a": 0.0}, n=50)
        assert np.all(s.evaluate(x)[:, s.output_names.index(phi.output)] == 0.0)
        # The other outputs keep their constant terms
        assert any(np.all(p.exponents == 0, axis=1).any() for p in s.outputs
                   if not p.output.startswith("phi"))


@pytest.mark.parametrize("azimuth", [0.0, 30.0, 45.0, 90.0])
def test_light_at_the_edge_of_the_field_is_served(general, azimuth):
    """A direction at the field angle (any azimuth), at the close focus distance: inside
    the fitted domain up to rounding."""
    t = math.tan(math.radians(DOMAIN.field_deg))
    a = math.radians(azimuth)
    fx, fy = (math.degrees(math.atan(t * math.cos(a))), math.degrees(math.atan(t * math.sin(a))))
    sc = Scene.from_dict(_with(light=[{"field_x_deg": fx, "field_y_deg": fy,
                                       "distance_mm": DOMAIN.close_focus_mm}]))
    special = specialise(general, sc)
    check_equal_at_fixed(general[0], special[0], sc.lights[0].inputs())
    # One percent further out is refused
    far = Scene.from_dict(_with(light=[{"field_x_deg": 1.01 * fx, "field_y_deg": 1.01 * fy}]))
    with pytest.raises(SceneError, match="outside the fitted"):
        specialise(general, far)


@pytest.mark.parametrize(("changes", "where", "what"), [
    ({"light": [{"field_x_deg": 25.0, "field_y_deg": 0.0}]}, "light[0]", "x_O"),
    ({"light": [{"field_x_deg": 0.0, "field_y_deg": -21.0}]}, "light[0]", "y_O"),
    # Within the box of x_O and y_O, but in its corner: directions were sampled on the
    # disc of the 20 degree field only (radius of (0.25, 0.25) is 0.354 > sin 20 = 0.342)
    ({"light": [{"field_x_deg": 15.0, "field_y_deg": 15.0}]}, "light[0]",
     "the direction (x_O, y_O)"),
    ({"light": [{"field_x_deg": 1.0, "field_y_deg": 1.0, "distance_mm": 100.0}]},
     "light[0]", "u_O"),
    ({"wavelengths_nm": [550.0, 300.0]}, "wavelengths_nm", "lambda = 300"),
    ({"wavelengths_nm": [800.0]}, "wavelengths_nm", "lambda = 800"),
    ({"focus_offset_mm": 12.0}, "focus_offset_mm", "z_S = 12"),
    ({"focus_offset_mm": -1.5}, "focus_offset_mm", "z_S = -1.5"),
])
def test_scene_outside_the_fitted_domain_is_refused(general, changes, where, what):
    sc = Scene.from_dict(_with(**changes), "far.toml")
    with pytest.raises(SceneError) as e:
        specialise(general, sc)
    msg = str(e.value)
    assert msg.startswith(f"far.toml: {where}: {what}"), msg
    assert "outside the fitted" in msg


@pytest.mark.parametrize("changes, key, what", [
    ({"ghosts": ["4-8"]}, "ghosts", "needs flares = true"),
    ({"flares": True, "ghosts": ["4-8"], "ghost_count": 2}, "ghost_count", "one of ghosts"),
    ({"flares": True, "ghosts": []}, "ghosts", "non-empty list"),
    ({"flares": True, "ghosts": [4]}, "ghosts", "non-empty list"),
    ({"flares": True, "ghost_count": 0}, "ghost_count", "positive number"),
    ({"flares": True, "ghost_count": True}, "ghost_count", "positive number"),
    ({"flares": True, "ghost_threshold": 2.0}, "ghost_threshold", "in (0, 1)"),
    ({"flares": True, "ghost_threshold": "1e-5"}, "ghost_threshold", "in (0, 1)"),
])
def test_ghost_choice_is_checked(changes, key, what):
    with pytest.raises(SceneError, match=rf"flare.toml: key '{key}': .*{re.escape(what)}"):
        Scene.from_dict(_with(**changes), "flare.toml")
    sc = Scene.from_dict(_with(flares=True, ghost_count=3), "flare.toml")
    assert (sc.flares, sc.ghost_count, sc.ghosts, sc.ghost_threshold) == (True, 3, None, None)


def test_missing_systems_are_refused(general):
    with pytest.raises(SceneError, match="no fitted P_o and P_s"):
        specialise(general[:1], Scene.from_dict(VALID))


def test_elliptic_field_of_an_anamorphic_domain(general):
    """With a narrower field in y the directions fill an ellipse: a light inside the
    box of (x_O, y_O) but outside the ellipse is refused, one inside is served."""
    narrow = DOMAIN.with_(field_y_deg=10.0)
    p_o = random_system("P_o", narrow.inputs_o(), OUTPUTS_O, 1)
    systems = [p_o, general[1]]
    sx, sy = math.sin(math.radians(20.0)), math.sin(math.radians(10.0))
    assert (p_o.inputs[0].hi, p_o.inputs[1].hi) == pytest.approx((sx, sy), rel=1e-15)

    def light_at(x, y):  # field angles of a light in the direction cosines (x, y)
        z = math.sqrt(1.0 - x * x - y * y)
        return {"field_x_deg": math.degrees(math.atan(-x / z)),
                "field_y_deg": math.degrees(math.atan(-y / z))}

    inside = Scene.from_dict(_with(light=[light_at(0.7 * sx, 0.7 * sy)]))  # r = 0.99
    special = specialise(systems, inside)
    check_equal_at_fixed(p_o, special[0], inside.lights[0].inputs())
    outside = Scene.from_dict(_with(light=[light_at(0.72 * sx, 0.72 * sy)]))  # r = 1.02
    with pytest.raises(SceneError, match=r"light\[0\]: the direction .* outside the fitted"):
        specialise(systems, outside)
