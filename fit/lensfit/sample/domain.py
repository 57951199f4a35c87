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

import numpy as np

from lensfit.common.errors import InputError
from lensfit.paraxial.paraxial import image_distance, paraxial, stop_radius_for_f_number
from lensfit.poly.polynomial import Input
from lensfit.prescription.model import Lens
from lensfit.prescription.ranges import Wavelengths, default_wavelengths

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


def describe_domain(lens: Lens, domain: Domain) -> str:
    """The domain in a person's terms for messages: 'a 35.2 degree half field, f/2, from
    infinity to 260 mm, 380-780 nm'."""
    from lensfit.paraxial.paraxial import f_number_for_stop_radius

    fx, fy = domain.field_xy_deg
    field = f"{fx:.3g} degree half field" + ("" if fy == fx else f" ({fy:.3g} in y)")
    near = ("infinity only" if math.isinf(domain.close_focus_mm)
            else f"from infinity to {domain.close_focus_mm:.4g} mm")
    f_n = abs(f_number_for_stop_radius(lens, domain.stop_radius_mm))
    return (f"a {field}, f/{f_n:.3g}, {near}, {domain.wavelength_min_nm:g}-"
            f"{domain.wavelength_max_nm:g} nm")


def declared_fit(lens: Lens) -> dict[str, Any]:
    """The lens file's [fit] table: the domain it declares instead of the default, and
    its reason ({} when it declares none)."""
    return dict((lens.raw or {}).get("fit", {}))


def fit_wavelengths(lens: Lens, wavelengths_nm: tuple[float, float] | None = None,
                    asked_by: str = "wavelengths_nm") -> Wavelengths:
    """The band a fit covers and why: ``wavelengths_nm`` as asked (``asked_by`` names
    who asked, e.g. ``--wavelengths 400,700``), else the default of
    :func:`lensfit.prescription.ranges.default_wavelengths`: 380-780 nm narrowed to the range
    every glass of the lens supports (unchanged when the lens allows extrapolation)."""
    if wavelengths_nm is None:
        return default_wavelengths(lens)
    return Wavelengths.asked(*wavelengths_nm, asked_by)


def default_domain(lens: Lens, f_number: float | None = None, *,
                   field_deg: float | None = None, close_focus_mm: float | None = None,
                   wavelengths_nm: tuple[float, float] | None = None,
                   focus_mm: tuple[float, float] | None = None,
                   image_circle_mm: float | None = None) -> Domain:
    """The design's own domain where the lens file states it, else a full-frame camera.

    Each part comes from the first of: the keyword here (the command line), the lens
    file's ``[fit]`` table (a declared domain, with its reason), the lens file's
    ``[lens]`` statement of the design (``f_number``, ``field_of_view_deg``: what the
    source or ``lensfit import`` wrote), the default: the image circle of 36 x 24 mm,
    the field that fills it (at most 60 degrees), focus from infinity to ten focal
    lengths (from real rays: no further than the chief ray passes, and the image
    circle the real image of the field's edge; an anamorphic lens's field narrowed in
    both meridians at the squeeze's ratio), the stop open to f/2 (or wide open when the
    lens is slower), 380-780 nm
    narrowed to the range every glass of the lens supports (:func:`fit_wavelengths`;
    an error naming the glasses when that leaves under 50 nm). A stated f-number wider
    than the stop opens is the widest stop; a stated field of view is the full diagonal
    field, so its half is the half field fitted, and the image circle follows.

    A lens that forms no real image of a distant scene in some meridian (its paraxial
    image lies in front of its last surface, or at infinity: an afocal group, or an
    attachment meant to sit behind another lens) is refused with the reason, unless the
    sensor travel is given (``focus_mm``). The sensor travel is taken from where the
    lens really focuses: a sensor that the table puts far from the paraxial focus is
    moved there (the travel is then not centred on z_S = 0).

    Each keyword narrows (or widens) one part: ``field_deg`` the half field angle in x
    (y follows the lens's squeeze) and with it the image circle (the real image of
    the field's edge plus IMAGE_MARGIN, at most the frame's; for an anamorphic lens the
    paraxial image plus 10%); ``image_circle_mm`` the
    radius of the sensor disc outright; ``close_focus_mm`` the nearest scene point (inf:
    infinity only) and with it the sensor travel; ``focus_mm`` the sensor shift range
    z_S outright; ``wavelengths_nm`` (lo, hi) outright (checked against the glasses'
    ranges when the fit starts: :func:`lensfit.prescription.ranges.check_glass_ranges`)."""
    # A lens file may declare a narrower default ([fit] in its TOML, with the reason)
    declared = declared_fit(lens)
    stated = stated_design(lens)
    stated_f = False
    if f_number is None:
        f_number = declared.get("f_number")
    if f_number is None and "f_number" in stated:
        f_number, stated_f = stated["f_number"], True
    asked_field = field_deg is not None
    if field_deg is None:
        field_deg = declared.get("field_deg")
    if field_deg is None and "field_deg" in stated:
        field_deg = min(stated["field_deg"], MAX_DEFAULT_FIELD_DEG)
    if focus_mm is None:
        refuse_without_image(lens)
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
    if lens.anamorphic and field_deg is None:
        # The frame's field of an anamorphic lens, from real rays too: in each meridian
        # no further than the chief ray passes (lens 2003: its rear anamorphic group's
        # housing at surface 18 stops the chief ray beyond 7.3 degrees in y, against the
        # frame's 11.8; it misses or reflects totally beyond 10.3, and 30% of the
        # frame's sensor-side grid had no ray), both narrowed together so that the
        # field keeps the squeeze's ratio (the sensor domain is a disc), and the image
        # circle the real image of the field's edge (the largest over the ellipse)
        squeeze = math.tan(math.radians(field_y)) / math.tan(math.radians(field))
        tan_x = min(math.tan(math.radians(passing_field(lens, field, "x"))),
                    math.tan(math.radians(passing_field(lens, field_y, "y"))) / squeeze)
        field = math.degrees(math.atan(tan_x))
        field_y = math.degrees(math.atan(squeeze * tan_x))
        r = anamorphic_image_radius(lens, field, field_y)
        if r is not None and (r > h or IMAGE_MARGIN * r < h):
            h = IMAGE_MARGIN * r
    if not lens.anamorphic:
        # Real rays, not paraxial ones: the field ends where the chief ray stops passing
        # (unless the field was asked for), and the image circle holds the real image of
        # the field's edge (a retrofocus's barrel distortion puts it well inside the
        # paraxial one, and sensor points beyond it are reached by no ray)
        if not asked_field:
            field = min(field, passing_field(lens, field))
        r = chief_image_radius(lens, field)
        if r is not None and field_deg is None:  # the frame's field: its real image
            if r > h or IMAGE_MARGIN * r < h:
                h = IMAGE_MARGIN * r
        elif r is not None and asked_field:  # its real image, within the frame
            h = min(IMAGE_MARGIN * r, FULL_FRAME_HALF_DIAGONAL_MM)
        elif r is not None:  # the design's own field (stated or declared): its image
            h = IMAGE_MARGIN * r
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
    infinity = float(image_distance(lens, math.inf))
    travel = float(image_distance(lens, close) - infinity)
    margin = 0.01 * efl
    if f_number is None or stated_f:
        try:
            stop = stop_radius_for_f_number(lens, f_number or DEFAULT_F_NUMBER)
        except ValueError:  # the lens is slower than f/2 (or its stated f/N): wide open
            stop = lens.stop_radius_max_mm
    else:
        stop = stop_radius_for_f_number(lens, f_number)
    # Where the table puts the sensor (z_S = 0) is the design's focus for a distant scene
    # unless it is off by more than the margin (lens 0012's table: 23 mm behind its
    # paraxial focus): the travel then reaches from the table's sensor to the paraxial
    # focus of a distant scene and on to the close focus
    shift = infinity - float(lens.sensor_z - lens.vertex_z[-1])
    ends = [0.0, travel] if abs(shift) <= margin else [0.0, shift, shift + travel]
    lo, hi = min(ends) - margin, max(ends) + margin
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


# A focal length this many times the lens's length (first vertex to sensor) is a group
# that is afocal or nearly so (a telephoto's is at most 2-3 times; the rear anamorphic
# attachment 2002 has 41 times in y): it forms no image a camera behind it can hold
AFOCAL_TRACK = 20.0


def stated_design(lens: Lens) -> dict[str, float]:
    """What the lens file's ``[lens]`` table states of the design, as a domain's parts:
    ``f_number`` (the design's aperture) and ``field_deg`` (half the stated full
    diagonal ``field_of_view_deg``), each only when stated as a positive number. The
    default domain caps the field at MAX_DEFAULT_FIELD_DEG (:func:`field_cap_note`)."""
    info = (lens.raw or {}).get("lens", {})
    out: dict[str, float] = {}
    f = info.get("f_number")
    if isinstance(f, (int, float)) and not isinstance(f, bool) and math.isfinite(f) and f > 0:
        out["f_number"] = float(f)
    fov = info.get("field_of_view_deg")
    if (isinstance(fov, (int, float)) and not isinstance(fov, bool) and math.isfinite(fov)
            and fov > 0):
        out["field_deg"] = 0.5 * float(fov)
    return out


def field_cap_note(lens: Lens, domain: Domain) -> str | None:
    """A line saying that the fitted field is narrower than the field of view the lens
    file states, and why, or None. Why: the default's cap (a fisheye's 180 degrees: the
    polynomials' scene-side field variables are direction cosines, whose maps a single
    polynomial does not follow past MAX_DEFAULT_FIELD_DEG); or the chief ray, which
    passes the housings no further (lens 0013's table: to 31.0 of its 31.7 degrees); or
    neither, a narrower field asked for (``--field``, the lens file's ``[fit]``, or a fit
    made before the lens file stated its field)."""
    half = stated_design(lens).get("field_deg")
    if half is None or half <= domain.field_deg + 1e-9:
        return None
    f = domain.field_deg
    if abs(f - MAX_DEFAULT_FIELD_DEG) < 1e-9:
        why = (f"a single polynomial in direction cosines is not fitted past "
               f"{MAX_DEFAULT_FIELD_DEG:g} degrees by default; --field sets it")
    elif f + 0.2 < 90.0 and chief_image_radius(lens, f + 0.2) is None:
        why = "the chief ray passes the lens's housings no further"
    else:
        why = ("a narrower field asked for: --field, the lens file's [fit] field_deg, or a "
               "fit made before the lens file stated its field")
    return (f"the lens states a {2 * half:.4g} degree field of view; fitted over "
            f"{2 * f:.4g} degrees (half field {f:.4g} degrees: {why})")


def refuse_without_image(lens: Lens) -> None:
    """InputError when ``lens`` forms no real image of a distant scene in some meridian:
    its paraxial image lies in front of the last surface (a diverging group: lens 2002,
    a rear attachment; or a table not in working order: lens 2001, whose x meridian
    focuses 2.2 mm in front of its last surface), or when its focal length is AFOCAL_TRACK
    times its length or more (afocal). The message says why and what to pass."""
    where = lens.source_file or lens.name
    track = float(lens.sensor_z - lens.vertex_z[0])
    for m in ("x", "y") if lens.anamorphic else ("y",):
        d = float(image_distance(lens, math.inf, meridian=m))
        efl = float(paraxial(lens, meridian=m).efl_mm)
        meridian = f" in the {m}-z meridian" if lens.anamorphic else ""
        if not (math.isfinite(d) and math.isfinite(efl)
                and abs(efl) < AFOCAL_TRACK * track):
            raise InputError(
                f"{where}: the lens is afocal{meridian} (paraxial EFL {efl:.6g} mm, "
                f"{AFOCAL_TRACK:g} times its length {track:.6g} mm or more): it forms no "
                "image a camera behind it can hold; fit the system "
                "it belongs to, or give the sensor travel (--focus LO,HI) and the image "
                "circle (--image-circle MM) to fit it as it is")
        if d <= 0.0:
            raise InputError(
                f"{where}: the lens forms no real image of a distant scene{meridian}: its "
                f"paraxial image lies {-d:.6g} mm in front of its last surface (EFL "
                f"{efl:.6g} mm); an attachment meant to sit behind or in front of another "
                "lens, or a table not in working order; fit the system it belongs to, or "
                "give the sensor travel (--focus LO,HI) to fit it as it is")


# The image circle fitted: the real image height of the field's edge times this (room for
# the spots of the field's edge and for lateral colour), when the paraxial one is off by
# more (lens 0005's field edge images at 17.2 mm against the frame's 21.6 mm)
IMAGE_MARGIN = 1.05


def _chief_rays(lens: Lens, field_deg: np.ndarray, wavelength_nm: float = 550.0,
                meridian: str = "x") -> tuple[np.ndarray, np.ndarray]:
    """The chief rays (through the stop centre) of lights at infinity at field angles
    ``field_deg`` in ``meridian`` (x or y): (image height on the nominal sensor (mm; NaN
    where the ray fails), passes: the ray exists and passes every housing)."""
    sin = np.sin(np.radians(np.asarray(field_deg, dtype=np.float64)))
    zero = np.zeros_like(sin)
    return _chief_rays_xy(lens, *((sin, zero) if meridian == "x" else (zero, sin)),
                          wavelength_nm)


def _chief_rays_xy(lens: Lens, x_O: np.ndarray, y_O: np.ndarray, wavelength_nm: float
                   ) -> tuple[np.ndarray, np.ndarray]:
    """:func:`_chief_rays` of lights at infinity in the directions (x_O, y_O) (direction
    cosines)."""
    from lensfit.sample.aim import aim_object_side
    from lensfit.trace.tracer import Rays, Status, Step, trace

    obj = aim_object_side(lens, x_O, y_O, 0.0, 0.0, 0.0, wavelength_nm)
    s, n = lens.stop_index, len(lens.surfaces)
    front = obj.ok & (obj.vignetting <= 1.0)
    pos = np.where(front[:, None], np.nan_to_num(obj.pos), [0.0, 0.0, lens.vertex_z[s]])
    d = np.where(front[:, None], np.nan_to_num(obj.dir), [0.0, 0.0, 1.0])
    out = trace(lens, Rays(pos, d, np.full(len(x_O), wavelength_nm)),
                [Step(k) for k in range(s + 1, n)], clip=True, end_z=lens.sensor_z)
    passes = front & (out.status == Status.OK)
    return np.where(passes, np.hypot(out.pos[:, 0], out.pos[:, 1]), np.nan), passes


CHIEF_WAVELENGTHS_NM = (450.0, 550.0, 650.0)


def _chief_passes(lens: Lens, field_deg: np.ndarray, meridian: str = "x"
                  ) -> tuple[np.ndarray, np.ndarray]:
    """(largest image height over CHIEF_WAVELENGTHS_NM (mm), passes at every one)."""
    runs = [_chief_rays(lens, field_deg, lam, meridian) for lam in CHIEF_WAVELENGTHS_NM]
    passes = np.logical_and.reduce([p for _, p in runs])
    heights = np.max([np.where(passes, h, 0.0) for h, _ in runs], axis=0)
    return np.where(passes, heights, np.nan), passes


def chief_image_radius(lens: Lens, field_deg: float) -> float | None:
    """How far from the axis the chief ray at ``field_deg`` meets the nominal sensor,
    the largest over CHIEF_WAVELENGTHS_NM (mm); None when it does not pass at one."""
    heights, passes = _chief_passes(lens, np.array([field_deg]))
    return float(heights[0]) if passes[0] else None


def passing_field(lens: Lens, field_deg: float, meridian: str = "x") -> float:
    """The largest half field up to ``field_deg`` whose chief rays (every angle from the
    axis out to it, at each of CHIEF_WAVELENGTHS_NM) pass every housing, to 0.1 degree
    (a lens made for a smaller frame: lens 0007's chief ray fails behind the stop at the
    36 x 24 mm frame's 39.8 degrees). ``field_deg`` itself when they all pass. The
    angles are in ``meridian`` (x or y: an anamorphic lens's y field; lens 2003's chief
    ray is clipped in its rear anamorphic group beyond 7.3 degrees in y)."""
    angles = np.linspace(0.0, field_deg, 241)
    _, passes = _chief_passes(lens, angles, meridian)
    if passes.all():
        return field_deg
    first = int(np.argmin(passes))
    if first == 0:
        raise InputError(f"{lens.source_file or lens.name}: the ray through the centre of "
                         "the stop on the axis does not pass the lens")
    lo, hi = float(angles[first - 1]), float(angles[first])
    while hi - lo > 0.1:
        mid = 0.5 * (lo + hi)
        if _chief_passes(lens, np.array([mid]), meridian)[1][0]:
            lo = mid
        else:
            hi = mid
    return lo


# Azimuths at which the edge of an anamorphic lens's field (an ellipse in direction
# cosines) is traced for its real image (anamorphic_image_radius); every 7.5 degrees of
# a quadrant (the lenses are mirror-symmetric in x and in y)
ELLIPSE_AZIMUTHS = 13


def anamorphic_image_radius(lens: Lens, field_x_deg: float, field_y_deg: float
                            ) -> float | None:
    """How far from the axis the chief rays of the edge of the field ellipse (half fields
    ``field_x_deg``, ``field_y_deg``) meet the nominal sensor, the largest over the
    ellipse and CHIEF_WAVELENGTHS_NM (mm); None when one of them does not pass."""
    a = np.linspace(0.0, 0.5 * math.pi, ELLIPSE_AZIMUTHS)
    x_O = math.sin(math.radians(field_x_deg)) * np.cos(a)
    y_O = math.sin(math.radians(field_y_deg)) * np.sin(a)
    runs = [_chief_rays_xy(lens, x_O, y_O, lam) for lam in CHIEF_WAVELENGTHS_NM]
    if not all(p.all() for _, p in runs):
        return None
    return float(max(np.max(h) for h, _ in runs))
