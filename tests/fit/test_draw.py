"""Cross-section drawings: the ray fans are aimed right and the files are written."""

from __future__ import annotations

import numpy as np
import pytest
from matplotlib.image import imread

from lensfit.cli import main
from lensfit.prescription import load_lens
from lensfit.sample.draw import FAN_OVERFILL, fan
from lensfit.trace.tracer import forward_path, trace


@pytest.mark.parametrize(("lens_id", "field"), [("0001", 0.0), ("0001", 15.0), ("0014", 80.0)])
def test_fans_span_the_stop(lens_id, field):
    """Real-ray aiming: the fan crosses the stop plane evenly from -125% to +125% of its
    radius, even at 80 degrees through a fisheye where paraxial pupils are far off.
    Rays aimed past the last ray that reaches the stop are extrapolated and may be
    stopped earlier; those that arrive must sit at their target heights."""
    lens = load_lens(lens_id)
    rays = fan(lens, field, 11, axis=1)
    assert len(rays) == 11
    path = forward_path(lens)[: lens.stop_index + 1]
    at_stop = trace(lens, rays, path, clip=False)
    target = np.linspace(-FAN_OVERFILL, FAN_OVERFILL, 11)
    inner = np.abs(target) <= 1.0
    assert np.all(at_stop.ok[np.abs(target) <= 0.5])
    arrived = inner & at_stop.ok
    y = at_stop.pos[:, 1] / lens.stop_radius_max_mm
    # Interpolated launch heights on a 4001-ray probe: 2% of the stop radius
    np.testing.assert_allclose(y[arrived], target[arrived], atol=0.02)
    # With the stop in place, the outer rays are stopped
    full = trace(lens, rays)
    assert not np.any(full.ok[~inner])


@pytest.mark.parametrize(("lens_id", "panels"), [("0001", 1), ("2004", 2)])
def test_draw_writes_a_png(tmp_path, lens_id, panels):
    out = tmp_path / f"{lens_id}.png"
    assert main(["draw", lens_id, "-o", str(out), "--f-number", "4"]) == 0
    img = imread(out)
    # 11 x 4.2 inches per panel at 130 dpi
    assert img.shape[1] == 1430 and img.shape[0] == pytest.approx(546 * panels, abs=2)
    assert not list(tmp_path.glob("*.tmp*"))  # written atomically


def test_draw_rejects_bad_output_and_field(tmp_path, capsys):
    assert main(["draw", "0001", "-o", str(tmp_path / "x.jpg")]) == 2
    assert "expected a .png" in capsys.readouterr().err
    assert main(["draw", "0001", "-o", str(tmp_path / "x.png"), "--field", "120"]) == 2
    assert "field angle" in capsys.readouterr().err
    assert not (tmp_path / "x.png").exists()
