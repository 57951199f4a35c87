"""The declared domain a lens is fitted over, and the raw input variables of P_o and P_s.

Inputs of the two systems (paper eq. 1 and 2, with one change: inverse distance):

* ``P_o(x_O, y_O, u_O, x_a, y_a, lambda)``: ``x_O, y_O`` are the x and y direction
  cosines of the scene point seen from the vertex of the first surface (the centre of the
  outer pupil); ``u_O = 1 / d_O`` is the inverse of its distance from there (1/mm, 0 for
  a point at infinity); ``x_a, y_a`` the point on the stop (mm); ``lambda`` in nm.
* ``P_s(x_S, y_S, z_S, x_a, y_a, lambda)``: ``x_S, y_S`` the sensor point (mm), ``z_S``
  the sensor's shift from its nominal position along +z (mm, positive away from the
  lens: focusing closer), then the stop point and wavelength as above.

A polynomial in ``d_O`` cannot reach infinity; one in ``u_O`` is smooth down to ``u_O =
0``, where the scene point becomes a direction. OPL is measured relative to ``d_O`` (see
:mod:`lensfit.sample.rays`), which stays finite at infinity too.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, replace
from typing import Any

from lensfit.errors import InputError
from lensfit.glass.ranges import Wavelengths, default_wavelengths
from lensfit.paraxial.paraxial import image_distance, paraxial, stop_radius_for_f_number
from lensfit.poly.polynomial import Input
from lensfit.prescription.model import Lens

FULL_FRAME_HALF_DIAGONAL_MM = 0.5 * math.hypot(36.0, 24.0)
CLOSE_FOCUS_EFL = 10.0  # default close focus: ten focal lengths in front of the lens
MAX_DEFAULT_FIELD_DEG = 60.0
# Default widest aperture fitted: f/2, the widest setting of the paper's Figure 7 and of our
# demo. Faster lenses need far more terms wide open (see the fit report); ask for it with
# an explicit stop radius or f-number.
DEFAULT_F_NUMBER = 2.0


@dataclass(frozen=True)
class Domain:
    """Where the polynomials must be right. Lengths in mm, angles in degrees, nm."""

    field_deg: float  # half field angle in x: scene directions within this cone
    close_focus_mm: float  # nearest scene point, from the first vertex (inf: infinity only)
    stop_radius_mm: float  # aperture disc sampled on the stop
    sensor_radius_mm: float  # sensor points within this disc (the image circle)
    focus_min_mm: float  # sensor shift range z_S
    focus_max_mm: float
    wavelength_min_nm: float = 380.0
    wavelength_max_nm: float = 780.0
    field_y_deg: float | None = None  # half field angle in y when it differs (anamorphic):
    # the directions then fill an ellipse in direction cosines

    @property
    def field_xy_deg(self) -> tuple[float, float]:
        return self.field_deg, self.field_deg if self.field_y_deg is None else self.field_y_deg

    def __post_init__(self) -> None:
        for k in self.__dataclass_fields__:  # plain floats (numpy scalars creep in)
            v = getattr(self, k)
            if v is not None:
                object.__setattr__(self, k, float(v))
        if self.field_y_deg is not None and not 0.0 < self.field_y_deg < 90.0:
            raise InputError(f"domain: field_y_deg = {self.field_y_deg} must be in (0, 90)")
        checks = [
            ("field_deg", 0.0 < self.field_deg < 90.0, "in (0, 90)"),
            ("close_focus_mm", self.close_focus_mm > 0.0, "positive (inf allowed)"),
            ("stop_radius_mm", 0.0 < self.stop_radius_mm < math.inf, "positive, finite"),
            ("sensor_radius_mm", 0.0 < self.sensor_radius_mm < math.inf, "positive, finite"),
            ("focus_min_mm", self.focus_min_mm < self.focus_max_mm, "below focus_max_mm"),
            ("wavelength_min_nm", 0.0 < self.wavelength_min_nm < self.wavelength_max_nm,
             "positive and below wavelength_max_nm"),
        ]
        for key, ok, want in checks:
            value = getattr(self, key)
            if not ok or math.isnan(value):
                raise InputError(f"domain: {key} = {value} must be {want}")

    @property
    def inverse_distance_max(self) -> float:
        """Largest u_O = 1/d_O (1/mm); 0 when only infinity is wanted."""
        return 0.0 if math.isinf(self.close_focus_mm) else 1.0 / self.close_focus_mm

    def inputs_o(self) -> tuple[Input, ...]:
        sx, sy = (math.sin(math.radians(f)) for f in self.field_xy_deg)
        u = self.inverse_distance_max
        r = self.stop_radius_mm
        return (
            Input("x_O", "1 (direction cosine)", -sx, sx),
            Input("y_O", "1 (direction cosine)", -sy, sy),
            # A degenerate [0, 0] domain is widened so the normalisation stays defined
            Input("u_O", "1/mm (inverse distance, 0 = infinity)", 0.0, u if u > 0 else 1e-9),
            Input("x_a", "mm (on the stop)", -r, r),
            Input("y_a", "mm (on the stop)", -r, r),
            self._wavelength_input(),
        )

    def inputs_s(self) -> tuple[Input, ...]:
        h, r = self.sensor_radius_mm, self.stop_radius_mm
        return (
            Input("x_S", "mm (on the sensor)", -h, h),
            Input("y_S", "mm (on the sensor)", -h, h),
            Input("z_S", "mm (sensor shift, + away from the lens)",
                  self.focus_min_mm, self.focus_max_mm),
            Input("x_a", "mm (on the stop)", -r, r),
            Input("y_a", "mm (on the stop)", -r, r),
            self._wavelength_input(),
        )

    def _wavelength_input(self) -> Input:
        # Dispersion is close to linear in 1/lambda^2 (Cauchy), so that is the variable
        return Input("lambda", "nm", self.wavelength_min_nm, self.wavelength_max_nm,
                     "inverse_square")

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        if math.isinf(self.close_focus_mm):
            d["close_focus_mm"] = "inf"
        return d

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> Domain:
        d = dict(d)
        if d.get("field_y_deg") is None:
            d.pop("field_y_deg", None)
        unknown = set(d) - set(cls.__dataclass_fields__)
        if unknown:
            raise InputError(f"domain: unknown keys {sorted(unknown)}")
        return cls(**{k: float(v) for k, v in d.items()})

    def with_(self, **changes: Any) -> Domain:
        return replace(self, **changes)


def declared_fit(lens: Lens) -> dict[str, Any]:
    """The lens file's [fit] table: the domain it declares instead of the default, and
    its reason ({} when it declares none)."""
    return dict((lens.raw or {}).get("fit", {}))


def fit_wavelengths(lens: Lens, wavelengths_nm: tuple[float, float] | None = None,
                    asked_by: str = "wavelengths_nm") -> Wavelengths:
    """The band a fit covers and why: ``wavelengths_nm`` as asked (``asked_by`` names
    who asked, e.g. ``--wavelengths 400,700``), else the default of
    :func:`lensfit.glass.ranges.default_wavelengths`: 380-780 nm narrowed to the range
    every glass of the lens supports (unchanged when the lens allows extrapolation)."""
    if wavelengths_nm is None:
        return default_wavelengths(lens)
    return Wavelengths.asked(*wavelengths_nm, asked_by)


def default_domain(lens: Lens, f_number: float | None = None, *,
                   field_deg: float | None = None, close_focus_mm: float | None = None,
                   wavelengths_nm: tuple[float, float] | None = None,
                   focus_mm: tuple[float, float] | None = None,
                   image_circle_mm: float | None = None) -> Domain:
    """A full-frame camera: the image circle of 36 x 24 mm, the field that fills it (at
    most 60 degrees), focus from infinity to ten focal lengths, the stop open to
    ``f_number`` (default: f/2, or wide open when the lens is slower), 380-780 nm
    narrowed to the range every glass of the lens supports (:func:`fit_wavelengths`;
    an error naming the glasses when that leaves under 50 nm).

    Each keyword narrows (or widens) one part: ``field_deg`` the half field angle in x
    (y follows the lens's squeeze) and with it the image circle (the paraxial image of
    the field plus 10% for distortion, at most the frame's); ``image_circle_mm`` the
    radius of the sensor disc outright; ``close_focus_mm`` the nearest scene point (inf:
    infinity only) and with it the sensor travel; ``focus_mm`` the sensor shift range
    z_S outright; ``wavelengths_nm`` (lo, hi) outright (checked against the glasses'
    ranges when the fit starts: :func:`lensfit.glass.ranges.check_glass_ranges`)."""
    # A lens file may declare a narrower default ([fit] in its TOML, with the reason)
    declared = declared_fit(lens)
    if f_number is None:
        f_number = declared.get("f_number")
    if field_deg is None:
        field_deg = declared.get("field_deg")
    efl_x, efl_y = (abs(paraxial(lens, meridian=m).efl_mm) for m in ("x", "y"))
    efl = min(efl_x, efl_y)
    h = FULL_FRAME_HALF_DIAGONAL_MM

    def field_for(f: float) -> float:
        return min(math.degrees(math.atan(h / f)), MAX_DEFAULT_FIELD_DEG)

    field = field_for(efl_x)
    # An anamorphic lens squeezes x: its field is wider in x than in y (an ellipse)
    field_y = field_for(efl_y) if lens.anamorphic else None
    if field_deg is not None:
        if not 0.0 < field_deg < 90.0:
            raise InputError(f"field = {field_deg!r} degrees: expected an angle in (0, 90)")
        if field_y is not None:  # keep the squeeze's ratio of the two fields
            field_y = math.degrees(math.atan(math.tan(math.radians(field_deg))
                                             * efl_x / efl_y))
        field = field_deg
        h = min(h, 1.1 * max(efl_x * math.tan(math.radians(field)),
                             efl_y * math.tan(math.radians(field_y or field))))
    if image_circle_mm is not None:
        if not (math.isfinite(image_circle_mm) and image_circle_mm > 0):
            raise InputError(f"image circle = {image_circle_mm!r} mm: expected a positive "
                             "radius")
        h = image_circle_mm
    close = float(CLOSE_FOCUS_EFL * efl) if close_focus_mm is None else float(close_focus_mm)
    if not close > 0:
        raise InputError(f"close focus = {close_focus_mm!r} mm: expected a positive distance "
                         "from the first vertex, or inf")
    # Sensor travel from infinity focus to close focus, with a margin both ways
    travel = float(image_distance(lens, close) - image_distance(lens, math.inf))
    margin = 0.01 * efl
    if f_number is None:
        try:
            stop = stop_radius_for_f_number(lens, DEFAULT_F_NUMBER)
        except ValueError:  # the lens is slower than f/2: wide open
            stop = lens.stop_radius_max_mm
    else:
        stop = stop_radius_for_f_number(lens, f_number)
    lo, hi = min(0.0, travel) - margin, max(0.0, travel) + margin
    if focus_mm is not None:
        lo, hi = focus_mm
    w_lo, w_hi = fit_wavelengths(lens, wavelengths_nm).range_nm
    return Domain(
        field_deg=field,
        close_focus_mm=close,
        stop_radius_mm=stop,
        sensor_radius_mm=h,
        focus_min_mm=lo,
        focus_max_mm=hi,
        wavelength_min_nm=w_lo,
        wavelength_max_nm=w_hi,
        field_y_deg=field_y,
    )
