"""Streamwise spectra, two-point correlations, quadrant analysis, conditional averages and POD
of another tool's vector series (``rspiv statistics --two-point --quadrant --conditional
--pod``; :func:`rspiv.vector_statistics`).

A lab's archive of DaVis, OpenPIV, PIVlab or Insight fields gets the campaign's analyses of the
boundary layer's structure, computed as a campaign computes them and written to the same files:

- **Two-point** (:mod:`rspiv.campaign.two_point`: the one-sided spectra ``phi_uu, phi_vv,
  phi_uv`` per row against ``k_x``, the correlation coefficients ``R_uu, R_vv, R_uv`` against
  the lag ``dx``, the integral lengths; ``two_point.nc``). A
  :class:`rspiv.two_point.TwoPointAccumulator` rides with the statistics in the first pass.
  Its columns are fixed before the first field, from the pilot fields
  (:func:`two_point_columns`): a campaign leaves out the columns whose windows reach past the
  sensor, and a tool marks those vectors not valid, so the columns kept are the longest
  contiguous run in which the tool accepted at least ``min_valid`` times the best column's
  share of vectors. A row of a field enters when all its vectors there are finite and at least
  ``min_valid`` of them valid (the tool's filled vectors fill the others, as a campaign's
  replacements do). The two-point maps (``R_uu(dx, y; y_ref)``, ``R_vv`` about reference
  rows at heights in delta_99, ``two_point_maps``) need the wall and delta_99 to place their
  rows, known only after the first pass: with maps the two-point sums are made in the second
  pass instead (:func:`second_pass`), and without wall units, or with a height the rows cannot
  hold, the maps are left out and said.
- **Quadrant** (:mod:`rspiv.campaign.quadrant`: ``<u'v'>`` per quadrant and hole size, the
  time fractions, the joint PDF of ``(u'/u_rms, v'/v_rms)``, the standard error of ``<u'v'>``
  from 8 batches of contiguous fields; ``quadrant.nc``). Each vector's fluctuation is taken
  about its own mean, which is known only at the end of the statistics, so the quadrant
  analysis is a second pass over the files (:func:`second_pass`): every field read again,
  checked, corrected and screened as in the first pass. The sums are exact about the
  series' means. The pass is kept in the checkpoint, so a stopped run resumes it. A file
  that read in the first pass and fails in the second (changed or removed since) is left out
  and said.
- **Conditional averages** (:mod:`rspiv.campaign.conditional`: u', v' averaged about the
  ejections (Q2) and sweeps (Q4) with ``|u'v'| >= hole u_rms v_rms`` at reference rows placed at
  heights in delta_99, over the rows from the wall's 2.5 window heights to twice the highest
  height and offsets as far either way; ``conditional.nc``), in the same second pass; and
  about vortex cores too with ``vortices`` (prograde and retrograde beside Q2 and Q4: the
  cores a field's vortex search found just before in the same pass).
- **POD** (:mod:`rspiv.campaign.pod`: the snapshot POD of the fluctuations about each vector's
  mean over the series, its domain, sampling error and warnings; ``pod.nc``), at the end
  (:func:`pod_pass`): at most ``pod`` of the fields the statistics took, spread evenly over
  the series, read again (once when the snapshots' domain fits 1 GB, else once per block of
  rows and once more), checked, corrected and screened as in the first pass. A planted mode
  in 30 exact fields comes out as the first mode (correlation 0.9965, its energy +0.7 %), and
  the decomposition is :func:`rspiv.pod.pod`'s of the same fields in memory to 1e-5. The POD
  is not checkpointed: a stopped run decomposes again (its passes resume).
- **Vortices** (:mod:`rspiv.campaign.vortices`: every field's vortex cores, connected vectors
  whose signed swirling strength exceeds ``vortices`` (1.5) times its rms at their height, and
  a Lamb-Oseen vortex fitted to the fluctuations about each; their population by height,
  prograde and retrograde apart; ``vortices.nc``), in the second pass. The thresholds come
  from the first pass's vorticity statistics (``vorticity=``, implied), the rows searched from
  the wall and delta_99, so wall units are needed (else left out and said). Vortices planted on
  exact fields come back at their centres with their core radius and circulation
  (``tests/test_vector_vortices.py``).

With a calibration (Method II) or levelling, every field is resampled between its nodes
(:func:`rspiv.vector_sampling.sample_at`, Keys' cubic), which smooths it a little: on the
synthetic layer seen through the tests' strong lens (fluctuations correlated over one grid
step) the integral length came out 2.3 % long (6.5 % with bilinear sampling) and ``R_uu`` one
step away 0.784 against the generator's 0.779; the quadrant shares did not move measurably.

Units and signs: a campaign's. SI (m, m/s, rad/m) when the statistics have wall units (a scale
and a pulse separation), else px and px per pair; ``u'`` downstream and ``v'`` away from the
wall; ``y`` the distance from the wall, nearest first, rows on the flow side only. Rows within
:data:`rspiv.campaign.analysis.NEAR_WALL_HEIGHTS` final-window heights of the wall carry the
``near_wall`` flag.
"""

from __future__ import annotations

import dataclasses
import hashlib
import time
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from rspiv.campaign.conditional import (
    conditional_accumulator,
    conditional_dataset,
    conditional_profile,
    core_events,
)
from rspiv.campaign.pod import decompose_with, domain_of, pod_dataset, pod_profile
from rspiv.campaign.pod import select_snapshots as spread
from rspiv.campaign.quadrant import quadrant_accumulator, quadrant_dataset, quadrant_profile
from rspiv.campaign.two_point import map_rows, two_point_dataset, two_point_profile
from rspiv.campaign.vortices import VortexOptions, VortexSearch, vortex_dataset
from rspiv.conditional import KINDS, VORTEX_KINDS
from rspiv.errors import InvalidInputError, RspivError
from rspiv.outputs import write_netcdf
from rspiv.pod import PodBuilder
from rspiv.two_point import TwoPointAccumulator
from rspiv.vector_files import VectorFile
from rspiv.vector_reduction import SeriesReducer, entry_name

__all__ = [
    "STRUCTURES",
    "StructureOptions",
    "conditional_result",
    "map_rows_of",
    "pod_pass",
    "quadrant_result",
    "second_pass",
    "structure_options",
    "structures",
    "two_point_columns",
    "report_lines",
    "summary_entries",
    "two_point_result",
    "vortex_result",
    "write_structures",
]

#: The analyses of this module, as :class:`rspiv.vector_statistics.VectorStatistics` holds
#: them and :func:`write_structures` writes them (``<name>.nc``).
STRUCTURES = ("two_point", "quadrant", "conditional", "pod", "vortices")


@dataclasses.dataclass(frozen=True)
class StructureOptions:
    """The structure analyses asked of a series (:func:`structure_options`; None: not asked).

    Attributes
    ----------
    two_point : float or None
        The share of valid vectors a row of a field needs to enter the two-point sums.
    maps : tuple of float or None
        The two-point maps' reference heights, delta_99.
    holes : tuple of float or None
        The quadrant analysis' hole sizes.
    conditional : tuple of float or None
        The conditional averages' reference heights, delta_99; ``conditional_hole`` their hole.
    pod : int or None
        The POD's snapshots at most (spread evenly over the fields); ``pod_modes`` kept,
        ``pod_height`` the domain's top in delta_99 (0: the whole flow side).
    vortices : VortexOptions or None
        The vortex population's threshold, smallest core and Lamb-Oseen fits.
    """

    two_point: float | None = None
    maps: tuple[float, ...] | None = None
    holes: tuple[float, ...] | None = None
    conditional: tuple[float, ...] | None = None
    conditional_hole: float = 1.0
    pod: int | None = None
    pod_modes: int = 10
    pod_height: float = 0.0
    vortices: VortexOptions | None = None

    @property
    def second(self) -> bool:
        """Whether a second pass over the files is needed (the POD's excepted)."""
        return any(
            a is not None for a in (self.holes, self.maps, self.conditional, self.vortices)
        )


def structure_options(
    two_point: bool | float = False,
    two_point_maps: Sequence[float] | None = None,
    quadrant: bool | Sequence[float] = False,
    conditional: bool | Sequence[float] = False,
    conditional_hole: float = 1.0,
    pod: bool | int = False,
    pod_modes: int = 10,
    pod_height: float = 0.0,
    vortices: bool | float = False,
    vortex_min_diameter: float = 1.0,
    vortex_fits: bool = True,
    vortex_fit_shear: bool = False,
) -> StructureOptions:
    """:func:`rspiv.vector_statistics`'s keywords of the same names, checked.

    Raises
    ------
    InvalidInputError
        One line naming the keyword and what it takes.
    """
    tp_min = (0.9 if two_point is True else float(two_point)) if two_point is not False else None
    if tp_min is not None and not 0 < tp_min <= 1:
        raise InvalidInputError(f"statistics: two_point = {two_point}: True or a share in (0, 1]")
    maps = None if two_point_maps is None else tuple(float(h) for h in two_point_maps)
    if maps is not None and (tp_min is None or not maps or not all(h > 0 for h in maps)):
        raise InvalidInputError(
            f"statistics: two_point_maps {two_point_maps}: positive heights in delta_99, with "
            "two_point"
        )
    cond = None if conditional is False else (0.15, 0.4) if conditional is True else conditional
    if cond is not None and (not len(cond) or not all(float(h) > 0 for h in cond)):
        raise InvalidInputError(f"statistics: conditional {conditional}: heights in delta_99")
    if not (np.isfinite(conditional_hole) and conditional_hole >= 0):
        raise InvalidInputError(f"statistics: conditional_hole = {conditional_hole}: >= 0")
    holes = None if quadrant is False else (0.0, 1.0, 2.0, 4.0) if quadrant is True else quadrant
    if holes is not None:
        h = np.asarray(holes, np.float64).ravel()
        if h.size == 0 or not np.all(np.isfinite(h)) or h[0] < 0 or np.any(np.diff(h) <= 0):
            raise InvalidInputError(
                f"statistics: quadrant holes {list(holes)} must be increasing numbers >= 0"
            )
        holes = tuple(float(x) for x in h)
    snaps = None if pod is False else 1000 if pod is True else pod
    if snaps is not None and (isinstance(snaps, float) or int(snaps) < 2):
        raise InvalidInputError(f"statistics: pod = {pod}: True or the snapshots (2 or more)")
    if not 1 <= int(pod_modes) <= 200 or not (np.isfinite(pod_height) and pod_height >= 0):
        raise InvalidInputError(
            f"statistics: pod_modes = {pod_modes} (1-200), pod_height = {pod_height} (>= 0)"
        )
    vx = None
    if vortices is not False:
        vx = VortexOptions(1.5 if vortices is True else float(vortices),
                           float(vortex_min_diameter), bool(vortex_fits), bool(vortex_fit_shear))
        if not (np.isfinite(vx.threshold) and vx.threshold > 0 and np.isfinite(vx.min_diameter)
                and vx.min_diameter > 0):  # fmt: skip
            raise InvalidInputError(
                f"statistics: vortices = {vortices} (True or a threshold > 0, the swirl's rms "
                f"times), vortex_min_diameter = {vortex_min_diameter} (> 0, final windows)"
            )
    return StructureOptions(
        tp_min, maps, holes, None if cond is None else tuple(float(c) for c in cond),
        float(conditional_hole), None if snaps is None else int(snaps), int(pod_modes),
        float(pod_height), vx,
    )  # fmt: skip


def two_point_columns(
    pilots: list[tuple[np.ndarray, np.ndarray, np.ndarray]], min_valid: float
) -> tuple[int, int]:
    """The columns ``[c0, c1)`` of a series' two-point sums (module docstring), from its pilot
    fields' ``(u, v, valid)`` (:func:`rspiv.vector_reduction.pilot_fields`).

    Raises
    ------
    InvalidInputError
        No pilot field, or fewer than 8 contiguous columns in which the tool accepted enough
        vectors.
    """
    if not pilots:
        raise InvalidInputError("two-point: no pilot field could be read to place its columns")
    share = np.mean([np.asarray(ok, bool).mean(axis=0) for _, _, ok in pilots], axis=0)
    good = share >= float(min_valid) * float(share.max()) if share.max() > 0 else share > 1
    best, run_start, at = (0, 0), None, 0
    for at, g in enumerate(np.append(good, False)):  # the longest contiguous run of good
        if g and run_start is None:
            run_start = at
        elif not g and run_start is not None:
            if at - run_start > best[1] - best[0]:
                best = (run_start, at)
            run_start = None
    if best[1] - best[0] < 8:
        raise InvalidInputError(
            f"two-point: only {best[1] - best[0]} contiguous columns of {share.size} hold "
            f"{100 * min_valid:g} % of the best column's share of accepted vectors (8 needed)"
        )
    return int(best[0]), int(best[1])


def two_point_result(
    tp: Any, an: Any, window: tuple[int, int], dx_px: float
) -> tuple[dict[str, Any] | None, list[str]]:
    """The two-point rows (and maps) of the filled accumulator ``tp`` (:func:`rspiv.campaign.
    two_point.two_point_profile`) and what must be said: rows away from the wall and inside
    the field that entered fewer than half the fields, or no row at all (then None)."""
    try:
        prof = two_point_profile(tp, an, window, dx_px)
    except InvalidInputError as exc:
        return None, [f"no two-point statistics: {exc}"]
    ny = tp.shape[0]
    inside = (prof["rows"] > 0) & (prof["rows"] < ny - 1)  # a field's outer rows: its edge
    away = ~prof["near_wall"] & inside
    few = int(np.count_nonzero(away & (prof["count"] < 0.5 * prof["pairs"])))
    said = []
    if few:
        prof["warning"] = (
            f"two-point: {few} of {int(away.sum())} rows away from the wall entered fewer than "
            f"half of the {prof['pairs']} fields (a row of a field enters with at least "
            f"{100 * tp.min_valid:g} % valid vectors in columns {tp.columns[0]}-"
            f"{tp.columns[1] - 1}): their spectra and correlations rest on fewer fields (count)"
        )
        said.append(prof["warning"])
    return prof, said


def map_rows_of(
    an: Any, heights: Any, window_height: float, what: str
) -> tuple[tuple[tuple[int, int], tuple[int, ...], list[float]] | None, list[str]]:
    """The band and the reference rows (:func:`rspiv.campaign.two_point.map_rows`) of
    reference ``heights`` in delta_99 from the wall analysed in ``an``, and the heights in px;
    or None and why not, said of ``what`` (no wall units, or a height the rows cannot hold)."""
    p, bl = an.profile, an.result
    if bl is None or not p.get("si") or not np.isfinite(bl.delta99):
        return None, [f"no {what}: their heights are in delta_99, which needs wall units"]
    px = [float(h) * bl.delta99 / p["m_per_px"] for h in heights]
    try:
        band, refs = map_rows(np.asarray(p["dist_px"], np.float64), px, window_height)
    except InvalidInputError as exc:
        return None, [f"no {what}: {exc}"]
    return (band, refs, px), []


def _key(parts: dict[str, Any], n: int) -> str:
    """What the second pass's sums are about: the quadrant's holes, vectors that may enter,
    signs, means and standard deviations; the two-point sums' grid, columns, rows and maps;
    the number of fields."""
    h = hashlib.sha256()
    for name in ("quadrant", "conditional"):
        q = parts.get(name)
        if q is None:
            continue
        plan = (q.holes,) if name == "quadrant" else (q.ref_rows, q.map_rows, q.offsets)
        for a in (*plan, q.usable, q.mean_u, q.mean_v, q.rms_u, q.rms_v):
            h.update(np.ascontiguousarray(a).tobytes())
        h.update(f"{name},{q.sign_x},{q.sign_y},{getattr(q, 'hole', '')}".encode())
    tp = parts.get("two_point")
    if tp is not None:
        h.update(repr((tp.shape, tp.columns, tp.min_valid, tp.band, tp.refs)).encode())
    vx = parts.get("vortices")
    if vx is not None:  # its thresholds, rows, means and options
        for a in (vx.thr, vx.usable, vx.mean_u, vx.mean_v, vx.x):
            h.update(np.ascontiguousarray(a).tobytes())
        h.update(repr((vx.options, vx.prograde, vx.min_vectors)).encode())
    h.update(f"{sorted(parts)},{n}".encode())
    return h.hexdigest()[:16]


def second_pass(
    parts: dict[str, Any],
    entries: list[Any],
    reads: Any,
    reducer: SeriesReducer,
    transform: Callable[[VectorFile], VectorFile],
    bounds: Any,
    state: dict[str, Any],
    save: Callable[[], None] | None = None,
    every: int = 500,
    progress: Callable[[int, int], None] | None = None,
) -> tuple[dict[str, Any], list[str]]:
    """The second pass over ``entries`` (module docstring; those in ``state["skipped"]``
    excepted): every field read (by ``reads``, a :class:`rspiv.vector_readahead.ReadAhead`,
    ahead of its use), checked, corrected and screened as in the first pass, and
    added to the empty accumulators ``parts`` (``"quadrant"``: a
    :class:`rspiv.quadrant.QuadrantAccumulator`, ``"two_point"``: a
    :class:`rspiv.two_point.TwoPointAccumulator` with its maps, ``"conditional"``, and
    ``"vortices"``: a :class:`rspiv.campaign.vortices.VortexSearch`). Returns the filled
    accumulators and the names of the fields that read in the first pass and not now.

    ``state`` is the statistics' checkpoint state: its ``second`` holds the pass's sums and is
    resumed when they are about the same means, rows and maps (:func:`_key`); ``save()``
    writes the checkpoint every ``every`` fields. ``progress(done, total)`` counts both passes.
    """
    n = len(entries)
    key = _key(parts, n)
    part = state.get("second") or {}
    if part.get("key") != key:
        part = {"key": key, "done": 0, "parts": parts, "lost": []}
        state["second"] = part
    parts = part["parts"]
    q, tp, cond = parts.get("quadrant"), parts.get("two_point"), parts.get("conditional")
    vx = parts.get("vortices")
    about_cores = cond is not None and VORTEX_KINDS[0] in cond.kinds
    skipped = state["skipped"]
    reads.along([k for k in range(part["done"], n) if entry_name(entries[k]) not in skipped])
    for k in range(part["done"], n):
        e = entries[k]
        name = entry_name(e)
        if name not in skipped:
            try:
                u, v, valid = reducer.again(reads, k, transform, bounds)
                if q is not None:
                    q.add(u, v, valid, pair_id=k, batch=k * q.batches // n)
                if tp is not None:
                    tp.add(u, v, valid, pair_id=k)
                if vx is not None:
                    vx.add_field(u, v, valid, pair_id=k, i=k)
                if cond is not None:
                    events = None
                    if about_cores:  # the field's cores, found just now
                        found = vx.part["events"].pop(k, None)
                        events = core_events(found, cond.ref_rows, cond.shape[1])
                    cond.add(u, v, valid, pair_id=k, batch=k * cond.batches // n, events=events)
            except RspivError as exc:
                part["lost"].append(f"{name}: {exc}")
        part["done"] = k + 1
        if progress is not None:
            progress(n + k + 1, 2 * n)
        if save is not None and (k + 1) % max(int(every), 1) == 0:
            save()
    return parts, list(part["lost"])


def structures(
    so: StructureOptions,
    acc: Any,
    an: Any,
    window: tuple[int, int],
    x_px: np.ndarray,
    min_count: int,
    passes: dict[str, Any],
    dt: float = 0.0,
) -> tuple[dict[str, dict[str, Any] | None], list[str]]:
    """The structure analyses ``so`` of a series whose statistics ``acc`` and wall and units
    ``an`` (``dt`` the pulse separation, s; 0 unknown) are known, on a grid of columns
    ``x_px``: the second pass (:func:`second_pass`) and
    the POD (:func:`pod_pass`) as asked, and their profiles (:data:`STRUCTURES` -> profile or
    None) with what must be said. ``passes`` holds :func:`second_pass`'s arguments after
    ``parts`` (``entries``, ``options``, ``reducer``, ``transform``, ``bounds``, ``state``,
    ``save``, ``every``, ``progress``)."""
    dx_px = abs(float(x_px[1] - x_px[0]))
    warnings: list[str] = []
    parts: dict[str, Any] = {}  # the second pass's accumulators
    if so.holes is not None:
        parts["quadrant"] = quadrant_accumulator(acc, an, min_count, so.holes)
    cond_rows = None
    if so.conditional is not None:
        cond_rows, said = map_rows_of(an, so.conditional, window[1], "conditional averages")
        warnings += said
    if so.vortices is not None:
        try:  # its cores' events serve the conditional averages about them (then dropped)
            parts["vortices"] = VortexSearch(acc, an, min_count, window, x_px, so.vortices,
                                             total=len(passes["entries"]),
                                             events=cond_rows is not None)  # fmt: skip
        except InvalidInputError as exc:
            warnings.append(f"no vortex population: {exc}")
    if cond_rows is not None:
        band, refs, heights = cond_rows
        kinds = KINDS + VORTEX_KINDS if "vortices" in parts else KINDS
        parts["conditional"] = conditional_accumulator(
            acc, an, band, refs, heights, dx_px, min_count, so.conditional_hole, kinds
        )
    if so.maps is not None:
        rows, said = map_rows_of(an, so.maps, window[1], "two-point maps")
        warnings += said
        band, refs = rows[:2] if rows is not None else (None, ())
        cols = passes["state"].get("columns")
        parts["two_point"] = TwoPointAccumulator(acc.shape, cols, so.two_point, band, refs)
    if parts:
        parts, lost = second_pass(parts, **passes)
        if passes["save"] is not None:
            passes["save"]()
        if lost:
            warnings.append(
                f"{len(lost)} field(s) read in the first pass failed in the second and are not "
                f"in its analyses ({', '.join(sorted(parts))}: their fields are about the means "
                f"of all {acc.n_fields}); the first {lost[0]}"
            )
    out: dict[str, dict[str, Any] | None] = dict.fromkeys(STRUCTURES)
    tp = parts.get("two_point", acc.two_point)
    if tp is not None:
        out["two_point"], said = two_point_result(tp, an, window, dx_px)
        warnings += said
    if "conditional" in parts:
        out["conditional"], said = conditional_result(
            parts["conditional"], acc, an, dx_px, window, min_count
        )
        warnings += said
    if "quadrant" in parts:
        out["quadrant"], said = quadrant_result(parts["quadrant"], acc, an, min_count, window)
        warnings += said
    if "vortices" in parts:
        out["vortices"], said = vortex_result(parts["vortices"], an, dt)
        warnings += said
    if so.pod is not None:
        out["pod"], said = pod_pass(so, acc, an, window, x_px, min_count, passes)
        warnings += said
    return out, warnings


def vortex_result(
    vx: VortexSearch, an: Any, dt: float
) -> tuple[dict[str, Any] | None, list[str]]:
    """The vortex population of the filled search ``vx`` (:meth:`rspiv.campaign.vortices.
    VortexSearch.profile`) and what must be said of it, or None when no field entered."""
    if vx.part["acc"].n_fields == 0:
        return None, ["no vortex population: no field entered the second pass"]
    prof, said = vx.profile([vx.part], dt, an)
    if vx.options.fits and prof["total"] and not prof["fits_kept"]:
        said.append(
            f"no core's Lamb-Oseen fit of {prof['total']} was kept: the swirling regions are "
            "not resolved Lamb-Oseen vortices"
        )
    if said:
        prof["warning"] = "vortices: " + "; ".join(said)
    return prof, ([prof["warning"]] if said else [])


def pod_pass(
    so: StructureOptions,
    acc: Any,
    an: Any,
    window: tuple[int, int],
    x_px: np.ndarray,
    min_count: int,
    passes: dict[str, Any],
) -> tuple[dict[str, Any] | None, list[str]]:
    """The snapshot POD of a series (a campaign's :mod:`rspiv.campaign.pod`: its domain,
    streaming and sampling error), over at most ``so.pod`` of the fields the statistics took,
    spread evenly over the series; each read, checked, corrected and screened as in the first
    pass, about the series' means. A field that fails now is taken as its mean (no
    fluctuation) and said. Returns the profile (:func:`rspiv.campaign.pod.pod_profile`) and
    what must be said, or None and why not (no domain). Not checkpointed: a stopped run
    decomposes again (its passes resume). ``passes["progress"]`` counts the reads after the
    passes' fields (its total grows by them)."""
    t0 = time.perf_counter()
    try:
        domain = domain_of(an, acc, window[1], min_count, so.pod_height, "pod_height")
    except InvalidInputError as exc:
        return None, [f"no POD: {exc}"]
    entries, state = passes["entries"], passes["state"]
    usable = [k for k, e in enumerate(entries) if entry_name(e) not in state["skipped"]]
    ids = spread(usable, so.pod)
    if len(ids) < 2:
        return None, [f"no POD: {len(ids)} field(s) to decompose, 2 needed"]
    p = an.profile
    builder = PodBuilder(acc.mean_u, acc.mean_v, domain, len(ids), float(p.get("sign_x", 1.0)),
                         float(p.get("sign_y", 1.0)))  # fmt: skip
    lost: list[str] = []
    red, transform, bounds = passes["reducer"], passes["transform"], passes["bounds"]

    reads = passes["reads"].along(ids)  # each sweep over the snapshots read ahead

    def read(i: int, rows: slice | None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        rows = slice(None) if rows is None else rows
        try:
            u, v, valid = red.again(reads, ids[i], transform, bounds)
            return u[rows], v[rows], valid[rows]
        except RspivError as exc:
            name = f"{entry_name(entries[ids[i]])}: {exc}"
            if name not in lost:
                lost.append(name)
            nan = np.full(acc.shape, np.nan, np.float32)[rows]
            return nan, nan, np.zeros(nan.shape, bool)

    with np.errstate(invalid="ignore", divide="ignore"):
        n_eff = min(len(ids), float(np.median(acc.n_eff("uu")[domain])))
    # the reads continue the count of the passes before (progress's total grows by them)
    counted, before = passes["progress"], len(entries) * (2 if so.second else 1)
    progress = None if counted is None else (lambda i, m: counted(before + i, before + m))
    # a series' grid is small (a 47 MP camera's: 183,000 vectors): blocks of 1 GB read most
    # series' snapshots once
    decompose_with(builder, read, so.pod_modes, n_eff, block_bytes=1 << 30, progress=progress)
    prof, said = pod_profile(builder.result(ids), an, domain, x_px, ids,
                             time.perf_counter() - t0)  # fmt: skip
    if lost:
        said.append(
            f"{len(lost)} of the {len(ids)} fields chosen failed to read again and entered as "
            f"their means (no fluctuation): the energies read low by about as much; the first "
            f"{lost[0]}"
        )
    if said:
        prof["warning"] = "POD: " + "; ".join(said)
    return prof, ([prof["warning"]] if said else [])


def quadrant_result(
    q: Any, acc: Any, an: Any, min_count: int, window: tuple[int, int]
) -> tuple[dict[str, Any] | None, list[str]]:
    """The quadrant rows of the filled accumulator ``q`` (:func:`rspiv.campaign.quadrant.
    quadrant_profile`) and what must be said of them, or None when no field entered."""
    if q.n_fields == 0:
        return None, ["no quadrant analysis: no field entered its second pass"]
    prof, said = quadrant_profile(q, acc, an, min_count, window[1])
    if said:
        prof["warning"] = "quadrant: " + "; ".join(said)
    return prof, ([prof["warning"]] if said else [])


def conditional_result(
    c: Any, acc: Any, an: Any, dx_px: float, window: tuple[int, int], min_count: int
) -> tuple[dict[str, Any] | None, list[str]]:
    """The conditional averages of the filled accumulator ``c`` (:func:`rspiv.campaign.
    conditional.conditional_profile`) and what must be said of them, or None when no field
    entered."""
    if c.n_fields == 0:
        return None, ["no conditional averages: no field entered the second pass"]
    prof, said = conditional_profile(c, acc, an, dx_px, window[1], min_count)
    if said:
        prof["warning"] = "conditional averages: " + "; ".join(said)
    return prof, ([prof["warning"]] if said else [])


def summary_entries(found: dict[str, dict[str, Any] | None]) -> dict[str, Any]:
    """The structure analyses' figures for ``summary.json`` (None where not made)."""
    tp, qd, cond, pod, vx = (found.get(k) for k in STRUCTURES)
    return {
        "two_point_rows": None if tp is None else int(tp["y"].size),
        "quadrant_rows": None if qd is None else int(qd["y"].size),
        "conditional_events": None if cond is None else cond["events"].tolist(),
        "pod_fraction": None if pod is None else pod["fraction"].tolist(),
        "vortex_cores": None if vx is None else [int(n) for n in vx["count"].sum(axis=0)],
        "vortex_fits_kept": None if vx is None else vx.get("fits_kept"),
    }


def report_lines(found: dict[str, dict[str, Any] | None]) -> list[str]:
    """The structure analyses' lines for the terminal."""
    tp, qd, cond, pod, vx = (found.get(k) for k in STRUCTURES)
    lines = []
    if tp is not None:
        c0, c1 = tp["columns"]
        lines.append(f"two-point: {tp['y'].size} rows, columns {c0}-{c1 - 1}, {tp['pairs']} fields")
    if qd is not None:
        lines.append(f"quadrant: {qd['y'].size} rows, {qd['pairs']} fields")
    if cond is not None:
        ev = cond["events"]
        cores = (f", {int(ev[:, 2].sum())} prograde and {int(ev[:, 3].sum())} retrograde cores"
                 if ev.shape[1] > 2 else "")  # fmt: skip
        lines.append(
            f"conditional averages: {int(ev[:, 0].sum())} ejections, {int(ev[:, 1].sum())} "
            f"sweeps{cores} at {ev.shape[0]} heights, {cond['pairs']} fields"
        )
    if pod is not None:
        fr = pod["fraction"]
        lines.append(
            f"POD: {pod['pairs']} fields over {pod['vectors']} vectors, the first mode "
            f"{100 * fr[0]:.1f} %, the first {fr.size} {100 * fr.sum():.1f} %"
        )
    if vx is not None:
        n = vx["count"].sum(axis=0)
        kept = f", {vx['fits_kept']} Lamb-Oseen fits kept" if "fits_kept" in vx else ""
        lines.append(
            f"vortices: {int(n[0])} prograde and {int(n[1])} retrograde cores in "
            f"{vx['y'].size} rows, {vx['pairs']} fields{kept}"
        )
    return lines


def write_structures(out: Any, run: Any, profiles: dict[str, Any], figures: bool) -> dict:
    """``two_point.nc``, ``quadrant.nc``, ``conditional.nc``, ``pod.nc`` and ``vortices.nc`` of
    ``profiles``
    (name -> the profile or None; their warnings as the files' ``warning`` attribute) in the
    folder ``out``, and with ``figures`` their figures in wall units (``two_point.png``,
    ``two_point_maps.png``, ``quadrant.png``, ``conditional.png``, ``pod.png``,
    ``vortices.png``); returns name
    -> path."""
    files: dict[str, Any] = {}
    datasets = {"two_point": two_point_dataset, "quadrant": quadrant_dataset,
                "conditional": conditional_dataset, "pod": pod_dataset,
                "vortices": vortex_dataset}  # fmt: skip
    for stem, dataset in datasets.items():
        prof = profiles.get(stem)
        if prof is None:
            continue
        ds = dataset(prof, run)
        if "warning" in prof:
            ds.attrs["warning"] = prof["warning"]
        files[stem] = write_netcdf(ds, out / f"{stem}.nc")
        if figures and "y_plus" in prof:
            from rspiv.plots.conditional import plot_conditional  # deferred: matplotlib
            from rspiv.plots.pod import plot_pod  # deferred: matplotlib
            from rspiv.plots.quadrant import plot_quadrant  # deferred: matplotlib
            from rspiv.plots.two_point import (  # deferred: matplotlib
                plot_two_point,
                plot_two_point_maps,
            )
            from rspiv.plots.vortices import plot_vortices  # deferred: matplotlib

            draw = {"two_point": plot_two_point, "quadrant": plot_quadrant,
                    "conditional": plot_conditional, "pod": plot_pod,
                    "vortices": plot_vortices}  # fmt: skip
            plots = [(stem, draw[stem])]
            if stem == "two_point" and "R_uu_map" in prof:
                plots.append(("two_point_maps", plot_two_point_maps))
            for name, plot in plots:
                try:
                    files[f"figure_{name}"] = plot(out / f"{name}.png", prof)
                except InvalidInputError:
                    pass  # too few rows in wall units to draw: the file holds them
    return files
