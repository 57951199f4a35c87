"""The visibility criterion's direct peak pixel against lensrt's Huygens PSF (issue 26).

`lensfit ghosts` calls a ghost visible when its peak pixel reaches a photograph's black
level, 2^-(overexposure + 8) of the light's own peak pixel
(:mod:`lensfit.ghosts.enumerate`, "Visibility"). The light's peak pixel is estimated from
the enumeration's rays (a histogram in pixel bins, at most the Airy pattern's pixel
average); here it is compared with the brightest pixel of the fitted lens's Huygens PSF
on the same pixels (box filter), which shares nothing with the estimate but the lens.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from lensfit.ghosts.enumerate import DEFAULT_PIXEL_MM, enumerate_ghosts
from lensfit.prescription import load_lens

ROOT = Path(__file__).resolve().parents[2]
TABLES = {"0001": ROOT / "generated" / "0001-angenieux-double-gauss" / "lens0001.table",
          "0009": ROOT / "generated" / "0009-zeiss-biotar" / "lens0009.table"}


@pytest.mark.parametrize("lens_id, f_number", [("0001", 2.0), ("0001", 8.0), ("0001", 16.0),
                                               ("0009", 8.0)])
def test_direct_peak_pixel_against_the_huygens_psf(rt, lens_id, f_number):
    """On the axis at 550 nm, 6 um pixels, one centred on the image point (odd window).
    Bound: within a factor 2 (one stop of visibility) either way. The estimate is
    geometric (4000 rays in pixel bins) and capped by the diffraction limit, so it misses
    diffraction's own spreading of a defocused core (0001 at f/16 sits 0.6 of the
    rendered: a ghost then errs towards visible) and a histogram maximum of few rays
    per bin overstates a little. Measured: 0.60-1.04 (0001 at f/16 and f/2)."""
    info = enumerate_ghosts(load_lens(lens_id), f_number=f_number, pairs=[(0, 2)],
                            wavelengths_nm=(550.0,))[0].info
    # The estimate per unit power: 1/mm^2, as the rendered pixel over the window's power
    estimate = info["direct_pixel_peak"][0] / info["direct_power"][0]
    p, n = DEFAULT_PIXEL_MM, 41
    r = rt.create(rt.load(TABLES[lens_id]), width=n, height=n, width_mm=n * p,
                  f_number=f_number, wavelengths=[550.0], pixel_filter="box")
    r.integrate(16, estimate=False)
    im = r.image().astype(np.float64)
    rendered = im.max() / (im.sum() * p * p)
    print(f"{lens_id} f/{f_number:g}: estimate {estimate:.0f}/mm^2, rendered "
          f"{rendered:.0f}/mm^2, ratio {estimate / rendered:.3f}")
    assert 0.5 <= estimate / rendered <= 2.0
