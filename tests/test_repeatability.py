"""Two shots of one plate (issue 15: an honest sigma where there is no truth): the markers'
repeatability against their reported sigma, with the shots' motion and a shared field (shimmer)
told apart. Rendered with exact answers (rspiv.synth)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from rspiv import calibrate, repeatability
from rspiv.cli import main
from rspiv.errors import InvalidInputError
from rspiv.synth import calibration_target
from rspiv.synth.target import PAPER_OPTICS, paper_lens

# A denser plate than the paper's (56 px pitch at scale 0.25): enough markers for the motion
# polynomial to leave a field of a few pitches alone.
OPTICS = dataclasses.replace(PAPER_OPTICS, pitch_mm=PAPER_OPTICS.pitch_mm / 3, n_markers=(37, 21))
PITCH = OPTICS.pitch_mm


class _Shimmer:
    """The paper's lens, plus a displacement field ``A sin(2 pi x / L)``, ``A sin(2 pi y / L)``
    (image px): what air moving between two shots does to the markers."""

    def __init__(self, amplitude: float, wavelength: float) -> None:
        self.lens = paper_lens(OPTICS.scaled(0.25))
        self.a, self.k = amplitude, 2 * np.pi / wavelength

    def forward(self, ideal: np.ndarray) -> np.ndarray:
        p = self.lens.distort(ideal)
        return p + self.a * np.sin(self.k * p)


def _shot(seed: int, offset: tuple[float, float], mapping=None):
    t = calibration_target(
        scale=0.25, optics=OPTICS, seed=seed, dot="disc", dot_diameter_px=12.0,
        grid_offset_px=offset, mapping=mapping,
    )  # fmt: skip
    return t, calibrate(t.image, PITCH, model="p3")


def test_noise_alone_repeats_as_reported():
    # The plate moved by (1.3, -0.7) px (full-scale offset) between the shots; new noise.
    _, a = _shot(0, (0.37, -0.21))
    _, b = _shot(1, (0.37 + 5.2, -0.21 - 2.8))
    rep = repeatability(a, b)
    assert rep.n == len(a.markers) == len(b.markers) == 37 * 21
    assert rep.shift_px == pytest.approx((1.3, -0.7), abs=0.02)
    assert 0.67 <= rep.ratio <= 1.5, rep
    assert rep.rms_field_px < 0.5 * rep.rms_reported_px, rep
    assert "actual/reported" in str(rep) and "\n" not in str(rep)


def test_a_shared_field_is_told_apart_from_the_markers_noise():
    amplitude, wavelength = 0.05, 8 * 56.0  # px; the truth: A / sqrt(2) per axis
    _, a = _shot(0, (0.37, -0.21))
    _, b = _shot(1, (0.37, -0.21), mapping=_Shimmer(amplitude, wavelength))
    rep = repeatability(a, b)
    assert 0.67 <= rep.ratio <= 1.5, rep
    assert rep.rms_field_px == pytest.approx(amplitude / np.sqrt(2), rel=0.15), rep


def test_bad_input_is_a_one_line_error():
    _, a = _shot(0, (0.37, -0.21))
    other = calibrate(calibration_target(scale=0.25, seed=2).image, PAPER_OPTICS.pitch_mm)
    for args, kw, msg in (
        ((a, object()), {}, "not a Calibration"),
        ((a, a), {"neighbours": 2}, "neighbours must be"),
        ((a, other), {}, "not the same plate"),
        ((a, calibrate(_shot(1, (0.37, -0.21))[0].image[:, :700], PITCH)), {}, "pair within"),
    ):
        with pytest.raises(InvalidInputError, match=msg) as e:
            repeatability(*args, **kw)
        assert "\n" not in str(e.value)


def test_the_cli_compares_two_calibration_files(tmp_path, capsys):
    files = []
    for seed in (0, 1):
        _, cal = _shot(seed, (0.37, -0.21))
        files.append(tmp_path / f"shot{seed}.json")
        cal.save(files[-1])
    assert main(["repeatability", str(files[0]), str(files[1])]) == 0
    out = capsys.readouterr().out.strip()
    assert len(out.splitlines()) == 1 and "actual/reported" in out
    assert main(["repeatability", str(files[0]), str(tmp_path / "none.json")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "none.json" in err
