"""Method II for another tool's vectors (:func:`rspiv.correction.correct_vectors`).

Ground truth: the exact image-frame field of a known object displacement seen through a strong
known lens (``d = F(X + D/2) - F(X - D/2)`` at the image grid), which the correction must turn
back into ``D`` at the object grid; and particle images rendered through that lens, whose
uncorrected rspiv field, corrected so, must agree with rspiv's own Method II and the truth.
"""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest
import rspiv
from lens_cases import frames_through, p3_mapping, strong_lens
from rspiv.cli import main
from rspiv.compare import compare_fields
from rspiv.correction import correct_vectors, position_only_bias
from rspiv.errors import InvalidInputError
from rspiv.vector_files import VectorFile

SHAPE = (400, 640)
U_OBJ, V_OBJ = 9.0, 1.5


@pytest.fixture(scope="module")
def mapping():
    return p3_mapping(strong_lens(SHAPE), SHAPE)


def _flow(x, y):
    """A smooth object-frame displacement, px."""
    return U_OBJ + 2.0 * np.sin(y / 90.0), V_OBJ + 0.5 * np.cos(x / 120.0)


def _image_field(mapping, step=8.0) -> VectorFile:
    """The exact field a tool measures on the raw frames at an image grid."""
    x, y = np.meshgrid(20 + step * np.arange(76), 20 + step * np.arange(46))
    img = np.column_stack([x.ravel(), y.ravel()])
    obj = mapping.inverse(img)
    d_obj = np.column_stack(_flow(obj[:, 0], obj[:, 1]))
    ends = mapping.forward(np.concatenate([obj - d_obj / 2, obj + d_obj / 2]))
    d = ends[len(obj):] - ends[: len(obj)]
    ones = np.ones(x.shape, bool)
    return VectorFile(
        x=x, y=y, u=d[:, 0].reshape(x.shape), v=d[:, 1].reshape(x.shape), valid=ones,
        postprocessed=~ones, peak_ratio=None, sigma_u=np.full(x.shape, 0.05),
        sigma_v=np.full(x.shape, 0.05), tool="exact", path="exact", frame="image",
    )  # fmt: skip


def test_the_exact_image_field_comes_back_to_the_object_displacement(mapping):
    raw = _image_field(mapping)
    c = correct_vectors(raw, mapping)
    assert c.frame == "object" and any("Method II" in n for n in c.notes)
    ok = c.valid
    assert ok.mean() > 0.85  # the points whose image lies inside the field's grid
    du, dv = _flow(c.x, c.y)
    err = np.hypot(c.u - du, c.v - dv)[ok]
    assert err.max() < 0.01  # bilinear between nodes 8 px apart of a smooth field
    # without the correction the raw field is off by the distortion at these points
    assert np.nanmax(np.hypot(raw.u - du, raw.v - dv)) > 0.3
    # positions only: the displacement is kept, off by the position-only bias
    p = correct_vectors(raw, mapping, mapping="positions")
    obj = np.column_stack([p.x[ok], p.y[ok]])
    bias = position_only_bias(mapping, obj, np.column_stack([du[ok], dv[ok]]))
    np.testing.assert_allclose(np.column_stack([p.u[ok] - du[ok], p.v[ok] - dv[ok]]), bias,
                               atol=0.01)  # fmt: skip
    # the uncertainties are carried through the inverse's Jacobian, as Method II's own are
    from rspiv.correction import map_sigmas

    expect = map_sigmas(mapping, obj, np.full((len(obj), 2), 0.05))
    np.testing.assert_allclose(c.sigma_u[ok], expect[:, 0], rtol=1e-12)
    assert c.sigma_u[ok].min() < 0.048  # the lens' magnification varies: not the raw 0.05
    with pytest.raises(InvalidInputError, match="already corrected"):
        correct_vectors(c, mapping)


def test_an_uncorrected_run_corrected_so_agrees_with_method_two(mapping, tmp_path, capsys):
    a, b = frames_through(strong_lens(SHAPE), SHAPE, (U_OBJ, V_OBJ), seed=7, render_seed=11)
    passes = [(64, 64), (32, 32)]
    raw = rspiv.piv(a, b, passes=passes)
    two = rspiv.piv(a, b, passes=passes, calibration=mapping, method="II")
    fixed = correct_vectors(raw, mapping)
    ok = fixed.valid
    rms = np.sqrt(np.mean((fixed.u[ok] - U_OBJ) ** 2 + (fixed.v[ok] - V_OBJ) ** 2))
    rms_raw = np.sqrt(np.nanmean((raw.u - U_OBJ) ** 2 + (raw.v - V_OBJ) ** 2))
    assert rms < 0.05 and rms_raw > 0.2
    c = compare_fields(fixed, two)
    assert c.median < 0.03 and abs(c.bias_u) < 0.01 and abs(c.bias_v) < 0.01
    # the same through the command line: the reference corrected with --calibration (a
    # calibration from the lens' lattice, its object frame its own: the API gives the answer)
    from rspiv.outputs import write_netcdf

    gx, gy = np.meshgrid(np.linspace(20, SHAPE[1] - 21, 13), np.linspace(20, SHAPE[0] - 21, 9))
    obj = np.column_stack([gx.ravel(), gy.ravel()])
    cal = rspiv.calibrate_points(strong_lens(SHAPE).distort(obj), obj / 20.0, image_shape=SHAPE,
                                 model="p3", sigma_px=0.02)  # fmt: skip
    cal.save(tmp_path / "cal.json")
    write_netcdf(raw.to_xarray(), tmp_path / "raw.nc")
    api = compare_fields(correct_vectors(raw, cal), raw)
    assert main(["compare", str(tmp_path / "raw.nc"), str(tmp_path / "raw.nc"), "--calibration",
                 str(tmp_path / "cal.json"), "--json", str(tmp_path / "c.json")]) == 0  # fmt: skip
    out = json.loads((tmp_path / "c.json").read_text())
    assert out["n_compared"] == api.n_compared and out["median"] == pytest.approx(api.median)
    # the corrected reference against the raw field: said
    err = capsys.readouterr().err
    assert "the field is in the image frame and the reference in the object frame" in err


def test_cli_corrects_a_batch_and_reads_it_back(mapping, tmp_path, capsys):
    """``rspiv correct-vectors``: each file corrected to NetCDF, read back as a corrected field
    of its tool, equal to the API's correction; a batch resumed keeps what it wrote."""
    from rspiv.vector_files import read_vectors

    gx, gy = np.meshgrid(np.linspace(20, SHAPE[1] - 21, 13), np.linspace(20, SHAPE[0] - 21, 9))
    obj = np.column_stack([gx.ravel(), gy.ravel()])
    cal = rspiv.calibrate_points(strong_lens(SHAPE).distort(obj), obj / 20.0, image_shape=SHAPE,
                                 model="p3", sigma_px=0.02)  # fmt: skip
    cal.save(tmp_path / "cal.json")
    raw = _image_field(mapping)
    files = []
    for k in range(2):
        f = tmp_path / f"B{k:05d}.txt"  # OpenPIV's text layout: positions from the corner
        rows = np.column_stack([(raw.x + 0.5).ravel(), (raw.y + 0.5).ravel(),
                                (raw.u + k).ravel(), raw.v.ravel()])  # fmt: skip
        np.savetxt(f, rows, fmt="%.10f")
        files.append(str(f))
    out = tmp_path / "fixed"
    args = ["correct-vectors", *files, "--calibration", str(tmp_path / "cal.json"), "-o", str(out)]
    assert main(args) == 0
    assert "2 fields corrected" in capsys.readouterr().out
    back = read_vectors(out / "B00001.nc")
    api = correct_vectors(read_vectors(files[1]), cal)
    assert back.frame == "object" and back.tool == "OpenPIV"
    np.testing.assert_array_equal(back.valid, api.valid)
    np.testing.assert_allclose(back.u[api.valid], api.u[api.valid], rtol=1e-12)
    # corrected again: refused; a resumed batch keeps what it wrote
    with pytest.raises(InvalidInputError, match="already corrected"):
        correct_vectors(back, cal)
    assert main([*args, "--skip-existing"]) == 0
    assert "0 fields corrected" in capsys.readouterr().out
    # read ahead by reader processes: the same files, bit for bit
    ahead = tmp_path / "ahead"
    assert main([*args[:-1], str(ahead), "--readers", "2"]) == 0
    for f in ("B00000.nc", "B00001.nc"):
        a, b = read_vectors(out / f), read_vectors(ahead / f)
        for name in ("x", "y", "u", "v", "valid"):
            np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
    assert main([*args[:-1], str(ahead), "--readers", "-1"]) == 2
    assert "--readers -1" in capsys.readouterr().err
    assert main([*args[:-4], str(tmp_path / "missing.txt"), *args[-4:]]) == 2
    assert "missing.txt: no such file" in capsys.readouterr().err
    # a field of a larger sensor than the calibration's: refused, not extrapolated
    big = dataclasses.replace(raw, x=raw.x * 2.0, path="big")
    with pytest.raises(InvalidInputError, match="reach past the calibration's 640 x 400 px"):
        correct_vectors(big, cal)
