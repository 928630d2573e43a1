"""DNS reference data: vendored with the package, parsed, and identical to ../shared/ref."""

from __future__ import annotations

from importlib import resources

import numpy as np
import pytest
from conftest import SHARED
from rspiv.errors import InvalidInputError
from rspiv.reference import AVAILABLE_RE_THETA, all_dns, dns_profile_for_re_tau, load_dns


def test_vendored_files_are_package_data_and_match_shared():
    root = resources.files("rspiv").joinpath("data").joinpath("dns")
    names = sorted(p.name for p in root.iterdir() if p.name.startswith("schlatter"))
    assert len(names) == 4
    assert "Schlatter" in root.joinpath("README.md").read_text(encoding="utf-8")
    shared = SHARED / "ref"
    if shared.is_dir():  # the source tree: the copies are byte-identical
        for n in names:
            assert root.joinpath(n).read_bytes() == (shared / n).read_bytes()


def test_load_4060_header_and_columns():
    d = load_dns(4060)
    assert d.re_theta == pytest.approx(4061.378) and d.re_tau == pytest.approx(1271.535)
    assert d.re_delta_star == pytest.approx(5633.318) and d.h12 == pytest.approx(1.387046)
    assert d.y_plus.size == d.u_plus.size == 513
    assert d.y_plus[0] == 0 and np.all(np.diff(d.y_plus) > 0)
    # first data row after the wall: y+ = 0.0326495, U+ = 0.0326495, urms+ = 0.0139059
    assert (d.y_plus[1], d.u_plus[1], d.urms_plus[1]) == (0.0326495, 0.0326495, 0.0139059)
    assert d.uv_plus.max() < 1e-3 and d.uv_plus.min() < -0.9  # -uv+ > 0, peaks near 1
    np.testing.assert_allclose(d.uu_plus, d.urms_plus**2)
    assert d.u_inf_plus == pytest.approx(25.9456473)
    # y/delta99 is y+ / Re_tau
    np.testing.assert_allclose(d.y_delta99[1:], d.y_plus[1:] / d.re_tau, rtol=2e-4, atol=1e-7)


def test_prof_stations_and_selection():
    profs = all_dns()
    assert [round(p.re_theta, -1) for p in profs] == [1010, 2000, 3030, 4060]
    assert np.all(np.diff([p.re_tau for p in profs]) > 0)
    assert profs[1].re_tau == pytest.approx(671.124) and profs[1].h12 is None
    assert dns_profile_for_re_tau(700).re_theta == pytest.approx(2000.703)
    assert dns_profile_for_re_tau(2386).re_tau == pytest.approx(1271.535)  # highest station
    assert dns_profile_for_re_tau(100).re_tau == pytest.approx(359.3794)
    assert load_dns(3000).re_theta == pytest.approx(3031.843)
    assert tuple(AVAILABLE_RE_THETA) == (1000, 2000, 3030, 4060)


def test_bad_requests():
    with pytest.raises(InvalidInputError, match="re_theta"):
        load_dns(6500)
    with pytest.raises(InvalidInputError, match="re_tau"):
        dns_profile_for_re_tau(-5)
    with pytest.raises(InvalidInputError, match="re_tau"):
        dns_profile_for_re_tau(float("nan"))
