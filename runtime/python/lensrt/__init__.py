"""lensrt from Python: ``import lensrt``.

The binding itself is the two modules beside this package, which the repository's tests
and scripts import by name and which keep working as they are:

* ``lensrt_ctypes``: the ctypes binding of the C API (``Lensrt``, ``Render``, ``Bank``);
* ``lensrt_exr``: lensrt's spectral EXR files read with the OpenEXR bindings.

This package re-exports their public names and holds the shared library that
``pip install runtime/python`` builds (``lensrt/liblensrt.so``)::

    import lensrt
    rt = lensrt.Lensrt()                       # lensrt.LIBRARY: which library it loads
    lens = rt.load("generated/0001-angenieux-double-gauss/lens0001.table")
    bank = lensrt.Bank(rt, "build/banks/demo/index.json")

Which library is loaded: ``$LENSRT_LIBRARY``, else the one inside this package, else a
checkout's ``build/runtime/runtime/liblensrt.so`` (lensrt_ctypes's docstring).
"""

from __future__ import annotations

from lensrt_ctypes import (
    LIBRARY,
    LIBRARY_ENV,
    NO_DEVICE,
    PACKAGE_LIBRARY,
    Bank,
    Lensrt,
    LensrtError,
    Render,
    Result,
    TargetNotReached,
    find_library,
    library_candidates,
    write_exr_reproducible,
)
from lensrt_exr import SpectralExr, exr_layers, read_spectral_exr, tone_map

__all__ = [
    "LIBRARY",
    "LIBRARY_ENV",
    "NO_DEVICE",
    "PACKAGE_LIBRARY",
    "Bank",
    "Lensrt",
    "LensrtError",
    "Render",
    "Result",
    "SpectralExr",
    "TargetNotReached",
    "exr_layers",
    "find_library",
    "library_candidates",
    "read_spectral_exr",
    "tone_map",
    "write_exr_reproducible",
]
