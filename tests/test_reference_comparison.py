"""A measured profile held against a reference (:mod:`rspiv.reference_comparison`).

Ground truth: the DNS itself as the measurement (no difference), the DNS with differences
planted in one band (read back exactly), profiles whose window average is known in closed form
(linear and quadratic), and a series of the synthetic layer's exact fields, whose inner layer
is the DNS's (:class:`rspiv.synth.tbl.TBLFlow`).
"""

from __future__ import annotations

import json

import numpy as np
import pytest
import rspiv
from rspiv.cli import main
from rspiv.reference import load_dns
from rspiv.reference_comparison import compare_reference

DNS = load_dns(4060)


def _columns(dns, eps=0.01):
    cols = {
        "y_plus": dns.y_plus.copy(),
        "U_plus": dns.u_plus.copy(),
        "uu_plus": dns.uu_plus.copy(),
        "vv_plus": dns.vv_plus.copy(),
        "uv_plus": dns.uv_plus.copy(),
    }
    for q in ("U_plus", "uu_plus", "vv_plus", "uv_plus"):
        cols[f"eps_{q}"] = np.full(dns.y_plus.size, eps)
    return cols


def _band(cmp, band, quantity):
    (b,) = [b for b in cmp.bands if b["band"] == band and b["quantity"] == quantity]
    return b


def test_the_dns_against_itself():
    cmp = compare_reference(_columns(DNS), DNS)
    assert cmp.bands and all(b["agrees"] for b in cmp.bands)
    assert max(abs(b["difference"]) for b in cmp.bands) < 1e-12
    names = {b["band"] for b in cmp.bands}
    assert names == {"viscous sublayer", "buffer layer", "log layer"}  # no Re_tau: no outer
    assert cmp.peak["measured"]["uu_plus"] == cmp.peak["reference"]["uu_plus"]
    assert 13 < cmp.peak["reference"]["y_plus"] < 16
    # the verdict names how large a difference the errors hide: 3 x 0.01 over the smallest
    # mean of U+ or uu+ in a band (the viscous sublayer's uu+)
    verdict = cmp.verdict()
    assert "every band agrees within three errors (three errors reach" in verdict
    want = max(3 * 0.01 / np.mean(np.abs(DNS.uu_plus[(DNS.y_plus > 0) & (DNS.y_plus < 5)])),
               3 * 0.01 / np.mean(DNS.u_plus[(DNS.y_plus > 0) & (DNS.y_plus < 5)]))  # fmt: skip
    assert f"reach {100 * want:.0f} % of the reference's U+ or uu+" in verdict


def test_the_rows_scatter_between_pairs_judges_where_enough_pairs_give_it():
    """A profile carrying both errors: the bound (0.5) hides a planted difference of 0.5 in
    the log layer's U+; its rows' scatter between pairs (0.05) shows it where a row has
    VERDICT_PAIRS pairs, the bound judges rows of fewer."""
    from rspiv.reference_comparison import VERDICT_PAIRS

    cols = _columns(DNS, eps=0.5)
    y = cols["y_plus"]
    cols["U_plus"][(y >= 30) & (y < 0.15 * DNS.re_tau)] += 0.5
    for q in ("U_plus", "uu_plus", "vv_plus", "uv_plus"):
        cols[f"eps_{q}_pairs"] = np.full(y.size, 0.05)
    cols["pairs"] = np.full(y.size, float(VERDICT_PAIRS))
    cmp = compare_reference(cols, DNS)
    b = _band(cmp, "log layer", "U_plus")
    assert cmp.errors == "pairs" and not b["agrees"]
    assert b["error"] == pytest.approx(0.05, rel=1e-12)
    assert cmp.to_dict()["errors"] == "pairs"
    cols["pairs"][:] = VERDICT_PAIRS - 1
    cmp = compare_reference(cols, DNS)
    b = _band(cmp, "log layer", "U_plus")
    assert cmp.errors == "bound" and b["agrees"] and b["error"] == pytest.approx(0.5)
    # a profile without them (another tool's, an older campaign's): the bound
    plain = {k: v for k, v in cols.items() if "pairs" not in k}
    assert compare_reference(plain, DNS).errors == "bound"


def test_planted_differences_are_read_back():
    cols = _columns(DNS, eps=0.05)
    y = cols["y_plus"]
    log = (y >= 30) & (y < 0.15 * DNS.re_tau)
    cols["U_plus"][log] += 0.5
    buffer = (y >= 5) & (y < 30)
    cols["uu_plus"][buffer] *= 0.88  # the paper's "up to 12 % lower"
    cols["near_wall"] = (y < 10).astype(float)
    cmp = compare_reference(cols, DNS)
    b = _band(cmp, "log layer", "U_plus")
    assert b["difference"] == pytest.approx(0.5, abs=1e-12) and not b["agrees"]
    assert b["error"] == pytest.approx(0.05, rel=1e-12)  # the DNS taken as exact
    b = _band(cmp, "buffer layer", "uu_plus")
    assert b["relative"] == pytest.approx(-0.12, abs=1e-12) and not b["agrees"]
    assert b["y_plus"][0] >= 10  # rows beside the wall left out of the stresses ...
    assert _band(cmp, "buffer layer", "U_plus")["y_plus"][0] < 10  # ... not of U+
    assert cmp.left_out_near_wall == int(np.count_nonzero(y < 10))
    assert _band(cmp, "viscous sublayer", "U_plus")["agrees"]
    assert {f"{b['band']} {b['quantity']}" for b in cmp.differing()} == {
        "log layer U_plus",
        "buffer layer uu_plus",
    }
    assert "log layer U_plus (+" in cmp.verdict()


def test_the_window_average_of_the_mean():
    """The reference's mean averaged over the window's height: exact for a linear profile, and
    h^2 / 12 above a quadratic one."""
    y = np.linspace(0.0, 60.0, 601)
    ref = {"y_plus": y, "U_plus": y.copy()}
    meas = {"y_plus": y[1:], "U_plus": y[1:].copy()}
    cmp = compare_reference(meas, ref, window_plus=(20.0, 4.0))
    for b in cmp.bands:
        assert abs(b["difference"]) < 1e-9 and b["y_plus"][0] >= 2.0 - 1e-9  # y < h/2 left out
    ref = {"y_plus": y, "U_plus": 0.01 * y**2}
    meas = {"y_plus": y[100:500], "U_plus": 0.01 * y[100:500] ** 2}
    cmp = compare_reference(meas, ref, window_plus=(20.0, 6.0))
    for b in cmp.bands:
        assert b["difference"] == pytest.approx(-0.01 * 6.0**2 / 12, rel=1e-3)


def test_outer_layer_in_outer_scaling():
    """Above 0.15 delta99 the velocity defect and the stresses at the same y / delta99."""

    class Result:  # what a BoundaryLayerResult gives the comparison
        re_tau, u_tau = DNS.re_tau, 0.4
        u_e = (DNS.u_inf_plus + 1.0) * 0.4  # a free stream 1 u_tau faster: the defect + 1

        def profile_columns(self):
            return _columns(DNS)

    cmp = compare_reference(Result(), DNS)
    outer = _band(cmp, "outer layer", "U_e+ - U+")
    assert outer["difference"] == pytest.approx(1.0, abs=1e-9) and not outer["agrees"]
    assert outer["y_plus"][0] >= 0.15 * DNS.re_tau and outer["y_plus"][1] <= DNS.re_tau
    for q in ("uu_plus", "vv_plus", "uv_plus"):
        assert _band(cmp, "outer layer", q)["difference"] == pytest.approx(0, abs=1e-12)
    assert _band(cmp, "log layer", "U_plus")["difference"] == pytest.approx(0, abs=1e-12)
    # without the measurement's Re_tau there is no outer band
    cols = _columns(DNS)
    assert "outer layer" not in {b["band"] for b in compare_reference(cols, DNS).bands}


def test_a_csv_reference_and_the_command(tmp_path, capsys):
    """Another campaign's profile as the reference, and `rspiv compare-profile`."""
    y = DNS.y_plus
    keep = (y > 0) & (y < DNS.re_tau)
    cols = {k: v[keep] for k, v in _columns(DNS).items()}
    head = f"# re_tau = {DNS.re_tau}\n# u_e = {DNS.u_inf_plus * 0.4}\n# u_tau = 0.4\n"
    body = ",".join(cols) + "\n" + "\n".join(
        ",".join(repr(float(cols[k][i])) for k in cols) for i in range(keep.sum())
    )
    ref = tmp_path / "ref.csv"
    ref.write_text(head + "# label = last year\n" + body + "\n")
    meas = tmp_path / "meas.csv"
    shifted = dict(cols)
    shifted["uu_plus"] = cols["uu_plus"] * 1.05
    body = ",".join(shifted) + "\n" + "\n".join(
        ",".join(repr(float(shifted[k][i])) for k in shifted) for i in range(keep.sum())
    )
    meas.write_text(head + body + "\n")
    cmp = compare_reference(meas, ref)
    assert cmp.reference == "last year (ref.csv)"
    out = _band(cmp, "outer layer", "uu_plus")
    assert out["relative"] == pytest.approx(0.05, abs=1e-9) and not out["agrees"]
    assert _band(cmp, "outer layer", "U_e+ - U+")["difference"] == pytest.approx(0, abs=1e-9)
    # default reference: the DNS station nearest the measurement's Re_tau (4060's)
    assert compare_reference(meas).reference.startswith("DNS Re_theta=4061")
    js = tmp_path / "c.json"
    assert main(["compare-profile", str(meas), str(ref), "--json", str(js)]) == 0
    text = capsys.readouterr().out
    assert "against last year (ref.csv)" in text and "differs in" in text
    assert json.loads(js.read_text())["differing"]
    # bad input: one line, exit 2
    bad = tmp_path / "bad.csv"
    bad.write_text("a,b\n1,2\n")
    with pytest.raises(rspiv.InvalidInputError, match="bad.csv: a profile needs a y_plus"):
        compare_reference(bad)
    assert main(["compare-profile", str(tmp_path / "none.csv")]) == 2
    assert "none.csv: no such file" in capsys.readouterr().err
    assert main(["compare-profile", str(meas), "--window-plus", "x"]) == 2
    empty = tmp_path / "empty.csv"
    empty.write_text("y_plus,U_plus\nnan,nan\n")
    with pytest.raises(rspiv.InvalidInputError, match="empty.csv: fewer than two rows"):
        compare_reference(meas, empty)
    with pytest.raises(rspiv.InvalidInputError, match="Re_tau is needed"):
        compare_reference({"y_plus": y, "U_plus": DNS.u_plus})


def test_u_tau_error_enters_each_rows_error(tmp_path):
    """A profile whose u_tau has its error from the pairs (0.5 %: a CSV header's
    ``u_tau_std_pairs`` over ``u_tau``): each row's error takes ``|U+| 0.005`` (``2 |q| 0.005``
    for a stress) in quadrature, so U+ 0.5 % high everywhere (a friction velocity low by its
    error) agrees in the log layer; the same profile without that header differs."""
    from rspiv.outputs import write_profile_csv

    cols = _columns(DNS, eps=0.01)
    cols["U_plus"] = cols["U_plus"] * 1.005
    meta = {"u_tau": 0.4, "re_tau": DNS.re_tau}
    with_err = write_profile_csv(tmp_path / "a.csv", cols, metadata={**meta,
                                                                       "u_tau_std_pairs": 0.002})
    plain = write_profile_csv(tmp_path / "b.csv", cols, metadata=meta)
    cmp = compare_reference(with_err, DNS)
    y = cols["y_plus"]
    log = (y >= 30) & (y < 0.15 * DNS.re_tau)
    b = _band(cmp, "log layer", "U_plus")
    want = np.mean(np.hypot(0.01, 0.005 * cols["U_plus"][log]))
    assert b["error"] == pytest.approx(want, rel=1e-9) and b["agrees"]
    b = _band(cmp, "log layer", "uu_plus")
    want = np.mean(np.hypot(0.01, 2 * 0.005 * np.abs(cols["uu_plus"][log])))
    assert b["error"] == pytest.approx(want, rel=1e-9)
    b = _band(compare_reference(plain, DNS), "log layer", "U_plus")
    assert b["error"] == pytest.approx(0.01, rel=1e-9) and not b["agrees"]
