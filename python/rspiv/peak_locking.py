"""Peak locking measured from the displacements themselves.

:meth:`rspiv.PivField.peak_locking` predicts peak locking from the particle images' diameter
(under 2 px). Other causes flatten a correlation peak just as well and leave the diameter
alone: particle images saturated by a strong laser pulse or a high gain (clipped at 30 % or 15
% of their peak, 2.5 px images read 3.0-3.3 px across and lock with an amplitude of 0.009-0.011
px on synthetic pairs), a sensor's fill factor, a compression. This module measures the lean
towards whole pixels in a field's (or a campaign's) own displacements, as PIV users read it
from their histograms (Christensen 2004, Exp. Fluids 36: 484-497).

The model
    A measured displacement ``x = t - a sin(2 pi t)`` of a true displacement ``t`` (the bias of
    :meth:`rspiv.PivField.peak_locking`, amplitude ``a`` px, positive towards whole pixels)
    makes the density of the measured displacements ``rho(x) (1 + 2 pi a cos(2 pi x))`` to
    first order in ``a``, where ``rho`` is the density of the true ones.

The estimate (:func:`locking_amplitude`)
    The valid displacements of u and of v are counted in bins of 1/20 px aligned with whole
    pixels. Each bin is held against the mean of the bins one pixel wide about it, which
    averages a period of one pixel out and keeps ``rho`` where ``rho`` is smooth over a pixel:
    bins where the density's curvature over a pixel exceeds :data:`MAX_CURVATURE` of it
    anywhere within half a pixel (a
    free stream whose displacements lie within a few tenths of a pixel, the narrow v of a
    boundary layer, the ends of the range) or whose mean count is under
    :data:`MIN_BIN_COUNT` are passed over. The ratio's cosine term, fitted by weighted least
    squares over the bins left of both components (with a sine term and a constant), is ``2
    pi a``. At least :data:`MIN_SMOOTH_PX` px of smooth density are needed, else NaN.

    The bins' own Poisson scatter is allowed for in the curvature (three of its standard
    deviations). On synthetic displacements with an imposed bias (uniform, or a boundary layer's
    u over its height beside its narrow v) ``a`` is recovered within 0.001 px; on synthetic PIV
    pairs the estimate reads 1.0-1.4 times the amplitude fitted against the exact
    displacements (0.0003 against 0.0008 px at 2.5 px particle images, 0.017 against 0.013 px
    at 1.5 px, 0.015 against 0.011 px with 2.5 px images clipped at 15 % of their peak;
    ``tests/test_peak_locking.py``).

Over a campaign (:class:`LockingHistogram`)
    Each pair's estimate per run is among the pair's figures
    (:func:`rspiv.campaign.pair_quality.measure`, ``locking`` in ``pairs_<run>.csv``). Each
    run's counts are also summed over its pairs (:class:`LockingHistogram`, carried beside the
    statistics through checkpoints, shards and Dask), in :data:`BATCHES` batches by pair id:
    the run's amplitude is that of the pooled counts (it tells where a field of a few thousand
    vectors alone cannot), its standard error the batches' scatter over the square root of
    their number (the vectors of a field are not independent; three batches that tell are
    needed). A checkpoint written before the counts falls back to the mean of the pairs' own
    figures (:func:`campaign_locking`). It is said
    (:data:`LOCKING_SAID_PX` or more, at :data:`LOCKING_SIGMAS` standard errors or more) for a
    run that correlates in its own frame (the uncorrected run, Method I); Method II maps the
    image frame's displacements by the mapping's Jacobian, which blurs the pattern where it is
    far from the identity: its figure is a lower bound.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from rspiv.errors import InvalidInputError

__all__ = [
    "BATCHES",
    "BINS_PER_PX",
    "LOCKING_SAID_PX",
    "LOCKING_SIGMAS",
    "MAX_CURVATURE",
    "MAX_NOISE",
    "MIN_BIN_COUNT",
    "MIN_SMOOTH_PX",
    "NBINS",
    "LockingHistogram",
    "campaign_locking",
    "exact_amplitude",
    "locking_amplitude",
    "locking_said",
]

#: Bins per px of the displacements' histogram (aligned with whole pixels).
BINS_PER_PX = 20
#: A bin enters where the density's curvature over a pixel (its one-pixel means half a pixel
#: either side, less twice its own) is at most this share of it.
MAX_CURVATURE = 0.1
#: ... plus three standard deviations of the counts' scatter, up to this much (a density
#: sampled too thinly to hold its curvature under ``MAX_CURVATURE + MAX_NOISE`` is passed
#: over: a shape that varies within a pixel would otherwise be read as locking).
MAX_NOISE = 0.1
#: ... and where its one-pixel mean holds at least this many vectors per bin.
MIN_BIN_COUNT = 5.0
#: Px of smooth density (u and v together) needed for an estimate.
MIN_SMOOTH_PX = 2.0
#: Displacements beyond this (px) are not counted (the histograms' length: a campaign's
#: :class:`LockingHistogram` holds 655 kB per run, carried in every checkpoint).
MAX_PX = 128.0
#: A campaign's amplitude at or above this (px) ...
LOCKING_SAID_PX = 0.005
#: ... and at this many standard errors or more is said.
LOCKING_SIGMAS = 3.0
#: A campaign's counts are kept in this many batches of pairs (by pair id) for their error.
BATCHES = 8
#: Bins of a :class:`LockingHistogram` (over +-MAX_PX px).
NBINS = int(2 * MAX_PX * BINS_PER_PX)


def locking_amplitude(u: Any, v: Any = None, valid: Any = None) -> float:
    """The amplitude ``a`` (px) of the bias ``-a sin(2 pi t)`` towards whole pixels in the
    displacements ``u`` (and ``v``) of the ``valid`` vectors (module docstring; positive
    towards whole pixels); NaN where under :data:`MIN_SMOOTH_PX` px of their density is smooth
    enough to tell.

    Parameters
    ----------
    u, v : array_like
        Displacements (px), any shape, the same for both; ``v`` may be None. NaN and inf are
        passed over.
    valid : array_like of bool, optional
        The vectors to count (default: every finite one).

    Raises
    ------
    InvalidInputError
        ``v`` or ``valid`` of another shape than ``u``, or not numbers.
    """
    u, v, ok = _arrays(u, v, valid)
    return _estimate([_histogram(d, ok) for d in (u, v) if d is not None])


def _arrays(u: Any, v: Any, valid: Any) -> tuple[np.ndarray, np.ndarray | None, np.ndarray]:
    """``u``, ``v`` (None stays None) as float64 and ``valid`` as bool (default: all), checked
    to be numbers of one shape (InvalidInputError)."""
    try:
        u = np.asarray(u, np.float64)
        ok = np.ones(u.shape, bool) if valid is None else np.asarray(valid, bool)
        v = None if v is None else np.asarray(v, np.float64)
    except (TypeError, ValueError) as exc:
        raise InvalidInputError(f"u, v, valid: expected arrays of numbers ({exc})") from None
    if (v is not None and v.shape != u.shape) or ok.shape != u.shape:
        got = [u.shape, None if v is None else v.shape, ok.shape]
        raise InvalidInputError(f"u, v, valid: expected one shape, got {got}")
    return u, v, ok


def _histogram(d: np.ndarray, ok: np.ndarray) -> tuple[np.ndarray, int]:
    """Counts of the finite ``d[ok]`` within :data:`MAX_PX` in bins of 1/:data:`BINS_PER_PX`
    px, bin ``j`` starting at ``(j + k0) / BINS_PER_PX`` px: ``(counts, k0)``, a pixel of empty
    bins either side."""
    x = d[ok & np.isfinite(d) & (np.abs(d) < MAX_PX)]
    if x.size == 0:
        return np.zeros(0, np.int64), 0
    k = np.floor(x * BINS_PER_PX).astype(np.int64)
    k0 = int(k.min()) - BINS_PER_PX
    return np.bincount(k - k0, minlength=int(k.max()) - k0 + BINS_PER_PX + 1), k0


def _estimate(hists: list[tuple[np.ndarray, int]]) -> float:
    """The amplitude (px) from histograms ``(counts, k0)`` (:func:`_histogram`) of u and v
    (module docstring), NaN under :data:`MIN_SMOOTH_PX` px of smooth density."""
    ratio, cos, sin, weight = [], [], [], []
    half = BINS_PER_PX // 2
    # the mean over one pixel centred on a bin (BINS_PER_PX + 1 taps, halves at the ends)
    box = np.r_[0.5, np.ones(BINS_PER_PX - 1), 0.5] / BINS_PER_PX
    for counts, k0 in hists:
        if not counts.any():
            continue
        h = counts.astype(np.float64)
        env = np.convolve(h, box, mode="same")
        below = np.r_[np.full(half, np.inf), env[:-half]]
        above = np.r_[env[half:], np.full(half, np.inf)]
        with np.errstate(invalid="ignore", divide="ignore"):
            # less the counts' own scatter: three of its standard deviations (a one-pixel mean
            # of Poisson counts; the curvature sums six of them)
            noise = np.minimum(3.0 * np.sqrt(6.0 / (BINS_PER_PX * env)), MAX_NOISE)
            curv = np.abs(above + below - 2 * env) / env - noise
        # the largest over the pixel about the bin: a density whose curvature passes through
        # zero (a narrow Gaussian's inflection) is not smooth there
        curv = np.nan_to_num(curv, nan=np.inf)
        worst = np.lib.stride_tricks.sliding_window_view(
            np.r_[np.full(half, np.inf), curv, np.full(half, np.inf)], 2 * half + 1
        ).max(axis=1)
        smooth = (worst <= MAX_CURVATURE) & (env >= MIN_BIN_COUNT)
        idx = np.flatnonzero(smooth)
        t = (idx + k0 + 0.5) / BINS_PER_PX  # the bins' centres, px
        ratio.append(h[idx] / env[idx])
        cos.append(np.cos(2 * np.pi * t))
        sin.append(np.sin(2 * np.pi * t))
        weight.append(env[idx])  # a bin's count is Poisson: the ratio's variance is 1 / env
    n = sum(r.size for r in ratio)
    if n < MIN_SMOOTH_PX * BINS_PER_PX:
        return float("nan")
    r, c, s, w = (np.concatenate(p) for p in (ratio, cos, sin, weight))
    sw = np.sqrt(w)
    design = np.stack([np.ones(n), c, s], 1) * sw[:, None]
    coef = np.linalg.lstsq(design, r * sw, rcond=None)[0]
    return float(coef[1] / (2 * np.pi))


def exact_amplitude(true: Any, measured: Any) -> float:
    """The amplitude ``a`` (px) of the bias ``-a sin(2 pi t)`` of ``measured`` displacements
    against the ``true`` ones ``t`` (a least-squares fit of the error to a constant, ``sin`` and
    ``cos`` of ``2 pi t``): the reference :func:`locking_amplitude` is checked against, where
    the exact displacements are known (synthetic images).

    Raises
    ------
    InvalidInputError
        Arrays of different sizes, or fewer than three values.
    """
    t = np.ravel(np.asarray(true, np.float64))
    m = np.ravel(np.asarray(measured, np.float64))
    if t.size != m.size or t.size < 3:
        raise InvalidInputError(
            f"true, measured: expected as many values, at least 3, got {t.size} and {m.size}"
        )
    design = np.stack([np.ones_like(t), np.sin(2 * np.pi * t), np.cos(2 * np.pi * t)], 1)
    return float(-np.linalg.lstsq(design, m - t, rcond=None)[0][1])


def campaign_locking(values: Any) -> dict[str, Any]:
    """A run's peak locking from its pairs' :func:`locking_amplitude` (module docstring).

    Returns
    -------
    dict
        ``amplitude_px`` (the mean, None without a pair that could tell), ``standard_error_px``
        (None under 3 pairs), ``pairs`` (those that could tell) and ``said`` (bool); with no
        pair that could tell, a ``note`` saying why.
    """
    a = np.asarray(values, np.float64).ravel()
    a = a[np.isfinite(a)]
    if a.size == 0:
        return {
            "amplitude_px": None, "standard_error_px": None, "pairs": 0, "said": False,
            "note": "the displacements do not spread smoothly enough over whole pixels to tell "
            "(too few vectors, or displacements within a pixel or two)",
        }  # fmt: skip
    mean = float(a.mean())
    se = float(a.std(ddof=1) / np.sqrt(a.size)) if a.size >= 3 else None
    said = se is not None and mean >= LOCKING_SAID_PX and mean >= LOCKING_SIGMAS * se
    return {
        "amplitude_px": round(mean, 5),
        "standard_error_px": None if se is None else round(se, 5),
        "pairs": int(a.size),
        "said": bool(said),
    }


def locking_said(runs: Any, locking: dict[str, dict[str, Any]]) -> tuple[str | None, str]:
    """The run a campaign's peak locking is judged on, and its one-line warning ("" when not
    said): the first of ``runs`` (:class:`rspiv.campaign.spec.RunSpec`) that correlates in its
    own frame (uncorrected, Method I) with an amplitude in ``locking`` (run name ->
    :func:`campaign_locking`), else the first with one (Method II: a lower bound)."""
    have = [r for r in runs if (locking.get(r.name) or {}).get("amplitude_px") is not None]
    if not have:
        return None, ""
    own = [r for r in have if r.method in ("none", "I")]
    run = (own or have)[0]
    got = locking[run.name]
    if not got["said"]:
        return run.name, ""
    bound = "" if own else " (a lower bound: Method II maps the image frame's displacements)"
    return run.name, (
        f"peak locking measured: the {run.label} displacements lean towards whole pixels, a bias "
        f"of amplitude {got['amplitude_px']:.3f} +- {got['standard_error_px']:.3f} px over "
        f"{got['pairs']} pairs{bound}; it does not average out (the mean, v'v' and the PDFs "
        "carry it): particle images under 2 px or saturated, defocus slightly or lower the "
        "laser or the gain, or smooth the frames ([preprocess] smooth)"
    )


class LockingHistogram:
    """A run's valid displacements counted over its pairs (u and v apart, in bins of
    1/:data:`BINS_PER_PX` px over +-:data:`MAX_PX` px), in :data:`BATCHES` batches by pair id:
    the amplitude of the pooled counts tells where one field is sampled too thinly, the
    batches' scatter gives its error (module docstring). Streamed and merged exactly (a
    campaign's checkpoints, shards and Dask chunks carry it beside the statistics).

    Attributes
    ----------
    counts : ndarray of int64, shape (BATCHES, 2, NBINS)
        Per batch, u (0) and v (1): the vectors in bin ``j``, which starts at ``(j - NBINS //
        2) / BINS_PER_PX`` px.
    pair_ids : set of int
    n_fields : int
    """

    def __init__(self) -> None:
        self.counts = np.zeros((BATCHES, 2, NBINS), np.int64)
        self.pair_ids: set[int] = set()
        self.n_fields = 0

    def add(self, u: Any, v: Any = None, valid: Any = None, pair_id: int | None = None) -> None:
        """Count one field's valid vectors, in batch ``pair_id % BATCHES`` (without an id, the
        fields' count's).

        Raises
        ------
        InvalidInputError
            Arrays of different shapes or not numbers, or a pair added before.
        """
        if pair_id is not None and int(pair_id) in self.pair_ids:
            raise InvalidInputError(f"locking: pair {pair_id} was added before")
        u, v, ok = _arrays(u, v, valid)
        batch = (self.n_fields if pair_id is None else int(pair_id)) % BATCHES
        for c, d in enumerate((u, v)):
            if d is None:
                continue
            counts, k0 = _histogram(d, ok)
            j = k0 + NBINS // 2  # the empty pixel either side may reach past the ends
            lo, hi = max(-j, 0), min(counts.size, NBINS - j)
            if hi > lo:
                self.counts[batch, c, j + lo : j + hi] += counts[lo:hi]
        self.n_fields += 1
        if pair_id is not None:
            self.pair_ids.add(int(pair_id))

    def __getstate__(self) -> dict[str, Any]:
        """Pickled with the bins that hold counts only (a checkpoint is written every few
        pairs)."""
        held = np.flatnonzero(self.counts.any(axis=(0, 1)))
        lo, hi = (int(held[0]), int(held[-1]) + 1) if held.size else (0, 0)
        state = self.__dict__.copy()
        state["counts"] = (lo, self.counts[:, :, lo:hi].copy())
        return state

    def __setstate__(self, state: dict[str, Any]) -> None:
        lo, held = state.pop("counts")
        self.__dict__.update(state)
        self.counts = np.zeros((BATCHES, 2, NBINS), np.int64)
        self.counts[:, :, lo : lo + held.shape[2]] = held

    def merge(self, other: LockingHistogram) -> LockingHistogram:
        """Add ``other``'s counts (no pair in both); returns self."""
        common = self.pair_ids & other.pair_ids
        if common:
            raise InvalidInputError(f"locking: pair {min(common)} in both parts")
        self.counts += other.counts
        self.pair_ids |= other.pair_ids
        self.n_fields += other.n_fields
        return self

    def result(self) -> dict[str, Any]:
        """The run's peak locking: :func:`campaign_locking`'s keys, the amplitude from the
        pooled counts and its standard error from the batches' amplitudes (their scatter over
        the square root of their number, three batches or more that tell); ``batches`` those
        that tell."""
        pooled = _estimate(_trimmed(self.counts.sum(axis=0)))
        each = np.array([_estimate(_trimmed(b)) for b in self.counts if b.any()])
        each = each[np.isfinite(each)]
        pairs = len(self.pair_ids) or self.n_fields
        if not np.isfinite(pooled):
            return {**campaign_locking([]), "pairs": pairs, "batches": 0}
        se = float(each.std(ddof=1) / np.sqrt(each.size)) if each.size >= 3 else None
        said = se is not None and pooled >= LOCKING_SAID_PX and pooled >= LOCKING_SIGMAS * se
        out = {
            "amplitude_px": round(pooled, 5),
            "standard_error_px": None if se is None else round(se, 5),
            "pairs": pairs,
            "batches": int(each.size),
            "said": bool(said),
        }
        if se is None:
            out["note"] = (
                f"no standard error: {each.size} of the {BATCHES} batches of pairs tell on their "
                "own, 3 are needed (more pairs give one)"
            )
        return out

    def to_dataset_vars(self) -> tuple[dict, dict]:
        """``(variables, attrs)`` to write beside a FieldAccumulator's (``locking_counts``)."""
        dims = ("locking_batch", "locking_component", "locking_bin")
        return {"locking_counts": (dims, self.counts)}, {"locking_fields": int(self.n_fields)}

    @classmethod
    def from_dataset_vars(cls, ds: Any, pair_ids: Any) -> LockingHistogram:
        """Read back :meth:`to_dataset_vars` (the pairs are the statistics')."""
        acc = cls()
        counts = np.asarray(ds["locking_counts"].values, np.int64)
        if counts.shape != acc.counts.shape:
            raise InvalidInputError(
                f"locking_counts: shape {counts.shape}, this rspiv counts {acc.counts.shape}"
            )
        acc.counts = counts.copy()
        acc.n_fields = int(ds.attrs.get("locking_fields", 0))
        acc.pair_ids = {int(i) for i in pair_ids}
        return acc


def _trimmed(counts: np.ndarray) -> list[tuple[np.ndarray, int]]:
    """:class:`LockingHistogram` counts ``(2, NBINS)`` as :func:`_estimate`'s histograms, cut
    to the bins held and a pixel either side."""
    out = []
    for row in counts:
        nz = np.flatnonzero(row)
        if nz.size == 0:
            continue
        lo = max(int(nz[0]) - BINS_PER_PX, 0)
        hi = min(int(nz[-1]) + BINS_PER_PX + 1, row.size)
        out.append((row[lo:hi], lo - NBINS // 2))
    return out
