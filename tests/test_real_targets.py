"""A real target photograph (issue 15), vendored under its licence (tests/data/real/README.md):
rspiv calibrates it as a user would, with nothing but the pitch, and says what it saw."""

from __future__ import annotations

import pathlib

import numpy as np
import pytest
from rspiv import calibrate

DATA = pathlib.Path(__file__).parent / "data" / "real"


def test_myptv_stepped_body_one_flat_section():
    # The crop holds one 6 x 23 flat section (x 250-420 px) and single columns at other
    # depths: the calibration takes the section alone, finds its small bright dots unaided,
    # and warns that the line fit leaves residuals above the markers' sigma (the body's own
    # accuracy and the view: MyPTV calibrates it in 3-D).
    cal = calibrate(DATA / "myptv_cal1_crop.tif", 3.0, model="auto")
    la = cal.lattice
    assert la["polarity"] == "bright" and la["levels"] == 1
    assert len(cal.markers) >= 105
    x = cal.markers.image_px[:, 0]
    assert x.min() > 240 and x.max() < 430  # the one flat section, nothing beside it
    assert la["pitch_px"] == pytest.approx([34.1, 33.8], abs=0.3)
    assert cal.magnification == pytest.approx(np.mean(la["pitch_px"]) / 3.0, rel=0.01)
    assert np.median(cal.markers.sigma_px) < 0.1
    assert any("follows the target less closely" in w for w in cal.warnings)
