"""A thin ctypes binding of the lensrt C API, for tests, benchmarks and notebooks.

    from lensrt_ctypes import Lensrt               # or: from lensrt import Lensrt
    rt = Lensrt()                                  # loads LIBRARY (below)
    lens = rt.analytic(focal_length_mm=50, sensor_distance_mm=50)
    img = rt.render(lens, width=64, height=64, width_mm=0.05, f_number=8,
                    wavelengths=[550], samples=1 << 16)   # numpy (n_wl, height, width)

Every failing call raises LensrtError with the library's message.

Which shared library Lensrt() loads (``find_library()``, once at import as ``LIBRARY``;
``Lensrt(library=...)`` overrides it), the first of:

1. ``$LENSRT_LIBRARY``, when set (another build; an error if that file is missing);
2. ``liblensrt.so`` inside the installed package ``lensrt`` (``<site-packages>/lensrt/``),
   which ``pip install runtime/python`` builds into the wheel (scikit-build-core);
3. in a source checkout (this file at ``runtime/python/``), the build tree's
   ``build/runtime/runtime/liblensrt.so`` that ``make runtime`` builds: what the editable
   install of ``make setup`` uses.

When none exists, LIBRARY is the path that was expected (the checkout's build tree, else
the package's) and Lensrt() raises FileNotFoundError naming every place searched.
"""

from __future__ import annotations

import ctypes as C
import enum
import math
import os
import zlib
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

LIBRARY_ENV = "LENSRT_LIBRARY"
LIBRARY_NAME = "liblensrt.so"
# The library a wheel installs: <site-packages>/lensrt/liblensrt.so (runtime/python/CMakeLists.txt)
PACKAGE_LIBRARY = Path(__file__).resolve().parent / "lensrt" / LIBRARY_NAME
# The repository root when this file is runtime/python/lensrt_ctypes.py of a checkout
ROOT = Path(__file__).resolve().parents[2]
IN_CHECKOUT = (ROOT / "runtime" / "python" / "pyproject.toml").is_file()
DEFAULT_LIBRARY = ROOT / "build" / "runtime" / "runtime" / LIBRARY_NAME  # `make runtime`'s


def library_candidates() -> list[tuple[Path, str]]:
    """The places the library lookup tries, in order, each with the setting it came from
    (the module docstring's rule)."""
    env = os.environ.get(LIBRARY_ENV)
    if env:
        return [(Path(env), f"${LIBRARY_ENV}")]
    places = [(PACKAGE_LIBRARY, "the installed package (pip install runtime/python)")]
    if IN_CHECKOUT:
        places.append((DEFAULT_LIBRARY, "the checkout's build tree (make runtime)"))
    return places


def find_library() -> Path:
    """The shared library Lensrt() loads: the first existing place of
    library_candidates(), else the place expected (the checkout's build tree in a checkout,
    else the package's), which does not exist."""
    places = library_candidates()
    for path, _ in places:
        if path.is_file():
            return path
    return places[-1][0]


def library_not_found(path: Path) -> str:
    """The message of a missing library: what was searched and how to get one."""
    tried = [f"{p} ({how})" for p, how in library_candidates()]
    if str(path) not in {str(p) for p, _ in library_candidates()}:
        tried.insert(0, f"{path} (given)")
    return ("lensrt's shared library not found; looked at " + "; ".join(tried)
            + f". Build it (`make runtime` in a checkout, or `pip install runtime/python`), "
            f"or set ${LIBRARY_ENV} to a liblensrt.so")


# The library Lensrt() loads by default
LIBRARY = find_library()

SAMPLERS = {"default": 0, "random": 1, "stratified": 2, "sobol": 3}
ESTIMATORS = {"default": 0, "paper": 1, "unbiased": 2}
PRECISIONS = {"default": 0, "double": 1, "naive_float": 2}
SHAPES = {"circle": 0, "blades": 1, "slit": 2}
DEVICES = {"cpu": 0, "gl": 1}
PIXEL_FILTERS = {"box": 0, "point": 1}
GL_PLATFORMS = {"auto": 0, "egl-device": 1, "egl-surfaceless": 2, "glfw": 3, "caller": 4}


CELLS_FIRST_RINGS = 8  # the cells integrator's first mesh in integrate_to
CELLS_MAX_RINGS = 512
FOURIER_FIRST_NODES = 0  # integrate_fourier_to's first rule: 0, the library's choice
FOURIER_MAX_NODES = 2048
FOURIER_REFINE = 1.25  # lensrt.h LENSRT_FOURIER_FINER: the estimate's finer rule, per side


def next_rings(rings: int, estimate: float, target: float) -> int:
    """The mesh that should bring a cells estimate to the target, the error falling as
    1 / rings^2: rings sqrt(estimate / target) with 10% to spare, 1.25 to 2 times rings
    (doubling reuses the previous meshes for the estimate, so it costs no more than
    1.6 times)."""
    factor = min(2.0, max(1.25, 1.1 * math.sqrt(estimate / target)))
    return 2 * rings if factor > 1.6 else int(math.ceil(rings * factor))


class Result(enum.IntEnum):
    """lensrt_result, in the header's order (LENSRT_SUCCESS, LENSRT_ERROR_...)."""
    SUCCESS = 0
    INVALID_ARGUMENT = 1
    OUT_OF_MEMORY = 2
    IO = 3
    PARSE = 4
    OUT_OF_DOMAIN = 5
    INCOMPATIBLE = 6
    UNSUPPORTED = 7
    CANCELLED = 8
    NO_DEVICE = 9
    DEVICE = 10


NO_DEVICE = Result.NO_DEVICE


class LensrtError(RuntimeError):
    def __init__(self, code: int, message: str) -> None:
        super().__init__(message)
        self.code = code


class TargetNotReached(RuntimeError):
    """Render.integrate_auto_to: no integrator reached the target error within its limits
    (the render's sums hold the last attempt; do not use them as the result)."""


class Versioned(C.Structure):
    """A struct of lensrt.h's ABI rules: struct_size first, set here to this layout's size
    (what the LENSRT_*_INIT macros do in C)."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        # Positional arguments are the fields after struct_size
        super().__init__(C.sizeof(type(self)), *args, **kwargs)


class ContextInit(Versioned):
    _fields_ = [("struct_size", C.c_size_t), ("alloc_fn", C.c_void_p), ("free_fn", C.c_void_p),
                ("log_fn", C.c_void_p),
                ("user_data", C.c_void_p), ("threads", C.c_int32), ("gl_platform", C.c_int32)]


class GlInfo(Versioned):
    _fields_ = [("struct_size", C.c_size_t), ("platform", C.c_char_p), ("renderer", C.c_char_p),
                ("version", C.c_char_p),
                ("software", C.c_int32)]


class AnalyticLens(Versioned):
    _fields_ = [("struct_size", C.c_size_t), ("focal_length_mm", C.c_double),
                ("sensor_distance_mm", C.c_double),
                ("one_dimensional", C.c_int32)]


class LensInfo(Versioned):
    _fields_ = [("struct_size", C.c_size_t), ("name", C.c_char_p), ("analytic", C.c_int32),
                ("focal_length_mm", C.c_double),
                ("f_number_min", C.c_double), ("stop_radius_max_mm", C.c_double),
                ("wavelength_min_nm", C.c_double), ("wavelength_max_nm", C.c_double),
                ("focus_offset_min_mm", C.c_double), ("focus_offset_max_mm", C.c_double),
                ("field_x", C.c_double), ("field_y", C.c_double),
                ("distance_min_mm", C.c_double), ("sensor_radius_mm", C.c_double),
                ("psf_vs_exact", C.c_double), ("psf_target", C.c_double),
                ("psf_vs_exact_cell", C.c_char_p),
                # ghost tables (issue 13); a library before them leaves these zero
                ("ghost", C.c_int32), ("ghost_first", C.c_int32), ("ghost_second", C.c_int32),
                ("ghost_label", C.c_char_p), ("ghost_clip_pairs", C.c_int32)]


class Aperture(C.Structure):
    _fields_ = [("shape", C.c_int32), ("radius_mm", C.c_double), ("f_number", C.c_double),
                ("blades", C.c_int32), ("blade_curvature", C.c_double),
                ("rotation_deg", C.c_double), ("slit_width_mm", C.c_double),
                ("slit_separation_mm", C.c_double)]


class Sensor(C.Structure):
    _fields_ = [("width", C.c_int32), ("height", C.c_int32), ("width_mm", C.c_double),
                ("height_mm", C.c_double), ("center_x_mm", C.c_double),
                ("center_y_mm", C.c_double), ("focus_offset_mm", C.c_double)]


class Light(Versioned):
    """(field_x_deg, field_y_deg, distance_mm, intensity): field angles of the chief ray,
    the designers' convention (lensrt.h, lensrt_light): +field_y is imaged at +y."""

    _fields_ = [("struct_size", C.c_size_t), ("field_x_deg", C.c_double),
                ("field_y_deg", C.c_double),
                ("distance_mm", C.c_double), ("intensity", C.c_double)]


class RenderDesc(Versioned):
    _fields_ = [("struct_size", C.c_size_t), ("lens", C.c_void_p), ("sensor", Sensor),
                ("aperture", Aperture), ("lights", C.POINTER(Light)), ("n_lights", C.c_int32),
                ("wavelengths_nm", C.POINTER(C.c_double)), ("n_wavelengths", C.c_int32),
                ("sampler", C.c_int32), ("estimator", C.c_int32), ("precision", C.c_int32),
                ("seed", C.c_uint64), ("phase_tolerance_waves", C.c_double),
                ("device", C.c_int32),
                # 0.8.0 (issue 26): the pixel filter and its sub-pixel samples per axis
                ("pixel_filter", C.c_int32), ("pixel_samples_x", C.c_int32),
                ("pixel_samples_y", C.c_int32)]


class Stats(Versioned):
    _fields_ = [("struct_size", C.c_size_t), ("width", C.c_int32), ("height", C.c_int32),
                ("n_wavelengths", C.c_int32), ("n_lights", C.c_int32),
                ("samples_per_wavelength", C.c_uint64),
                ("splats", C.c_uint64), ("seconds", C.c_double),
                ("splats_per_second", C.c_double), ("stop_radius_mm", C.c_double),
                ("f_number", C.c_double), ("phase_terms", C.c_double),
                ("clip_fraction", C.c_double), ("tau_fraction", C.c_double),
                ("dark_fraction", C.c_double),
                ("cells_rings", C.c_int32), ("cells_error_estimate", C.c_double),
                ("fourier_nodes", C.c_int32),
                ("pixel_filter", C.c_int32), ("pixel_samples_x", C.c_int32),
                ("pixel_samples_y", C.c_int32)]


class Render:
    """A render: run() adds samples, image() resolves the intensities."""

    def __init__(self, rt: Lensrt, handle: C.c_void_p, keep: list[Any]) -> None:
        self.rt, self.handle, self._keep = rt, handle, keep

    def __del__(self) -> None:
        if getattr(self, "handle", None):
            self.rt._destroy_render(self.handle)
            self.handle = None

    def run(self, samples_per_wavelength: int) -> None:
        lib = self.rt.lib
        self.rt._check(lib.lensrt_render_run(self.handle, C.c_uint64(samples_per_wavelength),
                                             None, None))

    def integrate(self, rings: int, estimate: bool = True) -> float | None:
        """The cells integrator (lensrt_render_integrate): the sums become the field of a
        mesh of `rings` rings; returns the image's estimated relative L2 error (None when
        not asked for)."""
        err = C.c_double(-1.0)
        self.rt._check(self.rt.lib.lensrt_render_integrate(
            self.handle, C.c_int32(rings), C.byref(err) if estimate else None, None, None))
        return err.value if estimate else None

    def integrate_to(self, target: float, first_rings: int = CELLS_FIRST_RINGS,
                     max_rings: int = CELLS_MAX_RINGS) -> tuple[int, float]:
        """Refine the cells mesh until the error estimate is within ``target`` (or the next
        mesh would pass ``max_rings``); the rings and the estimate of the last mesh."""
        rings = first_rings
        est = self.integrate(rings)
        assert est is not None
        while est > target and next_rings(rings, est, target) <= max_rings:
            rings = next_rings(rings, est, target)
            est = self.integrate(rings)
            assert est is not None
        return rings, float(est)

    def integrate_fourier(self, nodes: int, estimate: bool = True) -> float | None:
        """The Fourier integrator (lensrt_render_integrate_fourier, 0.6.0): the sums become
        the field of a Gauss rule of ``nodes`` per side; returns the image's estimated
        relative L2 error (None when not asked for). A clip cutting the aperture raises
        LensrtError with Result.UNSUPPORTED (integrate() resolves clips)."""
        fn = _need(self.rt.lib, "lensrt_render_integrate_fourier")
        fn.argtypes = [C.c_void_p, C.c_int32, C.POINTER(C.c_double), C.c_void_p, C.c_void_p]
        err = C.c_double(-1.0)
        self.rt._check(fn(self.handle, C.c_int32(nodes), C.byref(err) if estimate else None,
                          None, None))
        return err.value if estimate else None

    def fourier_nodes(self, target: float = 0.0) -> int:
        """The nodes per side the library chooses for an image of relative L2 error
        ``target`` (lensrt_render_fourier_nodes, 0.7.0; 0: the rule of nodes 0)."""
        fn = _need(self.rt.lib, "lensrt_render_fourier_nodes")
        fn.argtypes = [C.c_void_p, C.c_double, C.POINTER(C.c_int32)]
        n = C.c_int32(0)
        self.rt._check(fn(self.handle, C.c_double(target), C.byref(n)))
        return int(n.value)

    def footprint(self) -> tuple[float, float, float, float]:
        """(x_min, x_max, y_min, y_max) in mm of where the render's rays land on the sensor
        (lensrt_render_footprint, 0.10.0); x_min > x_max when no ray passes the clips."""
        fn = _need(self.rt.lib, "lensrt_render_footprint", "0.10.0")
        fn.argtypes = [C.c_void_p, C.POINTER(C.c_double)]
        box = (C.c_double * 4)()
        self.rt._check(fn(self.handle, box))
        return (box[0], box[1], box[2], box[3])

    def integrate_fourier_to(self, target: float, first_nodes: int = FOURIER_FIRST_NODES,
                             max_nodes: int = FOURIER_MAX_NODES) -> tuple[int, float]:
        """Refine the Fourier rule (nodes x 1.25 a step, each reusing the last step's finer
        rule) until the estimate is within ``target`` or the next rule would pass
        ``max_nodes``; the nodes and estimate of the image the sums hold. ``first_nodes``
        0: the library's choice for the target (fourier_nodes)."""
        est = self.integrate_fourier(first_nodes or self.fourier_nodes(target))
        assert est is not None
        nodes = int(self.stats().fourier_nodes)
        def finer(n: int) -> int:
            return math.ceil(FOURIER_REFINE * n)

        while est > target and finer(finer(nodes)) <= max_nodes:
            nodes = finer(nodes)
            est = self.integrate_fourier(nodes)
            assert est is not None
        return nodes, float(est)

    def integrate_auto_to(self, target: float, max_nodes: int = FOURIER_MAX_NODES,
                          max_rings: int = CELLS_MAX_RINGS) -> tuple[str, int, float]:
        """The Fourier integrator to ``target`` (integrate_fourier_to), or where a clip cuts
        the aperture (it refuses: Result.UNSUPPORTED) or its estimate stays above the
        target, the cells integrator (integrate_to): ("fourier", nodes, estimate) or
        ("cells", rings, estimate). Never keeps an image whose estimate misses the target
        (issue 39): raises TargetNotReached, saying what each integrator gave."""
        said = ""
        try:
            nodes, est = self.integrate_fourier_to(target, max_nodes=max_nodes)
            if est <= target:
                return "fourier", nodes, est
            said = f"Fourier {est:.3g} at {nodes} nodes, "
        except LensrtError as e:
            if e.code != Result.UNSUPPORTED:
                raise
        rings, est = self.integrate_to(target, max_rings=max_rings)
        if est <= target:
            return "cells", rings, est
        raise TargetNotReached(f"the auto integrator did not reach the target error {target:.3g} "
                               f"({said}cells {est:.3g} at {rings} rings, max_rings {max_rings})")

    def splat_points(self, xy_mm: np.ndarray, wavelength: int = 0) -> None:
        xy = np.ascontiguousarray(xy_mm, dtype=np.float64)
        self.rt._check(self.rt.lib.lensrt_render_splat_points(
            self.handle, wavelength, xy.ctypes.data_as(C.POINTER(C.c_double)), C.c_size_t(len(xy))))

    def stats(self) -> Stats:
        st = Stats()
        self.rt._check(self.rt.lib.lensrt_render_get_stats(self.handle, C.byref(st)))
        return st

    def image(self) -> np.ndarray:
        st = self.stats()
        out = np.zeros((st.n_wavelengths, st.height, st.width), dtype=np.float32)
        self.rt._check(self.rt.lib.lensrt_render_image(
            self.handle, out.ctypes.data_as(C.POINTER(C.c_float)), C.c_size_t(out.size)))
        return out

    def rgb(self) -> np.ndarray:
        st = self.stats()
        out = np.zeros((st.height, st.width, 3), dtype=np.float32)
        self.rt._check(self.rt.lib.lensrt_render_rgb(
            self.handle, out.ctypes.data_as(C.POINTER(C.c_float)), C.c_size_t(out.size)))
        return out

    def save(self, path: str | os.PathLike[str]) -> None:
        self.rt._check(self.rt.lib.lensrt_render_save(self.handle, os.fsencode(path)))

    def load(self, path: str | os.PathLike[str]) -> None:
        self.rt._check(self.rt.lib.lensrt_render_load(self.handle, os.fsencode(path)))

    def merge(self, path: str | os.PathLike[str]) -> None:
        self.rt._check(self.rt.lib.lensrt_render_merge(self.handle, os.fsencode(path)))

    def write_exr(self, path: str | os.PathLike[str]) -> None:
        self.rt._check(self.rt.lib.lensrt_render_write_exr(self.handle, os.fsencode(path)))

    def write_png(self, path: str | os.PathLike[str], decades: float = 0.0) -> None:
        self.rt._check(self.rt.lib.lensrt_render_write_png(self.handle, os.fsencode(path),
                                                           C.c_double(decades)))


class Lensrt:
    """One lensrt context (and the library it came from)."""

    def __init__(self, library: str | os.PathLike[str] | None = None, threads: int = 0,
                 gl_platform: str = "auto") -> None:
        path = Path(library or LIBRARY)
        if not path.exists():
            raise FileNotFoundError(library_not_found(path))
        lib = C.CDLL(str(path))
        self.lib = lib
        lib.lensrt_result_string.restype = C.c_char_p
        lib.lensrt_context_last_error.restype = C.c_char_p
        lib.lensrt_version_string.restype = C.c_char_p
        lib.lensrt_context_last_error.argtypes = [C.c_void_p]
        lib.lensrt_context_create.argtypes = [C.POINTER(ContextInit), C.POINTER(C.c_void_p)]
        lib.lensrt_context_destroy.argtypes = [C.c_void_p]
        lib.lensrt_lens_load.argtypes = [C.c_void_p, C.c_char_p, C.POINTER(C.c_void_p)]
        lib.lensrt_lens_create_analytic.argtypes = [C.c_void_p, C.POINTER(AnalyticLens),
                                                    C.POINTER(C.c_void_p)]
        lib.lensrt_lens_destroy.argtypes = [C.c_void_p, C.c_void_p]
        lib.lensrt_lens_get_info.argtypes = [C.c_void_p, C.POINTER(LensInfo)]
        lib.lensrt_lens_image_point.argtypes = [C.c_void_p, C.c_void_p, C.POINTER(Light),
                                                C.c_double, C.c_double, C.POINTER(C.c_double)]
        if hasattr(lib, "lensrt_light_direction_cosines"):  # not in libraries before it
            lib.lensrt_light_direction_cosines.argtypes = [C.c_void_p, C.POINTER(Light),
                                                           C.POINTER(C.c_double)]
        lib.lensrt_render_create.argtypes = [C.c_void_p, C.POINTER(RenderDesc),
                                             C.POINTER(C.c_void_p)]
        lib.lensrt_render_destroy.argtypes = [C.c_void_p]
        lib.lensrt_render_run.argtypes = [C.c_void_p, C.c_uint64, C.c_void_p, C.c_void_p]
        lib.lensrt_render_splat_points.argtypes = [C.c_void_p, C.c_int, C.POINTER(C.c_double),
                                                   C.c_size_t]
        if hasattr(lib, "lensrt_render_integrate"):  # lensrt 0.4.0 and later
            lib.lensrt_render_integrate.argtypes = [C.c_void_p, C.c_int32, C.POINTER(C.c_double),
                                                    C.c_void_p, C.c_void_p]
        lib.lensrt_render_get_stats.argtypes = [C.c_void_p, C.POINTER(Stats)]
        lib.lensrt_render_image.argtypes = [C.c_void_p, C.POINTER(C.c_float), C.c_size_t]
        lib.lensrt_render_rgb.argtypes = [C.c_void_p, C.POINTER(C.c_float), C.c_size_t]
        for name in ("save", "load", "merge", "write_exr"):
            getattr(lib, f"lensrt_render_{name}").argtypes = [C.c_void_p, C.c_char_p]
        lib.lensrt_render_write_png.argtypes = [C.c_void_p, C.c_char_p, C.c_double]
        lib.lensrt_context_gl_info.argtypes = [C.c_void_p, C.POINTER(GlInfo)]
        init = ContextInit(threads=threads, gl_platform=GL_PLATFORMS[gl_platform])
        ctx = C.c_void_p()
        code = lib.lensrt_context_create(C.byref(init), C.byref(ctx))
        if code != 0:
            raise LensrtError(code, lib.lensrt_result_string(code).decode())
        self.ctx = ctx
        self._lenses: list[C.c_void_p] = []
        self._renders: dict[int, C.c_void_p] = {}  # live renders by address

    def __del__(self) -> None:
        # The garbage collector finalises a cycle's objects in any order, so this may run
        # before the __del__ of a Render made here: renders go first, then lenses, since
        # lensrt_context_destroy must come last (render destruction uses the context)
        if getattr(self, "ctx", None):
            for handle in self._renders.values():
                self.lib.lensrt_render_destroy(handle)
            self._renders.clear()
            for lens in self._lenses:
                self.lib.lensrt_lens_destroy(self.ctx, lens)
            self.lib.lensrt_context_destroy(self.ctx)
            self.ctx = None

    def _destroy_render(self, handle: C.c_void_p) -> None:
        # Already destroyed with the context when the context went first
        if self._renders.pop(handle.value, None) is not None:
            self.lib.lensrt_render_destroy(handle)

    def _check(self, code: int) -> None:
        if code != 0:
            message = self.lib.lensrt_context_last_error(self.ctx).decode()
            raise LensrtError(code, message or self.lib.lensrt_result_string(code).decode())

    def version(self) -> str:
        """The loaded library's version ("0.8.0"), lensrt_version_string()."""
        return self.lib.lensrt_version_string().decode()

    def gl_info(self) -> dict[str, Any]:
        """The context's GL device (made on first use); LensrtError(NO_DEVICE) without one."""
        info = GlInfo()
        self._check(self.lib.lensrt_context_gl_info(self.ctx, C.byref(info)))
        return {"platform": info.platform.decode(), "renderer": info.renderer.decode(),
                "version": info.version.decode(), "software": bool(info.software)}

    def load(self, table: str | os.PathLike[str]) -> C.c_void_p:
        lens = C.c_void_p()
        self._check(self.lib.lensrt_lens_load(self.ctx, os.fsencode(table), C.byref(lens)))
        self._lenses.append(lens)
        return lens

    def analytic(self, *, sensor_distance_mm: float, focal_length_mm: float = 0.0,
                 one_dimensional: bool = False) -> C.c_void_p:
        desc = AnalyticLens(focal_length_mm, sensor_distance_mm, int(one_dimensional))
        lens = C.c_void_p()
        self._check(self.lib.lensrt_lens_create_analytic(self.ctx, C.byref(desc), C.byref(lens)))
        self._lenses.append(lens)
        return lens

    def info(self, lens: C.c_void_p) -> dict[str, Any]:
        info = LensInfo()
        self._check(self.lib.lensrt_lens_get_info(lens, C.byref(info)))
        d = {name: getattr(info, name) for name, _ in LensInfo._fields_}
        d["name"] = d["name"].decode()
        d["psf_vs_exact_cell"] = (d["psf_vs_exact_cell"] or b"").decode()
        d["ghost_label"] = (d["ghost_label"] or b"").decode()
        return d

    def image_point(self, lens: C.c_void_p, light: Sequence[float], wavelength_nm: float,
                    focus_offset_mm: float = 0.0) -> tuple[float, float]:
        xy = (C.c_double * 2)()
        lt = Light(*light)  # fields not given are zero
        self._check(self.lib.lensrt_lens_image_point(self.ctx, lens, C.byref(lt), wavelength_nm,
                                                     focus_offset_mm, xy))
        return xy[0], xy[1]

    def light_direction_cosines(self, light: Sequence[float]) -> tuple[float, float]:
        """P_o's (x_O, y_O) for a light (field angles in degrees, as for image_point)."""
        xy = (C.c_double * 2)()
        lt = Light(*light)
        self._check(self.lib.lensrt_light_direction_cosines(self.ctx, C.byref(lt), xy))
        return xy[0], xy[1]

    def create(self, lens: C.c_void_p, *, width: int, height: int, width_mm: float,
               height_mm: float = 0.0, center: tuple[float, float] = (0.0, 0.0),
               focus_offset_mm: float = 0.0, f_number: float = 0.0, radius_mm: float = 0.0,
               shape: str = "circle", blades: int = 0, blade_curvature: float = 0.0,
               rotation_deg: float = 0.0, slit_width_mm: float = 0.0,
               slit_separation_mm: float = 0.0, lights: Sequence[Sequence[float]] = (),
               wavelengths: Sequence[float] | int = 0, sampler: str = "default",
               estimator: str = "default", precision: str = "default", seed: int = 0,
               phase_tolerance_waves: float = 0.0, device: str = "cpu",
               pixel_filter: str = "box", pixel_samples: int | tuple[int, int] = 0) -> Render:
        """A render (lensrt_render_create). ``pixel_filter`` "box" (default: each pixel the
        mean intensity over its area, on ``pixel_samples`` sub-pixel points per axis, an int
        or (x, y); 0: chosen, README "The model") or "point" (the pixel centre's intensity,
        as before 0.8.0)."""
        keep: list[Any] = []
        desc = RenderDesc()
        desc.lens = lens
        desc.sensor = Sensor(width, height, width_mm, height_mm, center[0], center[1],
                             focus_offset_mm)
        desc.aperture = Aperture(SHAPES[shape], radius_mm, f_number, blades, blade_curvature,
                                 rotation_deg, slit_width_mm, slit_separation_mm)
        if lights:
            arr = (Light * len(lights))(*[Light(*x) for x in lights])
            keep.append(arr)
            desc.lights = arr
            desc.n_lights = len(lights)
        if isinstance(wavelengths, int):
            desc.n_wavelengths = wavelengths
        else:
            wl = (C.c_double * len(wavelengths))(*wavelengths)
            keep.append(wl)
            desc.wavelengths_nm = wl
            desc.n_wavelengths = len(wavelengths)
        desc.sampler = SAMPLERS[sampler]
        desc.estimator = ESTIMATORS[estimator]
        desc.precision = PRECISIONS[precision]
        desc.seed = seed
        desc.phase_tolerance_waves = phase_tolerance_waves
        desc.device = DEVICES[device]
        desc.pixel_filter = PIXEL_FILTERS[pixel_filter]
        psx, psy = ((pixel_samples, pixel_samples) if isinstance(pixel_samples, int)
                    else pixel_samples)
        desc.pixel_samples_x, desc.pixel_samples_y = psx, psy
        handle = C.c_void_p()
        self._check(self.lib.lensrt_render_create(self.ctx, C.byref(desc), C.byref(handle)))
        self._renders[handle.value] = handle
        return Render(self, handle, keep)

    def render(self, lens: C.c_void_p, *, samples: int, **kwargs: Any) -> np.ndarray:
        r = self.create(lens, **kwargs)
        r.run(samples)
        return r.image()

    def integrate(self, lens: C.c_void_p, *, rings: int, **kwargs: Any) -> tuple[np.ndarray, float]:
        """The image by the cells integrator and its error estimate."""
        r = self.create(lens, **kwargs)
        err = r.integrate(rings)
        assert err is not None
        return r.image(), err

    def write_exr_layers(self, path: str | os.PathLike[str],
                         layers: dict[str, Sequence[Render]], reproducible: bool = False
                         ) -> None:
        """One EXR with a layer per name (its renders' images added) and their sum in the
        unprefixed channels (lensrt_layers_write_exr; read with lensrt_exr); with
        ``reproducible``, without what differs between runs (lensrt_layers_write_exr_with,
        0.5.0), so the same renders give the same bytes."""
        extra: list[Any] = []
        if reproducible:
            fn = _need(self.lib, "lensrt_layers_write_exr_with")
            fn.argtypes = [C.POINTER(ExrLayer), C.c_int, C.c_char_p, C.POINTER(ExrOptions)]
            extra = [C.byref(ExrOptions(1))]
        else:
            fn = self.lib.lensrt_layers_write_exr
            fn.argtypes = [C.POINTER(ExrLayer), C.c_int, C.c_char_p]
        keep = []
        arr = (ExrLayer * len(layers))()
        for k, (name, renders) in enumerate(layers.items()):
            handles = (C.c_void_p * len(renders))(*[r.handle for r in renders])
            keep.append(handles)
            arr[k] = ExrLayer(name.encode(), C.cast(handles, C.c_void_p), len(renders))
        self._check(fn(arr, len(layers), os.fsencode(path), *extra))

    def spectrum_rgb(self, wavelengths_nm: Sequence[float], spectral: np.ndarray) -> np.ndarray:
        """Linear sRGB (height, width, 3) of a spectral image (n_wavelengths, height,
        width), as lensrt_render_rgb converts a render's (lensrt_spectrum_rgb, 0.9.0)."""
        fn = _need(self.lib, "lensrt_spectrum_rgb", "0.9.0")
        fn.argtypes = [C.c_void_p, C.c_int, C.POINTER(C.c_double), C.POINTER(C.c_float),
                       C.c_size_t, C.POINTER(C.c_float)]
        planes = np.ascontiguousarray(spectral, dtype=np.float32)
        if planes.ndim != 3 or planes.shape[0] != len(wavelengths_nm):
            raise ValueError(f"spectrum_rgb: expected ({len(wavelengths_nm)}, height, width) "
                             f"values, got {planes.shape}")
        lam = np.ascontiguousarray(wavelengths_nm, dtype=np.float64)
        out = np.zeros(planes.shape[1:] + (3,), dtype=np.float32)
        self._check(fn(self.ctx, len(lam), lam.ctypes.data_as(C.POINTER(C.c_double)),
                       planes.ctypes.data_as(C.POINTER(C.c_float)),
                       C.c_size_t(planes.shape[1] * planes.shape[2]),
                       out.ctypes.data_as(C.POINTER(C.c_float))))
        return out

    # ------------------------------------------------- per-ray evaluation -----

    def _eval_functions(self) -> None:
        lib = self.lib
        if getattr(self, "_eval_ready", False):
            return
        lib.lensrt_lens_system_info.argtypes = [C.c_void_p, C.c_int32, C.POINTER(SystemInfo)]
        lib.lensrt_lens_eval.argtypes = [C.c_void_p, C.c_void_p, C.POINTER(EvalDesc)]
        self._eval_ready = True

    def system_info(self, lens: C.c_void_p, system: str | int) -> dict[str, Any]:
        """Names, fitted domain and term counts of a lens's P_o or P_s."""
        self._eval_functions()
        info = SystemInfo()
        code = self.lib.lensrt_lens_system_info(lens, SYSTEMS.get(system, system), C.byref(info))
        if code != 0:
            raise LensrtError(code, self.lib.lensrt_result_string(code).decode())
        n_in, n_out = info.n_inputs, info.n_outputs
        return {"inputs": [info.input_names[i].decode() for i in range(n_in)],
                "outputs": [info.output_names[o].decode() for o in range(n_out)],
                "min": [info.input_min[i] for i in range(n_in)],
                "max": [info.input_max[i] for i in range(n_in)],
                "terms": [info.n_terms[o] for o in range(n_out)]}

    def eval(self, lens: C.c_void_p, system: str | int, inputs: np.ndarray, jacobians: bool = False,
             dtype: Any = np.float64, context: bool = True
             ) -> np.ndarray | tuple[np.ndarray, np.ndarray]:
        """lensrt_lens_eval on raw inputs (n_rays, 6): outputs (n_rays, 4), and with
        ``jacobians`` also d output / d input (n_rays, 4, 6), all of ``dtype`` (float64 or
        float32). Without ``context`` no message is recorded (ctx NULL). The GIL is
        released during the call (ctypes), so threads evaluate in parallel."""
        self._eval_functions()
        dt = np.dtype(dtype)
        if dt not in (np.dtype(np.float64), np.dtype(np.float32)):
            raise TypeError(f"eval: dtype must be float64 or float32, got {dt}")
        sys_id = SYSTEMS.get(system, system)
        info = self.system_info(lens, sys_id)
        n_in, n_out = len(info["inputs"]), len(info["outputs"])
        x = np.ascontiguousarray(inputs, dtype=dt).reshape(-1, n_in)
        out = np.empty((len(x), n_out), dtype=dt)
        jac = np.empty((len(x), n_out, n_in), dtype=dt) if jacobians else None
        desc = EvalDesc(sys_id, NUMBER_TYPES[dt.name], len(x), x.ctypes.data, out.ctypes.data,
                        jac.ctypes.data if jac is not None else None)
        code = self.lib.lensrt_lens_eval(self.ctx if context else None, lens, C.byref(desc))
        if code != 0:
            message = self.lib.lensrt_context_last_error(self.ctx).decode() if context else ""
            raise LensrtError(code, message or self.lib.lensrt_result_string(code).decode())
        return (out, jac) if jac is not None else out


# Per-ray evaluation (lensrt.h "per-ray evaluation")
SYSTEMS = {"P_o": 0, "object": 0, "P_s": 1, "sensor": 1, "P_clip": 2, "clip": 2}
NUMBER_TYPES = {"float64": 0, "float32": 1}
MAX_SYSTEM_INPUTS = 8
MAX_SYSTEM_OUTPUTS = 8


class ExrLayer(Versioned):
    _fields_ = [("struct_size", C.c_size_t), ("name", C.c_char_p), ("renders", C.c_void_p),
                ("n_renders", C.c_int32)]


class SystemInfo(Versioned):
    _fields_ = [("struct_size", C.c_size_t), ("n_inputs", C.c_int32), ("n_outputs", C.c_int32),
                ("input_names", C.c_char_p * MAX_SYSTEM_INPUTS),
                ("output_names", C.c_char_p * MAX_SYSTEM_OUTPUTS),
                ("input_min", C.c_double * MAX_SYSTEM_INPUTS),
                ("input_max", C.c_double * MAX_SYSTEM_INPUTS),
                ("n_terms", C.c_int32 * MAX_SYSTEM_OUTPUTS)]


class EvalDesc(Versioned):
    _fields_ = [("struct_size", C.c_size_t), ("system", C.c_int32), ("type", C.c_int32),
                ("n_rays", C.c_size_t), ("inputs", C.c_void_p), ("outputs", C.c_void_p),
                ("jacobians", C.c_void_p)]


# ---------------------------------------------------------------- PSF banks -----
# (lensrt 0.5.0, issue 23: lensrt.h "PSF banks"; reproducible EXRs for a bank's nodes)


class ExrOptions(Versioned):
    _fields_ = [("struct_size", C.c_size_t), ("reproducible", C.c_int32)]


class BankInfo(Versioned):
    _fields_ = [("struct_size", C.c_size_t), ("lens_name", C.c_char_p),
                ("table_crc32", C.c_uint32), ("width", C.c_int32), ("height", C.c_int32),
                ("pixel_x_mm", C.c_double), ("pixel_y_mm", C.c_double),
                ("n_wavelengths", C.c_int32), ("wavelengths_nm", C.POINTER(C.c_double)),
                ("n_f_numbers", C.c_int32), ("f_numbers", C.POINTER(C.c_double)),
                ("n_focus_offsets", C.c_int32), ("focus_offsets_mm", C.POINTER(C.c_double)),
                ("n_distances", C.c_int32), ("distances_mm", C.POINTER(C.c_double)),
                ("n_field_x", C.c_int32), ("field_x_deg", C.POINTER(C.c_double)),
                ("n_field_y", C.c_int32), ("field_y_deg", C.POINTER(C.c_double)),
                ("n_nodes", C.c_int32), ("worst_error_estimate", C.c_double)]


class BankQuery(Versioned):
    _fields_ = [("struct_size", C.c_size_t), ("field_x_deg", C.c_double),
                ("field_y_deg", C.c_double), ("wavelength_nm", C.c_double),
                ("f_number", C.c_double), ("focus_offset_mm", C.c_double),
                ("distance_mm", C.c_double), ("chief_given", C.c_int32),
                ("chief_x_mm", C.c_double), ("chief_y_mm", C.c_double)]


def _need(lib: Any, name: str, since: str = "0.5.0") -> Any:
    """The library's function `name`, or LensrtError(UNSUPPORTED) for a library before it."""
    if not hasattr(lib, name):
        raise LensrtError(Result.UNSUPPORTED,
                          f"{name}: this lensrt library predates it ({since})")
    return getattr(lib, name)


def write_exr_reproducible(render: Render, path: str | os.PathLike[str]) -> None:
    """The render's EXR without what differs between runs (lensrt/seconds,
    lensrt/splatsPerSecond, lensrt/lensFile): the same render gives the same bytes
    (lensrt_render_write_exr_with, reproducible)."""
    fn = _need(render.rt.lib, "lensrt_render_write_exr_with")
    fn.argtypes = [C.c_void_p, C.c_char_p, C.POINTER(ExrOptions)]
    options = ExrOptions(1)
    render.rt._check(fn(render.handle, os.fsencode(path), C.byref(options)))


class Bank:
    """A PSF bank opened from its index (lensrt_bank_open): ``info()`` says what it holds,
    ``psf()`` the PSF at a field point and wavelength. Close it (or let it go) before its
    Lensrt."""

    def __init__(self, rt: Lensrt, index_path: str | os.PathLike[str]) -> None:
        lib = rt.lib
        _need(lib, "lensrt_bank_open").argtypes = [C.c_void_p, C.c_char_p, C.POINTER(C.c_void_p)]
        lib.lensrt_bank_close.argtypes = [C.c_void_p]
        lib.lensrt_bank_get_info.argtypes = [C.c_void_p, C.POINTER(BankInfo)]
        lib.lensrt_bank_psf.argtypes = [C.c_void_p, C.POINTER(BankQuery), C.POINTER(C.c_float),
                                        C.c_size_t, C.POINTER(C.c_double)]
        self.rt = rt
        self.handle: C.c_void_p | None = None
        handle = C.c_void_p()
        rt._check(lib.lensrt_bank_open(rt.ctx, os.fsencode(index_path), C.byref(handle)))
        self.handle = handle

    def close(self) -> None:
        if getattr(self, "handle", None) and getattr(self.rt, "ctx", None):
            self.rt.lib.lensrt_bank_close(self.handle)
        self.handle = None

    def __del__(self) -> None:
        self.close()

    def __enter__(self) -> Bank:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def load_nodes(self) -> None:
        """Read and check every node's image now (lensrt_bank_load_nodes, 0.9.0); a
        query reads the nodes it needs otherwise."""
        fn = _need(self.rt.lib, "lensrt_bank_load_nodes", "0.9.0")
        fn.argtypes = [C.c_void_p]
        self.rt._check(fn(self.handle))

    def info(self) -> dict[str, Any]:
        """lensrt_bank_info as a dict: lists for the grids, the lens name as str."""
        info = BankInfo()
        self.rt._check(self.rt.lib.lensrt_bank_get_info(self.handle, C.byref(info)))
        d: dict[str, Any] = {"lens_name": info.lens_name.decode(), "table_crc32": info.table_crc32,
                             "width": info.width, "height": info.height,
                             "pixel_x_mm": info.pixel_x_mm, "pixel_y_mm": info.pixel_y_mm,
                             "n_nodes": info.n_nodes,
                             "worst_error_estimate": info.worst_error_estimate}
        grids = (("n_wavelengths", "wavelengths_nm"), ("n_f_numbers", "f_numbers"),
                 ("n_focus_offsets", "focus_offsets_mm"), ("n_distances", "distances_mm"),
                 ("n_field_x", "field_x_deg"), ("n_field_y", "field_y_deg"))
        for count, name in grids:
            d[name] = [getattr(info, name)[i] for i in range(getattr(info, count))]
        return d

    def psf(self, field_x_deg: float, field_y_deg: float, wavelength_nm: float,
            f_number: float = 0.0, focus_offset_mm: float = 0.0, distance_mm: float = 0.0,
            chief_mm: tuple[float, float] | None = None
            ) -> tuple[np.ndarray, tuple[float, float]]:
        """The PSF (float32, (height, width), row 0 at +y) on the bank's pixel grid centred
        on the interpolated chief point (or ``chief_mm`` when given: the lens's own,
        lensrt_lens_image_point), and that point (mm)."""
        info = BankInfo()
        self.rt._check(self.rt.lib.lensrt_bank_get_info(self.handle, C.byref(info)))
        out = np.zeros((info.height, info.width), dtype=np.float32)
        chief = (C.c_double * 2)()
        query = BankQuery(field_x_deg, field_y_deg, wavelength_nm, f_number, focus_offset_mm,
                          distance_mm, chief_mm is not None,
                          *(chief_mm if chief_mm is not None else (0.0, 0.0)))
        self.rt._check(self.rt.lib.lensrt_bank_psf(
            self.handle, C.byref(query), out.ctypes.data_as(C.POINTER(C.c_float)),
            C.c_size_t(out.size), chief))
        return out, (chief[0], chief[1])


class ImageDesc(Versioned):
    _fields_ = [("struct_size", C.c_size_t), ("bank", C.c_void_p), ("f_number", C.c_double),
                ("focus_offset_mm", C.c_double), ("distance_mm", C.c_double),
                ("width", C.c_int32), ("height", C.c_int32),
                ("center_x_mm", C.c_double), ("center_y_mm", C.c_double),
                ("focal_x_mm", C.c_double), ("focal_y_mm", C.c_double),
                ("n_channels", C.c_int32), ("channel_weights", C.POINTER(C.c_double)),
                ("ghosts", C.POINTER(C.c_void_p)), ("n_ghosts", C.c_int32),
                ("aperture", Aperture), ("flare_threshold", C.c_double),
                ("max_sources", C.c_int32), ("flare_target_error", C.c_double),
                ("flare_downsample", C.c_int32), ("oversample", C.c_int32),
                ("mirror", C.c_int32)]


IMAGE_MIRROR_X, IMAGE_MIRROR_Y = 1, 2


class ImageStats(Versioned):
    _fields_ = [("struct_size", C.c_size_t), ("seconds_warp", C.c_double),
                ("seconds_kernels", C.c_double), ("seconds_convolve", C.c_double),
                ("seconds_flares", C.c_double), ("n_nodes", C.c_int32),
                ("fft_width", C.c_int32), ("fft_height", C.c_int32),
                ("n_sources", C.c_int32), ("n_ghost_renders", C.c_int32),
                ("worst_flare_error", C.c_double)]


class ImageSource(Versioned):
    _fields_ = [("struct_size", C.c_size_t), ("field_x_deg", C.c_double),
                ("field_y_deg", C.c_double), ("power", C.c_double), ("pixels", C.c_int32)]


IMAGE_DIRECT, IMAGE_FLARE, IMAGE_GHOST = 0, 1, 2


class Image:
    """An image through the lens (lensrt_image_*, 0.11.0): a pinhole framebuffer of
    (n_channels, height, width) float32 through a bank's PSFs (``registration channel``)
    and its lens's ghosts. ``run(input)`` puts one frame through; ``layer(i)`` reads a
    layer back (IMAGE_DIRECT, IMAGE_FLARE, IMAGE_GHOST + g). The bank must outlive the
    image (the image keeps a reference to it)."""

    def __init__(self, bank: Bank, *, width: int, height: int, focal_x_mm: float,
                 focal_y_mm: float = 0.0, center: tuple[float, float] = (0.0, 0.0),
                 f_number: float = 0.0, focus_offset_mm: float = 0.0, distance_mm: float = 0.0,
                 channel_weights: np.ndarray | Sequence[Sequence[float]] | None = None,
                 n_channels: int = 0, ghosts: Sequence[C.c_void_p] = (),
                 aperture: dict[str, Any] | None = None, flare_threshold: float = 0.0,
                 max_sources: int = 0, flare_target_error: float = 0.0,
                 flare_downsample: int = 0, oversample: int = 0, mirror: int = 0) -> None:
        """``channel_weights``: (n_channels, bank wavelengths), or None for one channel per
        bank wavelength; ``aperture``: the ghost renders' (keys of Render's: shape,
        radius_mm, f_number, blades, blade_curvature, rotation_deg, slit_width_mm,
        slit_separation_mm); ``mirror``: IMAGE_MIRROR_X | IMAGE_MIRROR_Y for a bank over
        field >= 0 of a mirror-symmetric lens (0.12.0)."""
        rt = bank.rt
        lib = rt.lib
        _need(lib, "lensrt_image_create", since="0.11.0").argtypes = [
            C.c_void_p, C.POINTER(ImageDesc), C.POINTER(C.c_void_p)]
        lib.lensrt_image_destroy.argtypes = [C.c_void_p]
        lib.lensrt_image_run.argtypes = [C.c_void_p, C.POINTER(C.c_float), C.c_size_t]
        lib.lensrt_image_get_layer.argtypes = [C.c_void_p, C.c_int32, C.POINTER(C.c_float),
                                               C.c_size_t]
        lib.lensrt_image_get_stats.argtypes = [C.c_void_p, C.POINTER(ImageStats)]
        lib.lensrt_image_get_source.argtypes = [C.c_void_p, C.c_int32, C.POINTER(ImageSource)]
        self.rt = rt
        self.bank = bank
        self.handle: C.c_void_p | None = None
        desc = ImageDesc()
        desc.bank = bank.handle
        desc.f_number = f_number
        desc.focus_offset_mm, desc.distance_mm = focus_offset_mm, distance_mm
        desc.width, desc.height = width, height
        desc.center_x_mm, desc.center_y_mm = center
        desc.focal_x_mm, desc.focal_y_mm = focal_x_mm, focal_y_mm
        keep: list[Any] = []
        if channel_weights is None:
            desc.n_channels = n_channels or len(bank.info()["wavelengths_nm"])
        else:
            w = np.ascontiguousarray(channel_weights, dtype=np.float64)
            if w.ndim != 2:
                raise ValueError(f"channel_weights: shape {w.shape}; (n_channels, wavelengths)")
            keep.append(w)
            desc.n_channels = w.shape[0]
            desc.channel_weights = w.ctypes.data_as(C.POINTER(C.c_double))
        if ghosts:
            arr = (C.c_void_p * len(ghosts))(*[g.value if isinstance(g, C.c_void_p) else g
                                               for g in ghosts])
            keep.append(arr)
            desc.ghosts = arr
            desc.n_ghosts = len(ghosts)
        ap = dict(aperture or {})
        desc.aperture = Aperture(SHAPES[ap.get("shape", "circle")], ap.get("radius_mm", 0.0),
                                 ap.get("f_number", 0.0), ap.get("blades", 0),
                                 ap.get("blade_curvature", 0.0), ap.get("rotation_deg", 0.0),
                                 ap.get("slit_width_mm", 0.0), ap.get("slit_separation_mm", 0.0))
        desc.flare_threshold, desc.max_sources = flare_threshold, max_sources
        desc.flare_target_error, desc.flare_downsample = flare_target_error, flare_downsample
        desc.oversample = oversample
        desc.mirror = mirror  # a library before 0.12.0 refuses it when set (struct_size)
        handle = C.c_void_p()
        rt._check(lib.lensrt_image_create(rt.ctx, C.byref(desc), C.byref(handle)))
        self.handle = handle
        self.shape = (int(desc.n_channels), height, width)
        self.n_layers = 2 + len(ghosts)

    @classmethod
    def create(cls, bank: Bank, **kwargs: Any) -> Image:
        """The same as Image(bank, **kwargs)."""
        return cls(bank, **kwargs)

    def close(self) -> None:
        if getattr(self, "handle", None) and getattr(self.rt, "ctx", None):
            self.rt.lib.lensrt_image_destroy(self.handle)
        self.handle = None

    def __del__(self) -> None:
        self.close()

    def __enter__(self) -> Image:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def run(self, frame: np.ndarray) -> None:
        """Put one framebuffer through: float32 (n_channels, height, width), finite, >= 0."""
        a = np.ascontiguousarray(frame, dtype=np.float32)
        if a.shape != self.shape:
            raise ValueError(f"frame: shape {a.shape}; the image takes {self.shape}")
        self.rt._check(self.rt.lib.lensrt_image_run(
            self.handle, a.ctypes.data_as(C.POINTER(C.c_float)), C.c_size_t(a.size)))

    def layer(self, i: int = IMAGE_DIRECT) -> np.ndarray:
        """Layer i of the last run: float32 (n_channels, height, width)."""
        out = np.zeros(self.shape, dtype=np.float32)
        self.rt._check(self.rt.lib.lensrt_image_get_layer(
            self.handle, i, out.ctypes.data_as(C.POINTER(C.c_float)), C.c_size_t(out.size)))
        return out

    def stats(self) -> dict[str, Any]:
        """lensrt_image_stats of the last run as a dict."""
        st = ImageStats()
        self.rt._check(self.rt.lib.lensrt_image_get_stats(self.handle, C.byref(st)))
        return {name: getattr(st, name) for name, _ in ImageStats._fields_
                if name != "struct_size"}

    def sources(self) -> list[dict[str, Any]]:
        """The sources the last run found (brightest first), each a dict."""
        out = []
        for i in range(self.stats()["n_sources"]):
            s = ImageSource()
            self.rt._check(self.rt.lib.lensrt_image_get_source(self.handle, i, C.byref(s)))
            out.append({name: getattr(s, name) for name, _ in ImageSource._fields_
                        if name != "struct_size"})
        return out


# ------------------------------------------------------------------------------------
# A bank from PSFs the caller already has (tests, benchmarks, measured PSFs): the node
# EXRs of a `registration channel` bank (lensrt_exr.write_node_exr) and its stamped index
# (lensrt.h, "PSF banks"). lensfit's own writer (lensfit.banks) renders the PSFs; this
# one only writes them.
# ------------------------------------------------------------------------------------

def write_bank(folder: str | os.PathLike[str], psfs: np.ndarray, chiefs: np.ndarray, *,
               field_x_deg: Sequence[float], field_y_deg: Sequence[float],
               wavelengths_nm: Sequence[float], pixel_mm: float, f_number: float = 8.0,
               lens_name: str = "synthetic") -> Path:
    """A `registration channel` bank of one slice (f_number, focus 0, distance 0) in
    `folder`: psfs (n_field_y, n_field_x, n_wavelengths, height, width), each channel on
    its own chief point chiefs (n_field_y, n_field_x, n_wavelengths, 2) mm, row 0 at +y.
    Returns the index's path."""
    folder = Path(folder)
    (folder / "nodes").mkdir(parents=True, exist_ok=True)
    ny, nx, nl, h, w = psfs.shape
    r = repr

    def grid(key: str, values: Sequence[float]) -> str:
        return " ".join([key, str(len(values)), *(r(float(v)) for v in values)])

    lines = ["lensrt-bank 1", f"lens {lens_name}", "table_crc32 00000000", f"width {w}",
             f"height {h}", f"pixel_mm {r(float(pixel_mm))} {r(float(pixel_mm))}",
             "registration channel", grid("wavelengths_nm", wavelengths_nm),
             grid("f_numbers", [f_number]), "focus_offsets_mm 1 0.0", "distances_mm 1 0.0",
             grid("field_x_deg", field_x_deg), grid("field_y_deg", field_y_deg),
             f"nodes {nx * ny}"]
    for iy in range(ny):
        for ix in range(nx):
            k = iy * nx + ix
            rel = f"nodes/y{iy}-x{ix}.exr"
            identity = (f"0 0 0 {iy} {ix} {r(float(f_number))} 0.0 0.0 "
                        f"{r(float(field_x_deg[ix]))} {r(float(field_y_deg[iy]))}")
            from lensrt_exr import write_node_exr

            write_node_exr(folder / rel, psfs[iy, ix], wavelengths_nm, identity)
            crc = zlib.crc32((folder / rel).read_bytes())
            mid = chiefs[iy, ix, nl // 2]
            lines.append(f"node {k} 0 0 0 {iy} {ix} {r(float(mid[0]))} {r(float(mid[1]))} "
                         f"0.001 {crc:08x} {rel}")
            lines.append(" ".join(["chief", str(k),
                                   *(r(float(v)) for v in chiefs[iy, ix].reshape(-1))]))
    body = "\n".join(lines) + "\n"
    index = folder / "bank.index"
    index.write_text(body + f"checksum crc32 {zlib.crc32(body.encode()):08x}\n")
    return index
