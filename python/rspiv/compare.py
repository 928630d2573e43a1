"""How far two vector fields of one pair agree: rspiv against DaVis, OpenPIV, PIVlab or Insight.

:func:`compare_fields` takes a reference field (any :class:`rspiv.vector_files.VectorFile`, e.g.
the lab's DaVis result) and a field to test (an rspiv :class:`~rspiv.PivField` or another
file), brings the second to the reference's vector positions and states their differences
over the vectors valid in both, all in px over the pair (v down):

- ``bias_u``, ``bias_v``: the mean of (field - reference), with its standard error from the
  scatter of the means of blocks of 8 x 8 vectors (neighbouring vectors share their windows'
  pixels at the usual overlaps, and their differences with them: the scatter of single vectors
  over their number understated it 2.7 times for differences correlated over one neighbour,
  the blocks by 6 %; NaN with fewer than 8 blocks);
- ``std_u``, ``std_v``: the scatter of the differences about it; ``rms``: of their magnitude;
- ``median``, ``p95``: percentiles of the magnitude ``|d|``; ``share_apart``: the share of
  vectors more than ``threshold`` px apart (0.5 by default; a wrong vector in one of the
  two), with the ``worst`` ones' positions;
- the coverage: how many of each field's valid vectors the other has valid too;
- per row of vectors (``rows``: y, count, mean du and dv, rms), which shows a difference
  growing towards a wall;
- with both fields' uncertainties, ``z_std_u``/``z_std_v``: the spread of ``du / sqrt(sigma_f^2
  + sigma_r^2)`` over the vectors under ``threshold`` (1 if the uncertainties are honest and the
  errors independent; the two tools' errors are correlated on one pair, so under 1 is expected).

When the positions coincide (within 0.01 px) the values are taken as they are; otherwise the
field is interpolated from its valid neighbours (:func:`rspiv.vector_sampling.sample_at`:
Keys' cubic from 4 x 4, else bilinear from four; a position without four is left out, and the
interpolation's own smoothing is part of the difference: say so in a report, and compare on
one grid where it matters).

A comparison whose conventions are probably wrong looks like a bad tool. Before stating a
difference, :func:`compare_fields` checks what a file's conventions most often get wrong, and
``warning`` says it in one line:

- the reference's rows the other way up (OpenPIV's ``transform_coordinates``, a tool's y-up
  export): said when reading them so scatters less than half as much (the scatter is the
  median absolute deviation of du and dv about their medians, so that a bias and the wrong
  vectors of either tool do not decide it; checked when it exceeds 0.05 px);
- the positions off (MATLAB's 1-based indices, half a pixel, a window's corner for its centre):
  a reference value placed at p but measured at p + delta differs from the field by
  ``-grad(f) . delta`` plus a bias, so ``(offset_x, offset_y)`` is fitted by least squares with
  the field's own gradients and two biases, over the vectors under ``threshold``; said from
  0.25 px, at five standard errors and where it explains 30 % of the scatter or more (a flow
  without gradients leaves it undetermined: NaN);
- the field a factor other than 1 of the reference (another dt, another unit): the slope of a
  straight line (with an intercept, so that a bias leaves it at 1) off 1 by more than 10 %
  where the two correlate closely (r >= 0.99: the reference's own noise flattens the slope by
  about 1 - r^2, which at r = 0.965 made 0.87 of a field that was 1 of it).

It also warns when fewer than half of the reference's valid vectors can be compared, when one
field is corrected for the distortion and the other is not (``VectorFile.frame``), and when
the two fields' final windows differ (their differences then include the filtering of the
flow by the larger window).
"""

from __future__ import annotations

import dataclasses
import json
from typing import Any

import numpy as np

from rspiv.errors import InvalidInputError
from rspiv.vector_files import VectorFile, as_vectors
from rspiv.vector_sampling import axis_of, sample_at

__all__ = ["FieldComparison", "compare_fields", "json_ready"]

_BETTER = 0.5  # the other way up scattering under this share of the stated reading's
_NOTICE = 0.05  # px: a robust scatter under this raises no check of the rows' direction
_OFFSET = 0.25  # px: a fitted offset of the positions from this on is said
#: The factor check's correlation: the slope of a noisy reference is attenuated by about
#: 1 - r^2 (errors in both variables), under 2 % from here, well under the 10 % it looks for
_CORRELATED = 0.99


def json_ready(val: Any) -> Any:
    """``val`` with NaN and inf as None and tuples as lists, for :func:`json.dumps`."""
    if isinstance(val, float):
        return val if np.isfinite(val) else None
    if isinstance(val, dict):
        return {k: json_ready(v) for k, v in val.items()}
    if isinstance(val, (tuple, list)):
        return [json_ready(v) for v in val]
    return val


@dataclasses.dataclass(frozen=True)
class FieldComparison:
    """Differences of a field from a reference (module docstring); px over the pair.

    ``offset_x``, ``offset_y`` (px) are where the reference's vectors fit the field best
    relative to where it places them (its true positions minus its stated ones; NaN along an
    axis without varying gradients), with their standard errors ``offset_err_x``/``_y``.
    ``rows`` holds one tuple ``(y, n, mean du, mean dv, rms)`` per row of the reference's
    vectors with at least one compared; ``worst`` up to ten ``(x, y, du, dv)`` of the largest
    differences. ``warning`` is empty when nothing was seen.
    """

    reference: str
    field: str
    n_compared: int
    n_reference_valid: int
    n_field_valid: int
    interpolated: bool
    bias_u: float
    bias_v: float
    bias_err_u: float
    bias_err_v: float
    std_u: float
    std_v: float
    rms: float
    median: float
    p95: float
    threshold: float
    share_apart: float
    slope_u: float
    slope_v: float
    corr_u: float
    corr_v: float
    z_std_u: float
    z_std_v: float
    offset_x: float
    offset_y: float
    offset_err_x: float
    offset_err_y: float
    rows: tuple[tuple[float, int, float, float, float], ...]
    worst: tuple[tuple[float, float, float, float], ...]
    warning: str

    @property
    def coverage(self) -> float:
        """The share of the reference's valid vectors compared (valid in the field too)."""
        return self.n_compared / self.n_reference_valid if self.n_reference_valid else 0.0

    def to_dict(self) -> dict[str, Any]:
        """A JSON-ready dictionary (NaN as None)."""
        return json_ready(dataclasses.asdict(self))

    def to_json(self) -> str:
        """:meth:`to_dict` as JSON text."""
        return json.dumps(self.to_dict(), indent=1)

    def report(self) -> str:
        """A few lines a user reads: agreement, bias, outliers, coverage, the warning."""
        how = "interpolated to" if self.interpolated else "at"
        lines = [
            f"{self.field} against {self.reference}: {self.n_compared} vectors compared "
            f"({how} the reference's positions; {100 * self.coverage:.1f} % of its "
            f"{self.n_reference_valid} valid)",
            f"  bias du {self.bias_u:+.4f} +/- {self.bias_err_u:.4f} px, dv {self.bias_v:+.4f} "
            f"+/- {self.bias_err_v:.4f} px",
            f"  scatter: std du {self.std_u:.4f} px, dv {self.std_v:.4f} px; |d| median "
            f"{self.median:.4f}, 95th percentile {self.p95:.4f}, rms {self.rms:.4f} px",
            f"  {100 * self.share_apart:.2f} % more than {self.threshold:g} px apart"
            + (
                "; largest at (x, y) = "
                + ", ".join(f"({w[0]:.1f}, {w[1]:.1f})" for w in self.worst[:3])
                if self.worst
                else ""
            ),
            f"  straight line of field on reference: slope u {self.slope_u:.4f} (r "
            f"{self.corr_u:.3f}), v {self.slope_v:.4f} (r {self.corr_v:.3f})",
        ]
        offsets = [
            f"{o:+.3f} +/- {e:.3f} px along {axis}"
            for o, e, axis in ((self.offset_x, self.offset_err_x, "x"),
                               (self.offset_y, self.offset_err_y, "y"))
            if np.isfinite(o)
        ]  # fmt: skip
        if offsets:
            lines.append(
                "  positions: the reference fits best " + ", ".join(offsets)
                + " from where it places its vectors"
            )
        if np.isfinite(self.z_std_u) or np.isfinite(self.z_std_v):
            lines.append(
                f"  differences over their combined uncertainty: std {self.z_std_u:.2f} (u), "
                f"{self.z_std_v:.2f} (v)"
            )
        if self.warning:
            lines.append(f"  WARNING: {self.warning}")
        return "\n".join(lines)


def _gradients(f: VectorFile) -> list[np.ndarray]:
    """du/dx, du/dy, dv/dx, dv/dy of the field's valid vectors (central differences, one-sided
    of second order at its edges; NaN next to an invalid vector), px per px."""
    x0, dx, nx = axis_of(f.x[0])
    y0, dy, ny = axis_of(f.y[:, 0])
    out = []
    for a in (f.u, f.v):
        a = np.where(f.valid, a, np.nan)
        if nx < 2 or ny < 2:
            out += [np.full(a.shape, np.nan)] * 2
            continue
        gy, gx = np.gradient(a, dy, dx, edge_order=2 if min(nx, ny) > 2 else 1)
        out += [gx, gy]
    return out


@dataclasses.dataclass(frozen=True)
class _Diff:
    """The vectors compared: reference positions, flat indices into its grid, field - reference
    (du, dv), both fields' values and uncertainties there, and the field's gradients there."""

    x: np.ndarray
    y: np.ndarray
    index: np.ndarray
    du: np.ndarray
    dv: np.ndarray
    ru: np.ndarray
    rv: np.ndarray
    fu: np.ndarray
    fv: np.ndarray
    fsu: np.ndarray
    fsv: np.ndarray
    rsu: np.ndarray | None
    rsv: np.ndarray | None
    grads: tuple[np.ndarray, ...]


def _differences(ref: VectorFile, fld: VectorFile, flip: bool = False) -> _Diff:
    """Field - reference at the reference's valid vectors where the field has a value (the
    reference's rows read the other way up with ``flip``, without the field's gradients: the
    direction check needs only the differences)."""
    valid = ref.valid & np.isfinite(ref.u) & np.isfinite(ref.v)
    valid_read = valid[::-1] if flip else valid

    def pick(a: np.ndarray | None, sign: float = 1.0) -> np.ndarray | None:
        if a is None:
            return None
        return sign * (a[::-1] if flip else a)[valid_read]

    xs = ref.x[valid_read]
    ys = ref.y[valid_read]
    ru, rv = pick(ref.u), pick(ref.v, -1.0 if flip else 1.0)
    rsu, rsv = pick(ref.sigma_u), pick(ref.sigma_v)
    grads = [] if flip else _gradients(fld)
    sampled = sample_at(fld, xs, ys, [fld.u, fld.v, fld.sigma_u, fld.sigma_v, *grads])
    fu, fv = sampled[0], sampled[1]
    k = np.isfinite(fu) & np.isfinite(fv)
    return _Diff(
        x=xs[k], y=ys[k], index=np.flatnonzero(valid_read)[k], du=fu[k] - ru[k],
        dv=fv[k] - rv[k], ru=ru[k], rv=rv[k], fu=fu[k], fv=fv[k], fsu=sampled[2][k],
        fsv=sampled[3][k], rsu=None if rsu is None else rsu[k],
        rsv=None if rsv is None else rsv[k], grads=tuple(g[k] for g in sampled[4:]),
    )  # fmt: skip


def _spread(du: np.ndarray, dv: np.ndarray) -> float:
    """The differences' robust scatter about their median: hypot of the two components' median
    absolute deviations, px (a constant bias does not count, wrong vectors hardly do)."""
    if du.size == 0:
        return float("nan")
    return float(
        np.hypot(np.median(np.abs(du - np.median(du))), np.median(np.abs(dv - np.median(dv))))
    )


def _position_offset(du, dv, grads, small) -> tuple[np.ndarray, np.ndarray, float]:
    """Least-squares offset (dx, dy), px, of the reference's true positions from those it
    states, with its standard errors and the share of the differences' scatter it explains.

    A reference value stated at p but measured at p + delta differs from the field at p by
    ``-grad(f) . delta`` (plus a constant bias), so (du, dv) are fitted with the field's
    gradients and two biases over the vectors under the threshold with finite gradients. A
    component whose gradients do not vary about their mean (no gradient along it, or a
    uniform one, which a bias mimics) is not determined: NaN."""
    gux, guy, gvx, gvy = grads
    ok = small & np.isfinite(gux) & np.isfinite(guy) & np.isfinite(gvx) & np.isfinite(gvy)
    n = int(ok.sum())
    offset, err = np.full(2, np.nan), np.full(2, np.nan)
    if n < 20:
        return offset, err, 0.0
    b = np.concatenate([du[ok], dv[ok]])
    cols = []
    for k, (gu, gv) in enumerate(((gux, gvx), (guy, gvy))):
        col = -np.concatenate([gu[ok], gv[ok]])
        varying = np.concatenate([gu[ok] - gu[ok].mean(), gv[ok] - gv[ok].mean()])
        if np.sqrt(np.mean(varying**2)) > 1e-6:  # px per px
            cols.append((k, col))
    if not cols:
        return offset, err, 0.0
    bias = np.zeros((2 * n, 2))
    bias[:n, 0] = 1.0
    bias[n:, 1] = 1.0
    a = np.column_stack([c for _, c in cols] + [bias])
    # the normal equations (a few columns, 2n rows: lstsq's SVD of the whole matrix took
    # longer than the rest of a pair's comparison); rank as lstsq's default rcond decides it.
    # Products over the 2n rows by einsum, not BLAS: BLAS threads spinning between calls took
    # a core from the reader processes of a series (rspiv.compare_series)
    ata = np.einsum("ij,ik->jk", a, a)
    sing = np.sqrt(np.maximum(np.linalg.eigvalsh(ata), 0.0))
    if sing.min() <= sing.max() * np.finfo(float).eps * max(a.shape):
        return offset, err, 0.0
    inv = np.linalg.inv(ata)
    coef = inv @ np.einsum("ij,i->j", a, b)
    resid = b - np.einsum("ij,j->i", a, coef)
    rr = float(np.einsum("i,i->", resid, resid))
    var = rr / max(2 * n - a.shape[1], 1)
    cov = var * inv
    for m, (k, _) in enumerate(cols):
        offset[k] = coef[m]
        err[k] = np.sqrt(cov[m, m])
    centred = b - np.concatenate([np.full(n, du[ok].mean()), np.full(n, dv[ok].mean())])
    explained = 1.0 - rr / max(float(np.einsum("i,i->", centred, centred)), 1e-300)
    return offset, err, explained


def _block_error(d: np.ndarray, index: np.ndarray, shape: tuple[int, int], b: int = 8) -> float:
    """Standard error of the mean of ``d`` (at flat ``index`` of a grid of ``shape``) from the
    scatter of its means over blocks of ``b`` x ``b`` vectors, weighted by their counts."""
    rows, cols = np.divmod(index, shape[1])
    block = (rows // b) * ((shape[1] + b - 1) // b) + cols // b
    _, inv, counts = np.unique(block, return_inverse=True, return_counts=True)
    if counts.size < 8:
        return float("nan")
    means = np.bincount(inv, d) / counts
    w = counts / counts.sum()
    mean = float(w @ means)
    var = float(w @ (means - mean) ** 2) / (1.0 - float(w @ w))  # unbiased, weighted
    return float(np.sqrt(var * float(w @ w)))


def _rms(du: np.ndarray, dv: np.ndarray) -> float:
    return float(np.sqrt(np.mean(du**2 + dv**2))) if du.size else float("nan")


def _slope(f: np.ndarray, r: np.ndarray) -> tuple[float, float]:
    """Least-squares slope of f on r with an intercept (a bias leaves it at 1, another dt does
    not), and their correlation; NaN where r does not vary."""
    if r.size < 3 or np.std(r) == 0:
        return float("nan"), float("nan")
    # numpy's pairwise sums, not BLAS's threaded dot (_position_offset)
    rc, fc = r - r.mean(), f - f.mean()
    frc, rrc = float((fc * rc).sum()), float((rc * rc).sum())
    slope = frc / rrc
    if np.std(f) == 0:
        return slope, float("nan")
    return slope, frc / float(np.sqrt((fc * fc).sum() * rrc))


def _z_std(d: np.ndarray, sf: np.ndarray, sr: np.ndarray | None, small: np.ndarray) -> float:
    if sr is None:
        return float("nan")
    s = np.sqrt(sf**2 + sr**2)
    ok = small & np.isfinite(s) & (s > 0)
    if ok.sum() < 10:
        return float("nan")
    z = d[ok] / s[ok]
    return float(np.std(z))


def compare_fields(
    reference: Any,
    field: Any,
    *,
    threshold: float = 0.5,
) -> FieldComparison:
    """Compare ``field`` with ``reference`` at the reference's vectors (module docstring).

    Parameters
    ----------
    reference : VectorFile or PivField
        The field taken as the reference (e.g. :func:`rspiv.vector_files.read_vectors` of a
        DaVis ``.vc7``).
    field : VectorFile or PivField
        The field to compare (e.g. :func:`rspiv.piv` of the same pair).
    threshold : float
        px: vectors farther apart than this count as disagreeing (``share_apart``).

    Returns
    -------
    FieldComparison

    Raises
    ------
    InvalidInputError
        Not fields, a threshold that is not positive, or no vector valid in both.
    """
    ref = as_vectors(reference, "reference")
    fld = as_vectors(field, "field")
    if not (np.isfinite(threshold) and threshold > 0):
        raise InvalidInputError(f"compare: threshold {threshold} px must be positive")
    comparison, _ = compare_with_differences(ref, fld, threshold)
    return comparison


def compare_with_differences(
    ref: VectorFile, fld: VectorFile, threshold: float
) -> tuple[FieldComparison, _Diff]:
    """:func:`compare_fields` of two :class:`VectorFile`, and the vectors it compared (for
    :func:`rspiv.compare_series.compare_series`, which sums them over the pairs)."""
    for f in (ref, fld):
        if not f.origin_known:  # a calibrated PIVlab export: vectors would pair wrongly
            raise InvalidInputError(
                f"compare: {f.path}: its positions are the recording's px only up to its "
                "calibration's offset (a calibrated export): export it in px to compare"
            )
    d = _differences(ref, fld)
    x, y, du, dv = d.x, d.y, d.du, d.dv
    n = du.size
    n_ref = int((ref.valid & np.isfinite(ref.u)).sum())
    n_fld = int((fld.valid & np.isfinite(fld.u)).sum())
    if n == 0:
        raise InvalidInputError(
            f"compare: no vector of {fld.path} valid where {ref.path} has a valid one "
            f"({n_ref} and {n_fld} valid; do the two cover the same part of the frame?)"
        )
    interpolated = not (
        set(np.round(ref.x[0], 2)) <= set(np.round(fld.x[0], 2))
        and set(np.round(ref.y[:, 0], 2)) <= set(np.round(fld.y[:, 0], 2))
    )
    mag = np.hypot(du, dv)
    rms = _rms(du, dv)
    apart = mag > threshold
    top = min(10, int(apart.sum()))  # the largest, without sorting every vector
    at_top = np.argpartition(mag, mag.size - top)[mag.size - top :] if top else np.zeros(0, int)
    order = at_top[np.argsort(mag[at_top], kind="stable")[::-1]]
    worst = tuple((float(x[i]), float(y[i]), float(du[i]), float(dv[i])) for i in order)
    su, cu = _slope(d.fu, d.ru)
    sv, cv = _slope(d.fv, d.rv)
    ys, at = np.unique(y, return_inverse=True)  # per row: one pass of sums, not a mask a row
    cnt = np.bincount(at, minlength=ys.size)
    sums = [np.bincount(at, w, minlength=ys.size) for w in (du, dv, du**2 + dv**2)]
    rows = [
        (float(yy), int(c), float(su / c), float(sv / c), float(np.sqrt(sq / c)))
        for yy, c, su, sv, sq in zip(ys, cnt, *sums, strict=True)
    ]
    small = ~apart
    warnings: list[str] = []
    median = float(np.median(mag))
    spread = _spread(du, dv)
    if spread > _NOTICE:
        flipped = _differences(ref, fld, flip=True)
        alt = _spread(flipped.du, flipped.dv)
        if flipped.du.size >= (3 * n) // 4 and alt < _BETTER * spread:
            warnings.append(
                f"the differences scatter by {spread:.3g} px as read, {alt:.3g} px with the "
                "reference's rows the other way up (y and v turned: --y-up): check the files' "
                "conventions before the tools"
            )
    offset, offset_err, explained = _position_offset(du, dv, d.grads, small)
    known = np.isfinite(offset)
    if (
        known.any()
        and np.linalg.norm(offset[known]) >= _OFFSET
        and np.linalg.norm(offset[known] / offset_err[known]) >= 5.0
        and explained >= 0.3
    ):
        said = " and ".join(
            f"{offset[k]:+.2f} +/- {offset_err[k]:.2f} px along {'xy'[k]}" for k in (0, 1)
            if known[k]
        )  # fmt: skip
        warnings.append(
            f"the reference's vectors fit the field best {said} from where it places them "
            f"({100 * explained:.0f} % of the scatter): 1-based indices, half a pixel or a "
            "window's corner? check the positions' convention"
        )
    for name, s, c in (("u", su, cu), ("v", sv, cv)):
        if np.isfinite(s) and np.isfinite(c) and c >= _CORRELATED and abs(s - 1) > 0.1:
            warnings.append(
                f"the field's {name} is {s:.3g} times the reference's (r = {c:.3f}): "
                "another dt or unit?"
            )
    if n_ref and n < 0.5 * n_ref:
        warnings.append(
            f"only {n} of the reference's {n_ref} valid vectors compared "
            f"({100 * n / n_ref:.0f} %): the rest are invalid in the field or outside it"
        )
    if {ref.frame, fld.frame} == {"image", "object"}:
        warnings.append(
            f"the field is in the {fld.frame} frame and the reference in the {ref.frame} frame "
            "(one corrected for the distortion, one not): their positions and displacements "
            "differ by the distortion; compare runs of one frame (a campaign's uncorrected run)"
        )
    if ref.window is not None and fld.window is not None and ref.window != fld.window:
        warnings.append(
            f"final windows differ ({fld.window[0]} x {fld.window[1]} against "
            f"{ref.window[0]} x {ref.window[1]} px): the differences include the larger "
            "window's filtering of the flow"
        )
    return FieldComparison(
        reference=ref.path, field=fld.path, n_compared=int(n), n_reference_valid=n_ref,
        n_field_valid=n_fld, interpolated=bool(interpolated),
        bias_u=float(du.mean()), bias_v=float(dv.mean()),
        bias_err_u=_block_error(du, d.index, ref.u.shape),
        bias_err_v=_block_error(dv, d.index, ref.u.shape),
        std_u=float(du.std(ddof=1)) if n > 1 else float("nan"),
        std_v=float(dv.std(ddof=1)) if n > 1 else float("nan"),
        rms=rms, median=median, p95=float(np.percentile(mag, 95)),
        threshold=float(threshold), share_apart=float(apart.mean()), slope_u=su, slope_v=sv,
        corr_u=cu, corr_v=cv,
        z_std_u=_z_std(du, d.fsu, d.rsu, small), z_std_v=_z_std(dv, d.fsv, d.rsv, small),
        offset_x=float(offset[0]), offset_y=float(offset[1]),
        offset_err_x=float(offset_err[0]), offset_err_y=float(offset_err[1]),
        rows=tuple(rows), worst=worst, warning="; ".join(warnings),
    ), d  # fmt: skip
