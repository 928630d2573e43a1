"""Boundary-layer analysis against profiles generated from the Schlatter & Örlü DNS data."""

from __future__ import annotations

import numpy as np
import pytest
from rspiv.boundary_layer import (
    KAPPA_CMN,
    analyse_profile,
    chauhan_inner,
    clauser_fit,
    composite_fit,
    composite_u_plus,
    integral_quantities,
    stress_uncertainties,
)
from rspiv.errors import InvalidInputError
from rspiv.profiles import average_along_x, profile_from_accumulator
from rspiv.reference import load_dns

NU = 1.5e-5  # m^2/s


def _piv_profile(dns, u_tau, offset_plus, dy_plus=2.7, y_plus_first=3.0):
    """A PIV-like profile sampled from the DNS: points every dy_plus from y_plus_first, measured
    distances shifted by offset_plus viscous units (the true wall lies at y_m = offset)."""
    yp = np.arange(y_plus_first, 0.95 * dns.y_plus[-1], dy_plus)
    l_nu = NU / u_tau
    y_m = yp * l_nu + offset_plus * l_nu
    U = np.interp(yp, dns.y_plus, dns.u_plus) * u_tau
    uu = np.interp(yp, dns.y_plus, dns.uu_plus) * u_tau**2
    vv = np.interp(yp, dns.y_plus, dns.vv_plus) * u_tau**2
    uv = np.interp(yp, dns.y_plus, dns.uv_plus) * u_tau**2
    return y_m, U, uu, vv, uv


def test_integral_quantities_reproduce_dns_header():
    d = load_dns(4060)
    u_tau = 0.35
    y = d.y_plus * NU / u_tau
    iq = integral_quantities(y, d.u_plus * u_tau)
    assert iq.u_e * iq.theta / NU == pytest.approx(4061.378, rel=1e-3)
    assert iq.u_e * iq.delta_star / NU == pytest.approx(5633.318, rel=1e-3)
    assert iq.H == pytest.approx(1.387046, rel=1e-3)
    assert iq.delta99 * u_tau / NU == pytest.approx(d.re_tau, rel=1e-3)


@pytest.mark.parametrize(
    ("re_theta", "u_tau", "offset_plus"),
    [(4060, 0.35, 2.0), (4060, 0.5, -1.5), (3030, 0.3, 0.7), (2000, 0.42, 1.2)],
)
def test_analyse_profile_recovers_dns_truth(re_theta, u_tau, offset_plus):
    d = load_dns(re_theta)
    y_m, U, uu, vv, uv = _piv_profile(d, u_tau, offset_plus)
    r = analyse_profile(y_m, U, uu, vv, uv, NU, n_eff=2000.0)
    assert r.u_tau == pytest.approx(u_tau, rel=5e-3)
    assert abs(r.y0_plus - offset_plus) < 0.1  # a tenth of a viscous unit
    # integral quantities of the truncated, offset PIV-like profile against the DNS values
    # (delta_99 from the DNS: Re_tau; theta, delta* from the full-resolution DNS profile)
    full = integral_quantities(d.y_plus * NU / u_tau, d.u_plus * u_tau)
    assert r.delta99 == pytest.approx(d.re_tau * NU / u_tau, rel=1e-2)
    assert r.theta == pytest.approx(full.theta, rel=1e-2)
    assert r.delta_star == pytest.approx(full.delta_star, rel=1e-2)
    assert r.H == pytest.approx(full.H, rel=1e-2)
    assert r.re_theta == pytest.approx(d.re_theta, rel=1e-2)
    assert r.re_tau == pytest.approx(d.re_tau, rel=1e-2)
    # profiles in wall units on the corrected y
    np.testing.assert_allclose(
        r.u_plus,
        np.interp(r.y_plus, d.y_plus, d.u_plus),
        atol=0.2,  # 0.5 % of U+_inf ~ 0.13
    )
    np.testing.assert_allclose(r.uu_plus, uu / r.u_tau**2)
    assert np.all(r.eps_u_plus > 0) and np.all(np.isfinite(r.eps_uv_plus))


def test_dns_4060_with_file_values():
    """The stated Re_theta = 4061.378, Re_delta* = 5633.318, H12 = 1.387046 within 1 %."""
    d = load_dns(4060)
    y_m, U, uu, vv, uv = _piv_profile(d, 0.35, 1.0)
    r = analyse_profile(y_m, U, uu, vv, uv, NU)
    assert r.re_theta == pytest.approx(4061.378, rel=1e-2)
    assert r.re_delta_star == pytest.approx(5633.318, rel=1e-2)
    assert r.H == pytest.approx(1.387046, rel=1e-2)
    assert np.isnan(r.eps_u_plus).all()  # no n_eff, no uncertainty


def test_composite_fit_exact_on_its_own_model_and_clauser_agrees():
    u_tau = 0.4
    B = float(chauhan_inner(1e9, bump=False) - np.log(1e9) / KAPPA_CMN)
    for dplus in (3000.0, 10000.0):
        yp = np.geomspace(2, 1.5 * dplus, 400)
        y, U = yp * NU / u_tau + 0.5 * NU / u_tau, u_tau * composite_u_plus(yp, dplus, 0.45)
        cf = composite_fit(y, U, NU)
        assert cf.u_tau == pytest.approx(u_tau, rel=1e-8)
        assert cf.y0 * u_tau / NU == pytest.approx(0.5, abs=1e-6)
        assert cf.pi == pytest.approx(0.45, abs=1e-6)
        assert cf.delta * u_tau / NU == pytest.approx(dplus, rel=1e-6)
        c = clauser_fit(
            y, U, NU, kappa=KAPPA_CMN, b=B, y_plus_min=200, outer_fraction=0.1, y0=cf.y0
        )
        assert c.u_tau == pytest.approx(cf.u_tau, rel=3e-3)


def test_clauser_fit_pure_log_law():
    u_tau = 0.3
    yp = np.geomspace(60, 3000, 80)
    U = u_tau * (np.log(yp) / 0.41 + 5.0)
    c = clauser_fit(yp * NU / u_tau, U, NU, delta99=3000 / 0.15 * NU / u_tau)
    assert c.u_tau == pytest.approx(u_tau, rel=1e-8)
    assert c.rms_residual_plus < 1e-6


def test_uncertainty_formulas():
    eU, euu, evv, euv = stress_uncertainties(4.0, 1.0, -0.5, 100.0)
    assert eU == pytest.approx(0.2)
    assert euu == pytest.approx(4.0 * np.sqrt(0.02))
    assert evv == pytest.approx(np.sqrt(0.02))
    assert euv == pytest.approx(np.sqrt((4.0 + 0.25) / 100))


def test_average_along_x_weights_by_count():
    U = np.array([[1.0, 3.0], [2.0, 2.0]])
    cnt = np.array([[1, 3], [0, 5]])
    out = average_along_x(U, U, U, U, U, np.where(cnt == 1, 2, cnt), n_eff=cnt.astype(float))
    assert out["U"][0] == pytest.approx((2 * 1 + 3 * 3) / 5)
    assert out["U"][1] == pytest.approx(2.0) and out["count"].tolist() == [5, 5]
    with pytest.raises(InvalidInputError):
        average_along_x(U, U, U, U, U[:1], cnt)
    out = average_along_x(U, U, U, U, U, np.where(cnt == 1, 2, cnt), min_count=4)
    assert np.isnan(out["U"][0]) and out["U"][1] == 2.0 and out["count"].tolist() == [0, 5]
    assert np.isnan(average_along_x(U, U, U, U, U, cnt, min_count=6)["U"]).all()


def test_bad_input():
    y = np.linspace(1e-4, 0.1, 50)
    with pytest.raises(InvalidInputError, match="nu"):
        analyse_profile(y, y, y, y, y, -1.0)
    with pytest.raises(InvalidInputError, match="U: expected 50"):
        analyse_profile(y, y[:-1], y, y, y, NU)
    with pytest.raises(InvalidInputError, match="1D"):
        composite_fit(np.ones((3, 3)), np.ones((3, 3)), NU)
    with pytest.raises(InvalidInputError, match="at least 5"):
        integral_quantities([1e-3, 2e-3], [1.0, 2.0])


def test_campaign_statistics_end_to_end_with_correlated_samples():
    """Fields with the DNS mean and Reynolds stresses, successive fields AR(1)-correlated
    (rho = 0.5), accumulated, averaged along x and analysed: u_tau recovered, and the
    errors of U, uu, uv scaled by their n_eff-based uncertainties have unit spread."""
    from rspiv.stats import FieldAccumulator

    rng = np.random.default_rng(7)
    d = load_dns(4060)
    u_tau, rho, n_fields, nx = 0.35, 0.5, 400, 4
    yp = np.arange(3.0, 0.95 * d.y_plus[-1], 8.0)
    y_m = yp * NU / u_tau
    U = np.interp(yp, d.y_plus, d.u_plus) * u_tau
    uu, vv, uv = (np.interp(yp, d.y_plus, c) * u_tau**2 for c in (d.uu_plus, d.vv_plus, d.uv_plus))
    # per-y Cholesky factor of [[uu, uv], [uv, vv]] (free stream: tiny stresses)
    a = np.sqrt(np.maximum(uu, 1e-12))
    b = uv / a
    c = np.sqrt(np.maximum(vv - b**2, 1e-12))
    acc = FieldAccumulator((yp.size, nx))
    z = rng.standard_normal((2, yp.size))
    for k in range(n_fields):
        if k:
            z = rho * z + np.sqrt(1 - rho**2) * rng.standard_normal((2, yp.size))
        u = U + a * z[0]
        v = b * z[0] + c * z[1]
        # identical along x: the profile n_eff (count-weighted mean over x) is then exact
        acc.add(np.repeat(u[:, None], nx, 1), np.repeat(v[:, None], nx, 1), pair_id=k)
    assert np.median(acc.lag1_correlation("u")) == pytest.approx(rho, abs=0.05)
    prof = profile_from_accumulator(acc, min_count=10)
    r = analyse_profile(y_m, prof["U"], prof["uu"], prof["vv"], prof["uv"], NU, n_eff=prof["n_eff"])
    assert r.u_tau == pytest.approx(u_tau, rel=1e-2)
    assert np.median(r.n_eff) == pytest.approx(n_fields * (1 - rho) / (1 + rho), rel=0.15)
    n_uu = np.median(prof["n_eff"]["uu"])
    assert n_uu == pytest.approx(n_fields * (1 - rho**2) / (1 + rho**2), rel=0.15)
    inner = yp < 0.8 * d.re_tau  # where the stresses are not ~0
    for got, want, eps in (
        (prof["vv"], vv, r.eps_vv_plus * r.u_tau**2),
        (prof["U"], U, r.eps_u_plus * r.u_tau),
        (prof["uu"], uu, r.eps_uu_plus * r.u_tau**2),
        (prof["uv"], uv, r.eps_uv_plus * r.u_tau**2),
    ):
        zscore = ((got - want) / eps)[inner]
        assert 0.8 < np.std(zscore) < 1.25, np.std(zscore)


def test_clauser_fit_without_log_region_is_a_convergence_error():
    from rspiv.errors import ConvergenceError

    u_tau = 0.3
    yp = np.linspace(1.0, 30.0, 40)  # viscous sublayer and buffer layer only
    y = yp * NU / u_tau
    with pytest.raises(ConvergenceError, match="no usable log region"):
        clauser_fit(y, u_tau * chauhan_inner(yp), NU, delta99=y[-1])


def test_noise_corrected_stresses_and_their_uncertainty():
    """``analyse_profile(noise=...)``: uu and vv less the mean squared uncertainty (NaN where
    negative), their uncertainty the measured stresses' and the noise estimate's in
    quadrature; U, uv and the fits unchanged."""
    from rspiv.boundary_layer import analyse_profile, composite_u_plus

    nu, ut = 1.5e-5, 0.4
    y = np.geomspace(2e-4, 0.08, 60)
    U = ut * composite_u_plus(y * ut / nu, 2000.0, 0.5)
    uu = np.full(60, 4.0 * ut**2)
    vv = np.full(60, 1.0 * ut**2)
    uv = np.full(60, -0.9 * ut**2)
    nuu, nvv = 0.25 * uu, 0.5 * vv
    nuu[0] = 2 * uu[0]  # noise above the measured variance: no corrected value there
    enuu, envv = 0.01 * uu, 0.02 * vv
    raw = analyse_profile(y, U, uu, vv, uv, nu, 1000.0)
    cor = analyse_profile(y, U, uu, vv, uv, nu, 1000.0, noise=(nuu, nvv, enuu, envv))
    assert cor.u_tau == raw.u_tau and np.array_equal(cor.uv_plus, raw.uv_plus)
    np.testing.assert_allclose(cor.uu_plus[1:] * cor.u_tau**2, (uu - nuu)[1:], rtol=1e-12)
    np.testing.assert_allclose(cor.vv_plus * cor.u_tau**2, vv - nvv, rtol=1e-12)
    assert np.isnan(cor.uu_plus[0])
    np.testing.assert_allclose(
        cor.eps_uu_plus, np.hypot(raw.eps_uu_plus, enuu / raw.u_tau**2), rtol=1e-12
    )
    with pytest.raises(InvalidInputError, match="noise: expected"):
        analyse_profile(y, U, uu, vv, uv, nu, 1000.0, noise=(nuu, nvv))


def test_a_profile_without_free_stream_is_said():
    """A field (or region of interest) that stops inside the layer: its last values become
    U_e and delta_99 lies just below its top, a biased result that looks right; the result
    says so (``warning``), and with U_e given the layer's thickness is refused instead."""
    for re_theta in (2000, 3030, 4060):
        d = load_dns(re_theta)
        y_m, U, uu, vv, uv = _piv_profile(d, 0.35, 0.0)
        full = analyse_profile(y_m, U, uu, vv, uv, NU)
        assert full.warning is None
        # cut inside the layer, and just beyond it (delta_99 then 3-4 % low)
        for f in (0.6, 0.9, 1.1):
            cut = y_m < f * full.delta99
            part = analyse_profile(*(a[cut] for a in (y_m, U, uu, vv, uv)), NU)
            assert part.warning is not None and "no free stream in the field" in part.warning
            assert part.delta99 < 0.97 * full.delta99
        with pytest.raises(InvalidInputError, match="never reaches 0.99 U_e"):
            cut = y_m < 0.9 * full.delta99
            analyse_profile(*(a[cut] for a in (y_m, U, uu, vv, uv)), NU, u_e=full.u_e)
        # with the free stream from 1.3 delta_99 on the profile is trusted
        cut = y_m < 1.3 * full.delta99
        assert analyse_profile(*(a[cut] for a in (y_m, U, uu, vv, uv)), NU).warning is None
