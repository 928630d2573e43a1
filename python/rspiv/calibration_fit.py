"""The fit of a calibration: model comparison by held-out (leave-one-out) error, the choice
of the model, the magnification from the central marker's neighbours, and the check that the
fit follows the markers to their precision (used by :mod:`rspiv.calibration`).

Residuals and sigmas are per axis (the RMS over x and y), px.
"""

from __future__ import annotations

import warnings
from typing import Any

import numpy as np
import numpy.typing as npt

from rspiv import _rspiv
from rspiv.errors import InvalidInputError, RspivError
from rspiv.mapping import MODELS, Mapping, fit_mapping

__all__ = [
    "MIN_POINTS",
    "N_PARAMS",
    "check_fit",
    "choose_model",
    "compare_models",
    "fit_stats",
    "lattice_outliers",
    "touching_dots",
    "magnification",
]

# Points each model needs and its free coefficients (dewarp_core::Model::min_points, n_params).
MIN_POINTS = {"r1": 5, "r2": 9, "p3": 11}
N_PARAMS = {"r1": 8, "r2": 17, "p3": 20}
# Fit-quality limits (residual RMS against the markers' image sigma, both per axis, px): above
# max(REFUSE_FACTOR * sigma, REFUSE_FLOOR_PX) a calibration is refused unless accept_poor_fit;
# above WARN_FACTOR * sigma it is kept with a warning.
REFUSE_FACTOR = 10.0
REFUSE_FLOOR_PX = 0.5
WARN_FACTOR = 3.0
# Neighbours of the central marker that give the magnification: those within this factor of
# the nearest one's distance on the target (on a square grid: the four axial neighbours).
NEIGHBOUR_SHELL = 1.2
# Isolated outliers: markers whose miss of their neighbours' prediction exceeds this many robust
# standard deviations of all the misses, at most OUTLIER_SHARE of the markers (or 2).
OUTLIER_FACTOR = 8.0
OUTLIER_SHARE = 0.01


#: Up to this many markers the held-out error is leave-one-out; above, K-fold with HELD_OUT_FOLDS
#: folds (each marker still held out once; the cost stays K fits instead of n).
LOO_MAX_POINTS = 200
HELD_OUT_FOLDS = 20


def _loo_rms(obj: np.ndarray, img: np.ndarray, centre: int, model: str, scale: float) -> float:
    """RMS held-out error (px): each non-central marker predicted by a fit without it
    (leave-one-out up to :data:`LOO_MAX_POINTS` markers, else :data:`HELD_OUT_FOLDS`-fold
    cross-validation over a fixed shuffle; the central marker stays in every fit)."""
    n = len(obj)
    others = np.flatnonzero(np.arange(n) != centre)
    if n <= LOO_MAX_POINTS:
        folds = [others[k : k + 1] for k in range(len(others))]
    else:
        order = np.random.default_rng(0).permutation(others)
        folds = [order[f::HELD_OUT_FOLDS] for f in range(HELD_OUT_FOLDS)]
    errs = []
    for out in folds:
        keep = np.ones(n, dtype=bool)
        keep[out] = False
        c = centre - int(np.count_nonzero(out < centre))
        m = fit_mapping(obj[keep], img[keep], model, center_index=c, scale=scale)
        errs.append(np.sum((m.forward(obj[out]) - img[out]) ** 2, axis=1))
    return float(np.sqrt(np.mean(np.concatenate(errs))))


def compare_models(
    object_px: npt.ArrayLike,
    image_px: npt.ArrayLike,
    centre: int,
    models: tuple[str, ...] = MODELS,
) -> dict[str, dict[str, Any]]:
    """Fit each model and measure its residuals and its held-out error (leave-one-out, or
    K-fold for large targets: see :func:`_loo_rms`).

    Returns ``{model: {"max_abs_px", "mean_px", "rms_px", "loo_rms_px"}}`` for the models that
    have enough markers; models that cannot be fitted are left out.
    """
    obj = np.asarray(object_px, dtype=np.float64)
    img = np.asarray(image_px, dtype=np.float64)
    scale = float(np.max(np.abs(obj[:, 0])))
    out: dict[str, dict[str, Any]] = {}
    for model in models:
        try:
            m = fit_mapping(obj, img, model, center_index=centre, scale=scale)
            loo = _loo_rms(obj, img, centre, model, scale)
        except RspivError:
            continue
        out[model] = fit_stats(m, loo)
    return out


def fit_stats(m: Mapping, loo: float | None) -> dict[str, Any]:
    """A fit's residual statistics (px) and its held-out RMS (None: not computed)."""
    st = m.stats
    return {
        "max_abs_px": [float(v) for v in st["max_abs_px"]],
        "mean_px": [float(v) for v in st["mean_px"]],
        "rms_px": [float(v) for v in st["rms_px"]],
        "loo_rms_px": loo,
    }


def choose_model(model: str, models: dict[str, dict[str, Any]], what: str) -> tuple[str, str]:
    """The model to fit and why: the user's, or (``"auto"``) the smallest held-out error
    among ``models`` (:func:`compare_models`); InvalidInputError when ``"auto"`` finds no
    model (``what``: the points, for the message)."""
    if model == "auto":
        if not models:
            raise InvalidInputError(f"calibration: no model can be fitted to {what}")
        ranked = sorted(models, key=lambda m: models[m]["loo_rms_px"])
        return ranked[0], "smallest held-out error: " + " < ".join(
            f"{m} {models[m]['loo_rms_px']:.4f} px" for m in ranked
        )
    reason = "chosen by the user"
    if model in models and len(models) > 1:
        best = min(models, key=lambda m: models[m]["loo_rms_px"])
        if best != model:
            reason += f" (note: {best} has a smaller held-out error)"
    return model, reason


def magnification(
    image_px: np.ndarray, object_mm: np.ndarray, centre: int, one: str
) -> tuple[float, float, float]:
    """M (px/mm) as the mean ratio image distance / target distance from the central point to
    its nearest neighbours on the target (those within ``NEIGHBOUR_SHELL`` x the nearest one's
    distance, at least two; on a square grid the four axial neighbours), the standard deviation
    of those ratios, and the nearest neighbour's distance (mm). ``one``: "marker" or "point",
    for the message of the InvalidInputError raised when there are fewer than 2 neighbours."""
    d_obj = np.hypot(*(object_mm - object_mm[centre]).T)
    d_obj[centre] = np.inf
    order = np.argsort(d_obj, kind="stable")
    nearest = float(d_obj[order[0]])
    near = order[d_obj[order] <= NEIGHBOUR_SHELL * nearest]
    if len(near) < 2:
        near = order[:2]
    if len(near) < 2 or not np.all(np.isfinite(d_obj[near])):
        raise InvalidInputError(f"calibration: the central {one} has fewer than 2 neighbours")
    ratios = np.hypot(*(image_px[near] - image_px[centre]).T) / d_obj[near]
    return float(np.mean(ratios)), float(np.std(ratios, ddof=1)), nearest


def check_fit(
    model: str,
    rms: float,
    sigma: float,
    what: str,
    pitch_px: float,
    accept_poor_fit: bool,
) -> list[str]:
    """Check that a fit follows the markers to their precision.

    Parameters
    ----------
    model : str
        The fitted model.
    rms : float
        RMS of its residuals (per axis, px).
    sigma : float
        The noise the residuals are held to (per axis, px): the markers' typical image sigma
        (median), combined in quadrature with the target's own errors when stated
        (``pitch_sigma_mm * M``).
    what : str
        The points, for the message (``"91 indexed markers"``).
    pitch_px : float
        The lattice pitch at the centre (px), for the message.
    accept_poor_fit : bool
        Keep (with a warning) a fit that would be refused.

    Returns
    -------
    list of str
        The warning to record (empty, or one line): ``rms`` above ``WARN_FACTOR`` x ``sigma``,
        or a poor fit kept.

    Raises
    ------
    InvalidInputError
        ``rms`` above ``max(REFUSE_FACTOR * sigma, REFUSE_FLOOR_PX)`` and not
        ``accept_poor_fit``: one line saying what was seen.
    """
    seen = (
        f"{model} leaves {rms:.3g} px RMS residuals against a marker sigma of {sigma:.3g} px "
        f"over {what} (lattice pitch {pitch_px:.1f} px)"
    )
    if rms > max(REFUSE_FACTOR * sigma, REFUSE_FLOOR_PX):
        why = (
            f"this is not a flat target {model} can follow (an oblique view? particles? mixed "
            f"plate levels? a distortion beyond {model}? errors of the target itself: state "
            "them with pitch_sigma_mm)"
        )
        if not accept_poor_fit:
            raise InvalidInputError(
                f"calibration refused: {seen}: {why}; pass accept_poor_fit=True "
                "(rspiv calibrate --accept-poor-fit) to keep it"
            )
        return [f"poor fit kept (accept_poor_fit=True): {seen}: {why}"]
    if rms > WARN_FACTOR * sigma:
        return [
            f"{seen}, {rms / sigma:.1f} x the sigma: the model follows the target less closely "
            f"than the markers' precision (a distortion beyond {model}? a slightly oblique "
            "view? a few misplaced markers?)"
        ]
    return []


def _neighbour_miss(grid: np.ndarray) -> np.ndarray:
    """Each site's miss of the position its lattice neighbours predict (NaN where there is no
    marker or no prediction): the mean of the midpoints of its neighbours on either side along
    u and along v; at an edge, the extrapolations from the two sites behind."""
    nu, nv, _ = grid.shape
    pad = np.full((nu + 4, nv + 4, 2), np.nan)
    pad[2:-2, 2:-2] = grid

    def at(du: int, dv: int) -> np.ndarray:
        return pad[2 + du : 2 + du + nu, 2 + dv : 2 + dv + nv]

    with np.errstate(invalid="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN means: no prediction
        mids = np.stack([0.5 * (at(-1, 0) + at(1, 0)), 0.5 * (at(0, -1) + at(0, 1))])
        pred = np.nanmean(mids, axis=0)
        ext = np.stack([2 * at(d, 0) - at(2 * d, 0) for d in (-1, 1)]
                       + [2 * at(0, d) - at(0, 2 * d) for d in (-1, 1)])  # fmt: skip
        pred = np.where(np.isnan(pred), np.nanmean(ext, axis=0), pred)
    return np.hypot(*(grid - pred).transpose(2, 0, 1))


def lattice_outliers(index: npt.ArrayLike, image_px: npt.ArrayLike) -> tuple[np.ndarray, float]:
    """Isolated markers that disagree with their lattice neighbours (a dot half hidden by the
    plate's edge, a glint on it, a dot cut by the image's border).

    Each marker's miss is its distance from the position its neighbours predict (the mean of the
    midpoints of its neighbours on either side along u and v; at an edge, extrapolations from
    two sites behind): a local second difference, which a smooth distortion keeps small. The
    scale is the misses' robust standard deviation (``1.4826 x`` their median). The marker of
    the largest miss beyond :data:`OUTLIER_FACTOR` scales is taken out and the misses computed
    again (its neighbours' predictions no longer see it), until none is beyond. When that would
    take out more than ``max(2, OUTLIER_SHARE n)`` markers, none is: that is no isolated outlier
    but a lattice that bends faster than its neighbours follow (a strong distortion, mixed
    depths), which the fit's own check must see, not have hidden.

    Returns the outliers' rows and the scale (px); no rows below 30 markers.
    """
    uv = np.asarray(index, dtype=np.float64).reshape(-1, 2)
    px = np.asarray(image_px, dtype=np.float64).reshape(-1, 2)
    n = len(uv)
    if n < 30:
        return np.zeros(0, dtype=np.int64), 0.0
    ij = np.rint(uv - uv[0]).astype(np.int64)  # (an origin between sites shifts them all alike)
    ij -= ij.min(axis=0)
    grid = np.full((*(ij.max(axis=0) + 1), 2), np.nan)
    grid[ij[:, 0], ij[:, 1]] = px
    miss = _neighbour_miss(grid)
    scale = 1.4826 * float(np.nanmedian(miss)) / np.sqrt(2.0)  # per axis, from the 2-D misses
    if not scale > 0:
        return np.zeros(0, dtype=np.int64), 0.0
    cap = max(2, int(OUTLIER_SHARE * n))
    out: list[tuple[int, int]] = []
    while True:
        k = np.nanargmax(miss) if np.any(np.isfinite(miss)) else None
        if k is None or miss.flat[k] <= OUTLIER_FACTOR * scale:
            break
        if len(out) == cap:
            return np.zeros(0, dtype=np.int64), scale
        site = np.unravel_index(k, miss.shape)
        out.append((int(site[0]), int(site[1])))
        grid[site] = np.nan
        miss = _neighbour_miss(grid)
    rows = [int(np.flatnonzero((ij[:, 0] == a) & (ij[:, 1] == b))[0]) for a, b in out]
    return np.asarray(sorted(rows), dtype=np.int64), scale


#: Median share of the segments between lattice neighbours as dark as the dots above which the
#: dots touch (``dewarp_core::markers::TOUCH_SHARE``: dot targets 0-53 % for diameters up to 0.7
#: of the pitch, real ones 0-27 %; checkerboards 93 %).
TOUCH_SHARE = float(_rspiv.TOUCH_SHARE)


def touching_dots(
    image: np.ndarray,
    index: npt.ArrayLike,
    image_px: npt.ArrayLike,
    amplitude: npt.ArrayLike,
    dark: bool,
) -> str | None:
    """A one-line problem when the indexed dots touch their lattice neighbours, None otherwise.

    A checkerboard's squares are found as dark dots (square, but their fitted discs are as
    good as a printed disc's), on the lattice of the squares' diagonals: the pitch the user
    gives, the side of a square, is then not the lattice's (the diagonal, sqrt(2) x the side,
    or 2 x the side when the two sublattices are taken for two levels), and the magnification
    would be wrong by that factor. Between two adjacent dots of a dot target lies background;
    between two diagonal squares only the corner where they touch. The test is the engine's
    (``_rspiv.touching_share``, ``dewarp_core::markers::touching_share``: 15 bilinear samples
    of each segment's middle 70 %, the share nearer the dots' level than the background's,
    median over the pairs of neighbours), compared with :data:`TOUCH_SHARE`; no answer under 8
    pairs. ``index`` (N, 2): the lattice sites of ``image_px``.
    """
    px = np.ascontiguousarray(image_px, dtype=np.float64).reshape(-1, 2)
    idx = np.ascontiguousarray(index, dtype=np.float64).reshape(-1, 2)
    amp = np.ascontiguousarray(amplitude, dtype=np.float64).ravel()
    got = _rspiv.touching_share(np.ascontiguousarray(image), px, idx, amp, bool(dark))
    if got is None or got[0] <= TOUCH_SHARE:
        return None
    return (
        f"the markers touch their lattice neighbours ({100 * got[0]:.0f} % of the segment "
        "between adjacent markers is as dark as the markers, where a dot target leaves a gap "
        "of background): the squares of a checkerboard, indexed along their diagonals, whose "
        "pitch is not the squares' side? rspiv calibrates dot and disc targets"
    )
