"""A campaign's vortex population (``[statistics] vortices``).

A second pass over the fields the pair loop wrote (``[output] fields = true``), at the end of a
run, that finds every pair's vortex cores (:func:`rspiv.vortices.find_vortices`) and counts them
by height, prograde and retrograde apart (Wu & Christensen 2006). It needs the run's vorticity
statistics (``[statistics] vorticity = true``, which the configuration requires): the
threshold at each row is ``vortex_threshold`` (1.5) times the root mean square of the signed
swirling strength over that row's vectors and pairs, so it is known before the first core.

Frame and sign: the flow's (x downstream, y away from the wall); a core is prograde when it turns
with the mean shear, i.e. its sign is that of the domain's mean vorticity (negative in a
boundary layer). The rows searched are those on the flow side off the wall (2.5 final window
heights plus the differences' reach, ``near_wall`` in the vorticity file) up to delta_99, with
statistics of at least ``min_count`` pairs. Above the layer the swirl's rms is the noise's and a
threshold relative to it counts noise (on the demo's frame above 1.25 delta_99: 425 cores where
its exact field has none), so a run without a boundary-layer fit (a calibration, ``[flow] dt``)
is refused in one line.

Output ``vortices_<run>.nc``: per row (``y`` from the wall, ``y_plus``) and ``kind`` (prograde,
retrograde): ``count``, ``density`` (cores per m^2 of the row's strip per pair, 1/px^2 without a
calibration; cores are counted at the row nearest their centroid), ``density_delta2`` (times
delta_99^2), ``radius`` and ``circulation`` (means of the cores; m and m^2/s, with ``_plus`` in
wall units), each with its standard error ``_se`` (the density's from 8 batches of contiguous
pairs, which keeps the correlation of successive pairs; the means' from their cores' spread),
``threshold`` (1/s); and every core (dim ``core``, at most ``MAX_CORES``): ``pair``,
``x``, ``y``, ``sign``, ``radius``, ``circulation``, ``peak``, ``region`` (the cores of one
thresholded region split at its swirl's saddles share it: :func:`rspiv.vortices.find_vortices`).
A report figure.

Lamb-Oseen fits (``[statistics] vortex_fits``, on by default: about 0.2 ms a core in
``piv_core::vortex_fit``, 40 ms a pair's field on the demo's layer at scale 0.4, where the rest
of the pass takes 15 ms):
a Lamb-Oseen vortex is fitted to the fluctuations about each core (about each vector's mean
over the other pairs: the mean shear is removed; :func:`rspiv.vortices.fit_oseen`, a patch of
2.5 core radii). With ``[statistics] vortex_fit_shear`` the vortex sits in a uniform
background shear (Stanislas, Perret & Foucaut 2008), the local shear of the larger motions
about it. Every core lists its fit (``core_oseen_x``, ``_y``, ``_radius`` the core radius r_c,
``_circulation`` the whole circulation, ``_u`` and ``_v`` the convection velocity in the flow's
frame: the fit's plus the other pairs' mean at its centre, ``_shear`` the background's dU/dy in
the flow's frame (1/s, without the mean's; NaN without ``vortex_fit_shear``), ``_fit`` the
share of the patch's velocity about the fitted convection (and shear) it explains, ``_ok``),
and per row and kind ``oseen_count``,
``oseen_share`` and the means of the fits kept: ``oseen_radius``, ``oseen_circulation``,
``oseen_u`` (with ``_plus`` in wall units). The final window widens a core: a Gaussian core of
radius r_c reads sqrt(r_c^2 + W^2 / 6) through a W px top-hat window (`tests/test_vortices.py`).

A fit is kept only where the patch shows a vortex decaying within it. The demo's synthetic
turbulence (random Fourier modes) has few: most of its swirling regions rotate as solid bodies
across their patches and fit r_c beyond them (none kept at scale 0.15 over 3 pairs, 69-79 of
about 3070 cores per run at the demo's scale 0.4 over 24 pairs); a run without one says so. On
OpenPIV's ``test10`` vortex pairs the fit is kept at r_c 17-26 px. The mean over all N pairs
holds 1/N of every pair's vortex, so the fluctuations about it hold only (1 - 1/N) of its
circulation (17 % low over 6 pairs); the fit is therefore made about the mean of the *other*
pairs, ``u - (n u_mean - u) / (n - 1) = n / (n - 1) (u - u_mean)`` with ``n`` the vector's
count, which holds none of this pair's vortex. Vortices planted on the demo's layer
(``DemoScene.vortices``; 30 of r_c 24 px over 6 pairs): 15 kept on them and 1 elsewhere, their
median r_c 2.8 % under the planted core widened by the 32 x 8 px window, their median
circulation within 10 % of the planted one (`tests/test_oseen_campaign.py`); on exact fields
of another tool's format, one vortex each over 24 fields, r_c and the circulation within 3 %
(`tests/test_vector_vortices.py`).

Noise also makes cores, mostly small ones: cores smaller than a disc ``vortex_min_diameter``
(1.0) final windows wide are dropped (:func:`rspiv.vortices.min_core_vectors`; not resolved by
the windows). The threshold is a multiple of the *measured* rms, which the noise raises too.
Said in one line: a missing field file (left out); the core table cut at ``MAX_CORES``.
"""

from __future__ import annotations

import dataclasses
import time
from typing import Any

import numpy as np

from rspiv.campaign.fields import each_field, finish_pass, pass_section, run_field_files
from rspiv.campaign.spec import RunSpec
from rspiv.derivatives import SCHEMES
from rspiv.errors import InvalidInputError
from rspiv.vortices import (
    CORE_FIELDS,
    OSEEN_CROWDED,
    OSEEN_FIELDS,
    OSEEN_JOINT_MAX,
    SPLIT_SADDLE,
    VortexAccumulator,
    batch_density_se,
    confirm_splits,
    find_vortices,
    fit_neighbours,
    min_core_vectors,
)
from rspiv.vorticity import VorticityAccumulator

__all__ = [
    "MAX_CORES",
    "VortexOptions",
    "VortexSearch",
    "found_line",
    "report_section",
    "vortex_dataset",
    "write_outputs",
]

#: The most cores ``vortices_<run>.nc`` lists one by one (the counts hold every core).
MAX_CORES = 2_000_000
#: Batches of contiguous pairs for the densities' standard errors.
BATCHES = 8


@dataclasses.dataclass(frozen=True)
class VortexOptions:
    """How cores are found and fitted (a campaign's ``[statistics] vortex_threshold``,
    ``vortex_min_diameter``, ``vortex_fits``, ``vortex_fit_shear``; module docstring)."""

    threshold: float = 1.5
    min_diameter: float = 1.0
    fits: bool = True
    shear: bool = False


class VortexSearch:
    """One run's vortex search (module docstring): each row's threshold from the run's
    vorticity statistics, the rows searched, and the cores of the fields added.

    Parameters
    ----------
    acc : FieldAccumulator
        The run's statistics, with their ``vorticity`` (a
        :class:`rspiv.vorticity.VorticityAccumulator`).
    an : RunAnalysis
        The run's wall, profile and boundary layer (delta_99 bounds the rows).
    min_count : int
        The pairs a vector needs to be searched.
    window : (w, h)
        The final window, px (the rows near the wall, the smallest core).
    x : ndarray
        The columns' positions, px.
    options : VortexOptions
    total : int
        The fields the pass will add (``i`` of :meth:`add` places each in one of
        :data:`BATCHES` batches of contiguous fields); 0: one batch.
    events : bool
        Keep each pair's cores as events (``core_events``: row, column, prograde), for a
        campaign's conditional averages about them.

    Raises
    ------
    InvalidInputError
        No vorticity statistics, no delta_99 (a calibration, the pulse separation and a
        boundary-layer fit), or no row off the wall with swirling-strength statistics.

    Fields are added by :meth:`add` (into a part of :meth:`new_part`, for
    :func:`rspiv.campaign.fields.each_field`'s threads) or :meth:`add_field` (into
    ``self.part``); :meth:`profile` gives the population. It holds arrays and counts only, so
    a series' second pass keeps it in its checkpoint.
    """

    def __init__(self, acc: Any, an: Any, min_count: int, window: tuple[int, int],
                 x: np.ndarray, options: VortexOptions, total: int = 0,
                 events: bool = True):  # fmt: skip
        from rspiv.campaign.analysis import NEAR_WALL_HEIGHTS  # deferred: analysis imports us

        va = getattr(acc, "vorticity", None)
        if va is None:
            raise InvalidInputError("the run carries no vorticity statistics to set the threshold")
        p = an.profile
        self.options, self.dx, self.dy, self.scheme = options, va.dx, va.dy, va.scheme
        self.events = bool(events)
        self.dist = np.asarray(p["dist_px"], np.float64)
        self.profile_units = {"si": bool(p.get("si")), "m_per_px": p.get("m_per_px", 1.0)}
        self.shape = tuple(acc.shape)
        self.usable = an.flow_vectors(acc, min_count) & (va.swirl_count > 1)
        usable = self.usable
        self.orient = float(p.get("sign_x", 1.0)) * -float(p.get("sign_y", 1.0))
        reach = max(abs(k) for k in SCHEMES[va.scheme][0]) * va.dy
        near = self.dist < NEAR_WALL_HEIGHTS * window[1] + reach
        # above the layer the row's rms is the noise's, and a threshold relative to it counts
        # noise (the demo's frame above 1.25 delta_99: 425 cores where its exact field has none)
        bl = an.result
        if bl is None or not p.get("si") or not np.isfinite(bl.delta99):
            raise InvalidInputError(
                "the vortex population needs the run's delta_99 to bound its rows (a "
                "calibration, the pulse separation and a boundary-layer fit): above the layer a "
                "threshold relative to the row's swirl counts the noise"
            )
        self.rows_in = ((self.dist > 0) & ~near & usable.any(axis=1)
                        & (self.dist * p["m_per_px"] <= bl.delta99))  # fmt: skip
        if not self.rows_in.any():
            raise InvalidInputError("no row off the wall holds swirling-strength statistics")
        with np.errstate(invalid="ignore", divide="ignore"):
            # each vector's mean square over its pairs, averaged along the row: 1/pair
            msq = va.swirl_m2 / np.maximum(va.swirl_count, 1) + va.swirl_mean**2
            rms = np.sqrt(np.where(usable, msq, 0.0).sum(1) / usable.sum(1))
            omega = np.where(usable, va.mean("omega"), 0.0).sum(1) / usable.sum(1) * self.orient
        self.thr = np.where(self.rows_in & (rms > 0), options.threshold * rms, np.inf)
        self.prograde = -1.0 if np.nanmedian(omega[self.rows_in]) <= 0 else 1.0
        self.x = np.asarray(x, np.float64)
        self.min_vectors = min_core_vectors(options.min_diameter * max(window), va.dx, va.dy)
        self.row_index = np.arange(self.shape[0], dtype=np.float64)
        self.sign_x, self.sign_y = float(p.get("sign_x", 1.0)), float(p.get("sign_y", 1.0))
        self.mean_u = np.where(usable, acc.mean_u, np.nan)
        self.mean_v = np.where(usable, acc.mean_v, np.nan)
        # u - (n mean - u) / (n - 1) = n / (n - 1) (u - mean): the fluctuation about the mean
        # of the other fields, which holds none of this field's vortex (usable: n >= 2)
        n = np.asarray(acc.count, np.float64)
        self.loo = np.where(usable & (n > 1), n / np.maximum(n - 1.0, 1.0), np.nan)
        self.total = int(total)
        self.part = self.new_part()

    def new_part(self, w: int = 0) -> dict[str, Any]:
        """An empty part: the counts, the cores found (``(pair id, cores)``) and each pair's
        core events."""
        return {"acc": VortexAccumulator(self.shape[0], self.prograde, BATCHES), "cores": [],
                "n": 0, "events": {}}  # fmt: skip

    def add_field(self, u: np.ndarray, v: np.ndarray, valid: np.ndarray, pair_id: int,
                  i: int = 0) -> None:  # fmt: skip
        """Find one field's cores (px per pair, pixel axes) into ``self.part``; ``i`` the
        field's place among the ``total``."""
        self.add(self.part, i, pair_id, u, v, valid)

    def add(self, part: dict, i: int, pid: int, u, v, valid) -> None:
        """Find one field's cores into ``part`` (:func:`rspiv.campaign.fields.each_field`'s
        ``add``; ``i`` the field's place among the ``total``: its batch)."""
        batch = min(i * BATCHES // self.total, BATCHES - 1) if self.total > 0 else 0
        w, s = VorticityAccumulator.fields(u, v, valid, self.dx, self.dy, self.scheme)
        o = self.orient
        found = {"x": self.x, "y": self.row_index, "min_vectors": self.min_vectors}
        cores = find_vortices(s * o, w * o, self.thr[:, None], self.dx, self.dy, **found)
        if self.options.fits:  # regions of two vortices split where their parts fit as such

            def parts(regions: np.ndarray) -> dict:
                return find_vortices(s * o, w * o, self.thr[:, None], self.dx, self.dy,
                                     **found, split=SPLIT_SADDLE, regions=regions)  # fmt: skip

            cores = self._with_fits(cores, parts, u, v, valid, part["acc"], batch)
        rows = np.rint(cores["y"]).astype(np.int64)
        if self.options.fits:
            inside = (rows >= 0) & (rows < self.shape[0])  # as the counts take them
            near = inside & cores["oseen_ok"] & (cores["oseen_neighbour"] < OSEEN_CROWDED)
            joint = inside & cores["oseen_joint"]  # fitted with its neighbours
            part["crowded"] = part.get("crowded", 0) + int(np.count_nonzero(near & ~joint))
            part["joint"] = part.get("joint", 0) + int(np.count_nonzero(joint))
            _, which, count = np.unique(cores["region"], return_inverse=True, return_counts=True)
            split = inside & (count[which] > 1)  # one of a region's vortices
            part["split"] = part.get("split", 0) + int(np.count_nonzero(split))
        else:
            part["acc"].add(cores, rows, batch=batch)
        if self.events:  # each core at the vector nearest its centroid, for averages about it
            cols = np.rint(np.interp(cores["x"], self.x, np.arange(self.x.size))).astype(np.int64)
            part["events"][pid] = (rows, cols, cores["sign"] == self.prograde)
        if part["n"] < MAX_CORES:
            part["cores"].append((pid, cores))
            part["n"] += cores["x"].size

    def _with_fits(self, cores: dict, parts: Any, u, v, valid, counts: VortexAccumulator,
                   batch: int) -> dict:  # fmt: skip
        """The cores (those of ``parts``, :func:`rspiv.vortices.confirm_splits`', where a
        region's split is confirmed) with their Lamb-Oseen fits (``oseen_*``), counted."""
        # a Lamb-Oseen vortex (in a uniform shear, if asked) fitted to the fluctuations about
        # each core, about the other fields' mean (the mean shear removed, none of this
        # field's vortex); its convection is the fit's plus that mean there
        du, dv = (u - self.mean_u) * self.loo, (v - self.mean_v) * self.loo
        cores, fits = confirm_splits(du, dv, cores, parts, self.dx, self.dy, valid=valid,
                                     x=self.x, y=self.row_index, orient=self.orient,
                                     shear=self.options.shear)  # fmt: skip
        rows = np.rint(cores["y"]).astype(np.int64)
        ny, nx = self.shape
        at_i = np.clip(np.rint(np.nan_to_num(fits["y"])).astype(np.int64), 0, ny - 1)
        at_j = np.clip(np.rint(np.interp(np.nan_to_num(fits["x"]), self.x, np.arange(nx)))
                       .astype(np.int64), 0, nx - 1)  # fmt: skip
        at = (at_i, at_j)
        ok = np.asarray(valid, bool)[at]  # in the mean: the others' is u - du there
        fits["u"] = self.sign_x * (fits["u"] + np.where(ok, u[at] - du[at], self.mean_u[at]))
        fits["v"] = self.sign_y * (fits["v"] + np.where(ok, v[at] - dv[at], self.mean_v[at]))
        fits["shear"] = self.sign_x * self.sign_y * fits["shear"]  # dU/dy, flow's frame, 1/pair
        kept = fits["ok"] & np.isfinite(fits["u"])
        if not np.array_equal(kept, fits["ok"]):  # the neighbours among the fits still kept
            fits["ok"] = kept
            fits["joint"] &= kept
            fits["neighbour"] = fit_neighbours(fits["x"], fits["y"] * self.dy, fits["radius"],
                                               kept)  # fmt: skip
        counts.add(cores, rows, fits, batch=batch)
        return {**cores, **{f"oseen_{k}": val for k, val in fits.items()}}

    def profile(self, parts: list[dict], dt: float, an: Any) -> tuple[dict[str, Any], list[str]]:
        """The population of the fields in ``parts`` (in pair order; ``[self.part]`` for
        :meth:`add_field`'s), per row and kind, in the run's units (``dt`` the pulse
        separation, s, 0 unknown; ``an`` gives the wall units), and what must be said (the
        core table cut)."""
        counts = VortexAccumulator(self.shape[0], self.prograde, BATCHES)
        for part in parts:
            counts.merge(part["acc"])
        p = {**self.profile_units, "dist_px": self.dist}
        table = _core_table([c for part in parts for c in part["cores"]], self.dist, p, dt,
                            self.options.fits, MAX_CORES)  # fmt: skip
        si = p["si"]
        m = p["m_per_px"] if si else 1.0
        per_s = 1.0 / dt if dt > 0 else 1.0
        keep = np.flatnonzero(self.rows_in)
        keep = keep[np.argsort(self.dist[keep])]
        strip = self.usable.sum(1)[keep] * self.dx * self.dy * m * m  # each row's searched area
        n = max(counts.n_fields, 1)
        cb = counts.count_batches[:, :, keep].transpose(0, 2, 1)  # (batch, y, kind)
        with np.errstate(invalid="ignore", divide="ignore"):
            c = counts.count[:, keep].T.astype(np.float64)  # (y, kind)
            fitted = counts.oseen_count[:, keep].T.astype(np.float64)
            circ = m * m * per_s
            prof: dict[str, Any] = {
                "y": self.dist[keep] * m,
                "dist_px": self.dist[keep],
                "rows": keep,
                "count": counts.count[:, keep].T,
                "density": c / (n * strip[:, None]),
                "radius": counts.radius_sum[:, keep].T / c * m,
                "circulation": counts.circulation_sum[:, keep].T / c * circ,
                # the Lamb-Oseen fits that are ok (rspiv.vortices.fit_oseen): their share, and
                # their core radius, circulation and convection velocity downstream
                "oseen_count": counts.oseen_count[:, keep].T,
                "oseen_share": counts.oseen_count[:, keep].T / c,
                "oseen_radius": counts.oseen_radius_sum[:, keep].T / fitted * m,
                "oseen_circulation": counts.oseen_circulation_sum[:, keep].T / fitted * circ,
                "oseen_u": counts.oseen_u_sum[:, keep].T / fitted * m * per_s,
                "threshold": self.thr[keep] * per_s,
                "threshold_factor": self.options.threshold,
                "area": strip,
                "min_vectors": self.min_vectors,
                "prograde_sign": self.prograde,
                "cores": table,
                # pair id -> (row, column, prograde) of every core: not written; the
                # conditional averages about the cores (rspiv.campaign.conditional) read it
                "core_events": {k: e for part in parts for k, e in part["events"].items()},
                "si": si,
                "per_s": dt > 0,
                "pairs": int(counts.n_fields),
                "total": int(counts.count.sum()),
                "prograde_total": int(counts.count[0].sum()),
                "fits_kept": int(counts.oseen_count.sum()),
                # kept fits closer than OSEEN_CROWDED to another in their field and not
                # fitted with it (biased by it), and those fitted with their neighbours
                "fits_crowded": sum(int(part.get("crowded", 0)) for part in parts),
                "fits_joint": sum(int(part.get("joint", 0)) for part in parts),
                # cores that were one region of swirl, split where its parts fit as vortices
                "fits_split": sum(int(part.get("split", 0)) for part in parts),
                # one standard error: the density's from the batches of contiguous pairs, the
                # means' from their cores' spread
                "density_se": batch_density_se(cb, counts.fields_batches, strip[:, None]),
                "count_batches": cb,  # (batch, y, kind)
                "fields_batches": counts.fields_batches.copy(),
            }
            for name, scale, n_of in (("radius", m, c), ("circulation", circ, c),
                                      ("oseen_radius", m, fitted),
                                      ("oseen_circulation", circ, fitted),
                                      ("oseen_u", m * per_s, fitted)):  # fmt: skip
                sq = getattr(counts, f"{name}_sq")[:, keep].T * scale**2
                mean = prof[name]
                var = np.maximum(sq / n_of - mean**2, 0.0) * n_of / (n_of - 1)
                prof[f"{name}_se"] = np.where(n_of > 1, np.sqrt(var / n_of), np.nan)
        r = an.result
        if r is not None and si and dt > 0:
            prof["y_plus"] = prof["y"] * r.u_tau / r.nu
            for name, to_plus in (("radius", r.u_tau / r.nu), ("circulation", 1.0 / r.nu),
                                  ("oseen_radius", r.u_tau / r.nu),
                                  ("oseen_circulation", 1.0 / r.nu),
                                  ("oseen_u", 1.0 / r.u_tau)):  # fmt: skip
                prof[f"{name}_plus"] = prof[name] * to_plus
                prof[f"{name}_plus_se"] = prof[f"{name}_se"] * to_plus
            prof["density_delta2"] = prof["density"] * r.delta99**2
            prof["density_delta2_se"] = prof["density_se"] * r.delta99**2
            prof["delta_99"] = float(r.delta99)
        if not self.options.fits:  # no Lamb-Oseen fit was made
            prof = {k: val for k, val in prof.items()
                    if not k.startswith("oseen_")
                    and k not in ("fits_kept", "fits_crowded", "fits_joint", "fits_split")}
        said = []
        crowded, kept = prof.get("fits_crowded", 0), prof.get("fits_kept", 0)
        if kept and crowded >= 0.05 * kept:
            said.append(
                f"{crowded} of the {kept} Lamb-Oseen fits kept lie within {OSEEN_CROWDED:g} core "
                "radii of another in their field and could not be fitted with it (the joint fit "
                f"not kept, or more than {OSEEN_JOINT_MAX} close together): a single-vortex fit "
                "is biased by its neighbour there (at 3 core radii up to 16 %; "
                "core_oseen_neighbour and core_oseen_joint in the core table)"
            )
        if table["x"].size < prof["total"]:
            said.append(
                f"the core table lists the first {table['x'].size} of {prof['total']} cores"
            )
        return prof, said


def found_line(prof: dict[str, Any], fits: bool) -> str:
    """The log's line on a population: cores, fields, prograde, fits kept, seconds."""
    kept = f"{prof.get('fits_kept', 0)} Lamb-Oseen fits kept; " if fits else ""
    return (
        f"{prof['total']} vortex cores in {prof['pairs']} pairs' fields "
        f"({prof['prograde_total']} prograde; {kept}{prof.get('seconds', 0.0):.1f} s)"
    )


def write_outputs(camp: Any, res: Any, run: RunSpec, an: Any) -> dict[str, Any] | None:
    """The vortex population of ``run`` (module docstring), written as
    ``OUT/vortices_<run>.nc`` (with ``[output] netcdf``); None when ``[statistics] vortices``
    is off."""
    st = camp.config.statistics
    if not st.vortices:
        return None
    acc = res.accumulators[run.name]
    if not acc.pair_ids:
        raise InvalidInputError("the accumulator holds no pair ids to read the fields of")
    t0 = time.perf_counter()
    ids, paths, x = run_field_files(camp, run.name, acc.pair_ids)
    options = VortexOptions(st.vortex_threshold, st.vortex_min_diameter, st.vortex_fits,
                            st.vortex_fit_shear)  # fmt: skip
    search = VortexSearch(acc, an, st.min_count, res.context.piv.final_window, x, options,
                          total=len(ids))  # fmt: skip
    screen = res.context.screens().get(run.name)
    parts, missing = each_field(paths, acc.shape, run.name, search.new_part, search.add,
                                screen=screen)  # fmt: skip
    prof, said = search.profile(parts, camp.config.flow.dt, an)
    prof["missing"] = missing
    prof["seconds"] = time.perf_counter() - t0
    camp.say(f"{run.label}: {found_line(prof, st.vortex_fits)}")
    if missing:
        said.insert(0,
            f"{len(missing)} of {len(paths)} pairs have no field file (first: pair "
            f"{missing[0]}): the vortex population holds {prof['pairs']} pairs"
        )  # fmt: skip
    return finish_pass(camp, res, run, prof, said, "vortices", "vortices", vortex_dataset)


def _core_table(found: list, dist: np.ndarray, p: dict, dt: float, fits: bool, limit: int) -> dict:
    """Every core of ``found`` (``(pair id, cores)``, in pair order), at most ``limit``, in the
    flow's units (``dt`` the pulse separation, s; 0 unknown): y the distance from the wall."""
    found = sorted(found, key=lambda t: t[0])
    m = p["m_per_px"] if p.get("si") else 1.0
    per_s = 1.0 / dt if dt > 0 else 1.0
    names = CORE_FIELDS + (tuple(f"oseen_{k}" for k in OSEEN_FIELDS) if fits else ())
    # (a core found before an array was added, kept in a checkpoint, has NaN there)
    cols = {k: [c.get(k, np.full(c["x"].size, np.nan)) for _, c in found] for k in names}
    out = {k: np.concatenate(v)[:limit] if v else np.zeros(0) for k, v in cols.items()}
    pair = [np.full(c["x"].size, pid) for pid, c in found]
    out["pair"] = np.concatenate(pair)[:limit] if pair else np.zeros(0, np.int64)
    out["y"] = np.interp(out["y"], np.arange(dist.size), dist) * m
    out["x"] = out["x"] * m
    out["radius"] = out["radius"] * m
    out["circulation"] = out["circulation"] * m * m * per_s
    out["peak"] = out["peak"] * per_s
    if not fits:
        return out
    out["oseen_ok"] = out["oseen_ok"].astype(bool)
    out["oseen_y"] = np.interp(out["oseen_y"], np.arange(dist.size), dist) * m  # NaN stays
    out["oseen_x"] = out["oseen_x"] * m
    out["oseen_radius"] = out["oseen_radius"] * m
    out["oseen_circulation"] = out["oseen_circulation"] * m * m * per_s
    out["oseen_u"] = out["oseen_u"] * m * per_s
    out["oseen_v"] = out["oseen_v"] * m * per_s
    out["oseen_shear"] = out["oseen_shear"] * per_s
    return out


def vortex_dataset(prof: dict, run: Any) -> Any:
    """``vortices_<run>.nc`` of the population ``prof`` (module docstring)."""
    import xarray as xr

    length = "m" if prof["si"] else "pix"
    circ = ("m2 s-1" if prof["per_s"] else "m2") if prof["si"] else "pix2"
    rate = "s-1" if prof["per_s"] else "1"
    dims = ("y", "kind")
    t = prof["cores"]
    ds = xr.Dataset(
        coords={
            "y": ("y", prof["y"], {"units": length, "long_name": "distance from the wall"}),
            "kind": ("kind", ["prograde", "retrograde"]),
        }
    )
    ds["count"] = (dims, prof["count"], {"long_name": "cores whose centroid is in the row"})
    ds["density"] = (dims, prof["density"], {"units": f"{length}-2",
                     "long_name": "cores per area of the row's strip per pair"})  # fmt: skip
    ds["radius"] = (dims, prof["radius"], {"units": length,
                    "long_name": "mean radius of a disc of the core's area"})  # fmt: skip
    ds["circulation"] = (dims, prof["circulation"], {"units": circ,
                         "long_name": "mean circulation inside the threshold"})  # fmt: skip
    ds["threshold"] = ("y", prof["threshold"], {"units": rate,
                       "long_name": "|Lambda_ci| of a core's vectors at least"})  # fmt: skip
    for k in ("density", "radius", "circulation"):  # one standard error
        ds[f"{k}_se"] = (dims, prof[f"{k}_se"], {"units": ds[k].attrs["units"],
                         "long_name": f"standard error of {k}" + (
                             " (batches of contiguous pairs)" if k == "density" else "")})
    for k in ("pair", "x", "y", "sign", "radius", "circulation", "peak", "region"):
        ds[f"core_{k}"] = ("core", t[k])
    ds["core_region"].attrs["long_name"] = ("the thresholded region of the pair's field the "
                                            "core is part of (split at its swirl's saddles)")
    if "oseen_count" in prof:
        _oseen_variables(ds, prof, dims, length, circ)
    if "y_plus" in prof:
        ds["y_plus"] = ("y", prof["y_plus"], {"units": "1"})
        for k in ("radius_plus", "circulation_plus", "density_delta2", "oseen_radius_plus",
                  "oseen_circulation_plus", "oseen_u_plus"):  # fmt: skip
            for name in (k, f"{k}_se"):
                if name in prof:
                    ds[name] = (dims, prof[name], {"units": "1"})
        ds.attrs["delta_99"] = prof["delta_99"]
    ds.attrs.update(
        {
            "run": run.name,
            "label": run.label,
            "pairs": prof["pairs"],
            "min_vectors": prof["min_vectors"],
            "prograde_sign": prof["prograde_sign"],
            **({k: prof[k] for k in ("fits_kept", "fits_crowded", "fits_joint", "fits_split")}
               if "fits_kept" in prof else {}),
            "description": "rspiv vortex cores (rspiv.vortices): connected vectors of signed "
            "swirling strength beyond the row's threshold; the flow's frame (x downstream, y "
            "away from the wall), sign +1 counter-clockwise",
        }
    )
    return ds


def _oseen_variables(ds: Any, prof: dict, dims: tuple, length: str, circ: str) -> None:
    """The Lamb-Oseen fits' variables of ``vortices_<run>.nc`` (``[statistics] vortex_fits``)."""
    t = prof["cores"]
    vel = ("m s-1" if prof["per_s"] else "m") if prof["si"] else "pix"
    ds["oseen_count"] = (dims, prof["oseen_count"], {"long_name": "cores whose Lamb-Oseen "
                         "fit is kept (rspiv.vortices.fit_oseen)"})  # fmt: skip
    ds["oseen_share"] = (dims, prof["oseen_share"], {"units": "1"})
    ds["oseen_radius"] = (dims, prof["oseen_radius"], {"units": length, "long_name":
                          "mean Lamb-Oseen core radius r_c of the fits kept"})  # fmt: skip
    ds["oseen_circulation"] = (dims, prof["oseen_circulation"], {"units": circ, "long_name":
                               "mean Lamb-Oseen circulation of the fits kept"})  # fmt: skip
    ds["oseen_u"] = (dims, prof["oseen_u"], {"units": vel, "long_name":
                     "mean convection velocity downstream of the fits kept"})  # fmt: skip
    for k in ("oseen_radius", "oseen_circulation", "oseen_u"):
        ds[f"{k}_se"] = (dims, prof[f"{k}_se"], {"units": ds[k].attrs["units"],
                         "long_name": f"standard error of {k}"})  # fmt: skip
    for k in OSEEN_FIELDS:
        ds[f"core_oseen_{k}"] = ("core", t[f"oseen_{k}"])
    ds["core_oseen_neighbour"].attrs.update({"units": "1", "long_name": "distance to the "
        f"nearest other kept fit in their mean core radius (below {OSEEN_CROWDED:g}: biased "
        "unless fitted jointly)"})
    ds["core_oseen_joint"].attrs["long_name"] = "fitted together with its neighbours"
    ds["core_oseen_shear"].attrs.update({"units": "s-1" if prof["per_s"] else "1", "long_name":
                                         "background dU/dy of the fit, without the mean's"})


def report_section(camp: Any, res: Any) -> Any:
    """The report's section on the main run's vortex population, or None."""
    main = res.context.runs[0]
    prof = res.vortices.get(main.name)
    if prof is None or "y_plus" not in prof:
        return None
    total = prof["count"].sum(axis=0)
    text = (
        f"Vortex cores over {prof['pairs']} pairs (connected vectors whose signed swirling "
        f"strength exceeds {camp.config.statistics.vortex_threshold:g} times its rms at their "
        f"height, at least {prof['min_vectors']} vectors: a disc as wide as "
        f"{camp.config.statistics.vortex_min_diameter:g} final window): {total[0]} "
        f"prograde (turning with the mean shear) and {total[1]} retrograde. Densities are per "
        "delta_99^2 and pair (error bars: one standard error from 8 batches of contiguous "
        "pairs); the measurement noise makes cores too and raises the threshold."
        + (_oseen_sentence(prof, camp.config.statistics.vortex_fit_shear)
           if "oseen_count" in prof else "")
    )
    return pass_section(
        camp, prof, "Vortex population", text, "rspiv.plots.vortices:plot_vortices", "vortices",
        f"{main.label}: vortex population",
    )


def _oseen_sentence(prof: dict, shear: bool) -> str:
    """The report's sentence on the Lamb-Oseen fits (wall units)."""
    n = prof["oseen_count"].sum(axis=0)
    if n.sum() == 0:
        return (
            " No core's Lamb-Oseen fit was kept (a core radius inside its patch, a centre near "
            "the core's and 70 % of the patch's velocity explained): the swirling regions are "
            "not resolved Lamb-Oseen vortices (a patch in solid-body rotation fits a vortex "
            "larger than itself), and no radius, circulation or convection velocity is given."
        )
    parts = []
    for i, kind in enumerate(("prograde", "retrograde")):
        if n[i] == 0:
            continue
        cnt = prof["oseen_count"][:, i]
        mean = {k: np.nansum(prof[f"oseen_{k}_plus"][:, i] * cnt) / n[i]
                for k in ("radius", "circulation", "u")}  # fmt: skip
        parts.append(f"{n[i]} {kind}: r_c+ {mean['radius']:.1f}, Gamma+ "
                     f"{mean['circulation']:.0f}, convected at {mean['u']:.1f} u_tau")  # fmt: skip
    total = prof["count"].sum()
    return (
        f" A Lamb-Oseen vortex{' in a uniform background shear' if shear else ''} fitted to "
        f"the fluctuations about each core (rspiv.vortices.fit_oseen) explains 70 % or more of "
        f"its patch's velocity for {n.sum()} of {total} "
        f"cores ({'; '.join(parts)}; means over the fits kept). The final window widens a core: "
        "r_c^2 + W^2/6 for a W px window."
    )
