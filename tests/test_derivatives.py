"""Velocity gradients, vorticity, divergence and swirling strength (rspiv.derivatives) against
exact answers: polynomials, solid-body rotation, a Lamb-Oseen vortex (the schemes' orders), the
noise each scheme passes, the frame's sign, and a vortex measured through PIV (its
circulation)."""

from __future__ import annotations

import numpy as np
import pytest
import rspiv
from rspiv.derivatives import SCHEMES, derivative, divergence, gradients, swirling_strength
from rspiv.derivatives import vorticity as vort
from rspiv.errors import InvalidInputError
from rspiv.synth import particle_pair


def _grid(ny, nx, h):
    y, x = np.mgrid[0:ny, 0:nx] * h
    return x, y  # pixel frame: y down


def _lamb_oseen(x, y, xc, yc, gamma, rc):
    """Displacements (pixel frame) of a counter-clockwise (on the image) Lamb-Oseen vortex and
    its exact vorticity (x right, y up)."""
    rx, ry = x - xc, -(y - yc)  # y up
    r2 = rx**2 + ry**2
    with np.errstate(invalid="ignore", divide="ignore"):
        ut = np.where(r2 > 0, gamma / (2 * np.pi * r2) * (1 - np.exp(-r2 / rc**2)), 0.0)
    u, v_up = -ut * ry, ut * rx
    return u, -v_up, gamma / (np.pi * rc**2) * np.exp(-r2 / rc**2)


def test_solid_body_rotation_and_shear():
    """Counter-clockwise rotation on the image at Omega: vorticity 2 Omega, swirling strength
    Omega, no divergence, by every scheme; a shear u growing downward (the image's y) turns
    counter-clockwise too; NaN only on the outermost rows and columns."""
    x, y = _grid(30, 40, 4.0)
    om = 0.013
    u, v = om * y, om * x  # u = -Omega y_up, v = -(Omega x): v_up = Omega x
    v = -v
    for scheme in SCHEMES:
        w = vort(u, v, 4.0, 4.0, scheme)
        inner = (slice(1, -1), slice(1, -1))
        np.testing.assert_allclose(w[inner], 2 * om, rtol=1e-12)
        assert np.isnan(w[0]).all() and np.isnan(w[:, -1]).all()
        assert np.isfinite(w[inner]).all()
        np.testing.assert_allclose(swirling_strength(u, v, 4, 4, scheme, signed=True)[inner], om,
                                   rtol=1e-12)  # fmt: skip
        np.testing.assert_allclose(divergence(u, v, 4, 4, scheme)[inner], 0.0, atol=1e-15)
    w = vort(0.02 * y, np.zeros_like(y), 4, 4)
    np.testing.assert_allclose(w[1:-1, 1:-1], 0.02, rtol=1e-12)
    # a shear has vorticity but does not swirl
    assert np.all(swirling_strength(0.02 * y, np.zeros_like(y), 4, 4)[1:-1, 1:-1] == 0)


@pytest.mark.parametrize(("scheme", "degree"), [("central", 2), ("least_squares", 2),
                                                ("richardson", 4)])  # fmt: skip
def test_each_scheme_is_exact_up_to_its_degree(scheme, degree):
    x, _ = _grid(3, 30, 0.5)
    for p in range(degree + 1):
        d = derivative(x**p, 0.5, 1, scheme)[:, 2:-2]
        np.testing.assert_allclose(d, p * x[:, 2:-2] ** max(p - 1, 0), rtol=1e-10, atol=1e-10)
    d = derivative(x ** (degree + 1), 0.5, 1, scheme)[:, 2:-2]
    assert not np.allclose(d, (degree + 1) * x[:, 2:-2] ** degree, rtol=1e-6)


def test_the_schemes_converge_at_their_order():
    """A Lamb-Oseen vortex of core radius 10, 20 and 40 grid steps: at 10 the largest vorticity
    error is under 0.1 % (Richardson), 0.6 % (central) and 2 % (least squares, the smoothing
    scheme); from 20 to 40 it falls by about 4 (central, least squares) and 16 (Richardson)."""
    err = {}
    for n, h in ((80, 4.0), (160, 2.0), (320, 1.0)):
        x, y = _grid(n, n, h)
        c = 0.5 * (n - 1) * h
        u, v, exact = _lamb_oseen(x, y, c, c, 4000.0, 40.0)
        for scheme in SCHEMES:
            inner = (slice(2, -2), slice(2, -2))  # the schemes' own stencils, no fallback
            w = vort(u, v, h, h, scheme)[inner]
            err.setdefault(scheme, []).append(np.max(np.abs(w - exact[inner])) / exact.max())
    assert err["richardson"][0] < 1e-3 and err["central"][0] < 0.006
    assert err["least_squares"][0] < 0.02
    for scheme, order in (("central", 4), ("least_squares", 4), ("richardson", 16)):
        assert err[scheme][1] / err[scheme][2] == pytest.approx(order, rel=0.1), (scheme, err)


def test_noise_passes_as_documented():
    """White noise of unit variance: the derivative's standard deviation is sqrt(sum w^2) / h
    (0.707, 0.316, 0.950), within 1 % over 400,000 points."""
    rng = np.random.default_rng(2)
    f = rng.normal(size=(2000, 204))
    for scheme, want in (("central", 0.7071), ("least_squares", 0.3162), ("richardson", 0.9501)):
        d = derivative(f, 2.0, 1, scheme)[:, 2:-2]
        assert d.std() * 2.0 == pytest.approx(want, rel=0.01)
        assert want == pytest.approx(np.sqrt(np.sum(np.square(SCHEMES[scheme][1]))), rel=1e-3)


def test_missing_vectors_fall_back_to_the_central_difference_then_nan():
    x, y = _grid(9, 9, 1.0)
    u = 0.5 * x * x
    u[4, 4] = np.nan
    d = derivative(u, 1.0, 1, "least_squares")
    assert np.isnan(d[4, 3]) and np.isnan(d[4, 5]) and np.isnan(d[4, 4]) is np.False_
    np.testing.assert_allclose(d[4, [2, 6]], x[4, [2, 6]])  # central: exact for a quadratic
    np.testing.assert_allclose(d[3, 2:-2], x[3, 2:-2])
    assert np.isnan(derivative(u, 1.0, 0, "central")[[3, 5], 4]).all()


def test_bad_input_is_refused():
    z = np.zeros((5, 5))
    with pytest.raises(InvalidInputError, match="scheme"):
        derivative(z, 1.0, 0, "fourier")
    with pytest.raises(InvalidInputError, match="2-D"):
        derivative(np.zeros(5), 1.0, 0)
    with pytest.raises(InvalidInputError, match="positive"):
        derivative(z, 0.0, 0)
    with pytest.raises(InvalidInputError, match="shape"):
        gradients(z, np.zeros((5, 4)), 1, 1)
    a, b = particle_pair((128, 128), (1.0, 0.5), seed=1)
    f = rspiv.piv_at(a, b, np.array([[64.0, 64.0]]), window=(32, 32))
    with pytest.raises(InvalidInputError, match="regular grid"):
        f.vorticity()


def test_a_vortex_through_piv_keeps_its_circulation():
    """A counter-clockwise Lamb-Oseen vortex (core radius 60 px, up to 2.3 px displacement)
    through rspiv.piv (64 -> 32 px): the vorticity peaks positive at the centre, and its
    integral over the disc of 150 px (Stokes: the circulation there, which the windows'
    average does not change) is within 3 % of the exact one."""
    shape = (512, 512)
    gamma, rc, c = 1200.0, 60.0, 255.5

    def disp(px, py):
        u, v, _ = _lamb_oseen(px, py, c, c, gamma, rc)
        return u, v

    a, b = particle_pair(shape, disp, seed=4)
    field = rspiv.piv(a, b, passes=[(64, 64), (32, 32)], overlap=0.5)
    w = field.vorticity()
    i = np.unravel_index(np.nanargmax(w), w.shape)
    assert abs(field.x[i] - c) <= 16 and abs(field.y[i] - c) <= 16
    r = np.hypot(field.x - c, field.y - c)
    disc = r <= 150
    assert np.isfinite(w[disc]).all()
    dx, dy = field.grid[2], field.grid[3]
    circ = np.sum(w[disc]) * dx * dy
    exact = gamma * (1 - np.exp(-(150 / rc) ** 2))
    # the grid's disc is not exactly the circle: its area against pi 150^2
    area = disc.sum() * dx * dy / (np.pi * 150**2)
    assert circ == pytest.approx(exact, rel=0.03 + abs(area - 1)), (circ, exact, area)
    ds = field.to_xarray(derived="least_squares")
    np.testing.assert_array_equal(ds["vorticity"].values, w)
    assert ds["swirling_strength"].attrs["units"] == "1/pair"
    assert float(ds["swirling_strength"].values[i]) > 0
