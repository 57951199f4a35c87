"""lensrt's EXR writer against a defect of the OpenEXRCore it builds with (issue 37's note).

OpenEXRCore 3.1-3.4.7 (Debian 12 has 3.1.5) keeps a ZIP chunk whose zlib stream is exactly
as long as its packed pixels as the zlib stream, and readers take a chunk of that size for
raw pixels (OpenEXR issue #2306). Lens 0001's PSF at f/8, field (0, -3.25) deg, 670 nm in
a 48 x 48 window of 80 um on its chief point, 7 curved blades, by the cells integrator to
1% has such a chunk: written, it read back with NaN and -1e38 where the image is finite.
The writer stores such a chunk raw (image_exr.c, compress_or_store): the file reads back
as the render's image bit for bit.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from lensrt_ctypes import LIBRARY, Lensrt, write_exr_reproducible
from lensrt_exr import read_spectral_exr

ROOT = Path(__file__).resolve().parents[2]
TABLE = next((ROOT / "generated").glob("0001*/lens*.table"), None)

pytestmark = pytest.mark.skipif(not LIBRARY.exists() or TABLE is None,
                                reason="needs lensrt (make runtime) and lens 0001's table")


def test_a_chunk_that_does_not_compress_reads_back_exactly(tmp_path: Path) -> None:
    rt = Lensrt(LIBRARY, threads=1)
    lens = rt.load(TABLE)
    light = (0.0, -3.25, 0.0, 1.0)
    chief = rt.image_point(lens, light, 670.0, 0.0)
    r = rt.create(lens, width=48, height=48, width_mm=0.08, height_mm=0.08, center=chief,
                  f_number=8.0, shape="blades", blades=7, blade_curvature=0.5,
                  lights=[light], wavelengths=[670.0])
    r.integrate_to(0.01, max_rings=256)
    image = r.image()
    assert np.isfinite(image).all()
    for name, write in (("reproducible", lambda p: write_exr_reproducible(r, p)),
                        ("plain", r.write_exr)):
        path = tmp_path / f"{name}.exr"
        write(path)
        back = read_spectral_exr(path)
        np.testing.assert_array_equal(back.spectral, image, err_msg=name)
        assert np.isfinite(back.rgb).all()
