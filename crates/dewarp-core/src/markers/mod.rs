//! Marker detection on a calibration-target image, with a per-marker uncertainty.
//!
//! Files: [`mod@survey`] (size and polarity from the image), `coarse` (block averaging, template,
//! FFT correlation, peaks), `blob` (the sub-pixel fit and its covariance), `disc` (the
//! blurred-disc profile), this file (the pipeline).
//!
//! Pipeline:
//!
//! 1. **Size and polarity.** Taken from the caller when both are given; otherwise read from
//!    the image by the [`mod@survey`]: the size on a geometric ladder and the polarity at which the
//!    detections form the strongest regular lattice (clutter, glare and particles form none).
//! 2. **Coarse detection.** The image is block-averaged by `d = max(1, floor(s / 2.5))` (47 MP
//!    stays memory-light and fast) and cross-correlated, by FFT (rustfft, zero padding against
//!    wrap-around), with a zero-mean template: a Gaussian dot of standard deviation `s / d`, or a
//!    cross of arm length `6 s / d` and arm width `s / d`. A zero-mean template ignores smooth
//!    background and illumination. Peaks are local maxima over a `(2r+1)^2` neighbourhood above
//!    both `threshold` x a reference and `min_snr` x the robust (MAD) noise of the correlation;
//!    the reference is the surveyed lattice's median level (a glare spot or a 5x vignetting
//!    leaves it alone), or the strongest peak when size and polarity were given.
//! 3. **Size and profile.** When the size was surveyed (a ladder step) it is refined to the
//!    median fitted width of the [`PROFILE_SAMPLE`] strongest markers; the same Gaussian fits
//!    choose the dot profile ([`DotProfile::Auto`]): a printed disc when they show a flat top
//!    (a score test, [`FLAT_TOP_THRESHOLD`]), with a tilted top when the discs are large
//!    ([`TILT_FLATNESS`]).
//! 4. **Sub-pixel fit.** Around each peak, at full resolution, the profile plus a plane
//!    (`b0 + bx xw + by yw + A g`, see `blob`) is fitted to the pixel values by the project's
//!    Levenberg-Marquardt ([`crate::lm`], MINPACK stopping rules) on normal equations
//!    accumulated pixel by pixel (no per-pixel storage). The covariance of (x0, y0) is the
//!    heteroscedasticity-consistent sandwich estimate
//!    `(J^T J)^-1 (sum r_k^2 J_k^T J_k) (J^T J)^-1 * n / (n - p)`, valid under shot noise whose
//!    variance grows with the signal, and honest because the profile fits (its residuals are
//!    noise, not misfit). For crosses the blob term is the brighter of two perpendicular
//!    Gaussian bars; `size_px` is then the bar's Gaussian sigma.
//!    Fits that diverge (centre moving more than `s`, width out of range, amplitude of the
//!    wrong sign) are dropped, and so are fits whose centre's sigma exceeds the marker size
//!    (or 1 px); duplicates closer than `s` are merged. Only starts on the coarse
//!    lattice, or within 1.5 of its steps of it (the plate's edge), are fitted: clutter, glare
//!    and text beyond are reported (`rejected`), never fitted.

mod blob;
mod coarse;
pub(crate) mod disc;
pub mod survey;
mod touching;

use crate::error::{DewarpError, Result};
use blob::{fit_blob, BlobScratch, Profile};
use coarse::{block_mean, correlate_marker, correlation_noise, local_maxima};
pub use image_core::Pixel;
use ndarray::ArrayView2;
use rayon::prelude::*;
pub use survey::{survey, Survey};
pub use touching::{touching_share, TOUCH_SHARE};

/// The shape of the markers.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum MarkerKind {
    /// Round dots.
    Dot,
    /// Crosses (+).
    Cross,
}

impl std::str::FromStr for MarkerKind {
    type Err = DewarpError;
    fn from_str(s: &str) -> Result<Self> {
        match s.to_ascii_lowercase().as_str() {
            "dot" => Ok(Self::Dot),
            "cross" => Ok(Self::Cross),
            _ => Err(DewarpError::InvalidInput(format!(
                "marker kind {s:?} is not one of \"dot\", \"cross\""
            ))),
        }
    }
}

/// Options of [`detect_markers`].
#[derive(Debug, Clone, PartialEq)]
pub struct DetectOptions {
    /// Marker shape.
    pub kind: MarkerKind,
    /// Dot size as a Gaussian standard deviation in px; `None` estimates it.
    pub size_px: Option<f64>,
    /// Keep correlation peaks above this fraction of the strongest peak.
    pub threshold: f64,
    /// Keep correlation peaks above this multiple of the correlation's robust noise.
    pub min_snr: f64,
    /// Markers darker than the background; `None` finds the polarity ([`mod@survey`]).
    pub dark: Option<bool>,
    /// The dot profile of the sub-pixel fit.
    pub profile: DotProfile,
}

/// The dot profile of the sub-pixel fit ([`MarkerKind::Dot`] only; crosses use their bars).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum DotProfile {
    /// Chosen from the image: the blurred disc when the strongest dots' Gaussian fits show a
    /// flat top (median score above [`FLAT_TOP_THRESHOLD`]), else the Gaussian.
    Auto,
    /// Isotropic Gaussian blob.
    Gaussian,
    /// Uniform disc blurred by a Gaussian point-spread function (a printed dot).
    Disc,
}

impl std::str::FromStr for DotProfile {
    type Err = DewarpError;
    fn from_str(s: &str) -> Result<Self> {
        match s.to_ascii_lowercase().as_str() {
            "auto" => Ok(Self::Auto),
            "gaussian" | "gauss" => Ok(Self::Gaussian),
            "disc" | "disk" => Ok(Self::Disc),
            _ => Err(DewarpError::InvalidInput(format!(
                "dot profile {s:?} is not one of \"auto\", \"gaussian\", \"disc\""
            ))),
        }
    }
}

/// The size refinement and the automatic profile choice fit this many of the strongest dots,
pub const PROFILE_SAMPLE: usize = 12;
/// ... each fit within this many evaluations (a non-converged Gaussian fit counts as a flat top).
pub const SAMPLE_MAX_EVALS: usize = 100;
/// Each marker's fit gives up after this many evaluations (a blob that needs more is no marker
/// this model describes: it is dropped, never kept unconverged).
pub const FIT_MAX_EVALS: usize = 300;
/// ... and take the disc when the median flat-top score of their Gaussian fits exceeds this
/// (under a Gaussian profile the score follows a chi-square of one degree of freedom, median
/// 0.45).
pub const FLAT_TOP_THRESHOLD: f64 = 25.0;
/// Discs whose median radius is at least this many blur sigmas are fitted with a tilted top
/// (the illumination gradient across a large disc; see `blob`'s `DiscTilted`).
pub const TILT_FLATNESS: f64 = 6.0;

impl Default for DetectOptions {
    fn default() -> Self {
        Self {
            kind: MarkerKind::Dot,
            size_px: None,
            threshold: 0.25,
            min_snr: 8.0,
            dark: None,
            profile: DotProfile::Auto,
        }
    }
}

/// One detected marker (image px).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Marker {
    pub x: f64,
    pub y: f64,
    /// Standard uncertainty of x and y (px) and their covariance (px^2).
    pub sigma_x: f64,
    pub sigma_y: f64,
    pub cov_xy: f64,
    /// Fitted blob amplitude (counts) and width (px): the Gaussian sigma, or for a disc the
    /// blur sigma of its edge.
    pub amplitude: f64,
    pub width: f64,
    /// Disc radius (px); 0 for a Gaussian dot or a cross.
    pub radius: f64,
    /// Normalised correlation strength of the coarse peak.
    pub strength: f64,
}

/// Result of [`detect_markers`].
#[derive(Debug, Clone, PartialEq)]
pub struct Detection {
    pub markers: Vec<Marker>,
    /// Dot size used (Gaussian sigma, px).
    pub size_px: f64,
    /// Block-averaging factor of the coarse detection.
    pub downsample: usize,
    /// The profile fitted: "gaussian", "disc" or "cross".
    pub profile: &'static str,
    /// The polarity used (markers darker than the background).
    pub dark: bool,
    /// The survey that chose the size and polarity (`None` when both were given).
    pub survey: Option<Survey>,
    /// Blobs off the coarse lattice (clutter, glare), at their coarse positions (px): reported,
    /// not fitted (empty when the detections formed no lattice: then every one was fitted).
    pub rejected: Vec<[f64; 2]>,
}

/// Detect the markers of a calibration-target image; see the module documentation.
pub fn detect_markers<T: Pixel>(image: ArrayView2<T>, opts: &DetectOptions) -> Result<Detection> {
    let (h, w) = image.dim();
    if h < 16 || w < 16 {
        return Err(DewarpError::InvalidInput(format!(
            "marker detection: image of {h} x {w} px is too small"
        )));
    }
    let valid = opts.threshold > 0.0 && opts.threshold < 1.0 && opts.min_snr > 0.0;
    if !valid {
        return Err(DewarpError::InvalidInput(
            "marker detection: threshold must lie in (0, 1) and min_snr be > 0".into(),
        ));
    }
    if image.iter().any(|v| !v.to_f64().is_finite()) {
        return Err(DewarpError::InvalidInput(
            "marker detection: image contains NaN or inf".into(),
        ));
    }
    if let Some(s) = opts.size_px {
        if !(s.is_finite() && s > 0.0) {
            return Err(DewarpError::InvalidInput(format!(
                "marker detection: marker size {s} px must be > 0"
            )));
        }
    }
    // Size and polarity from the survey unless both are given.
    let surveyed = match (opts.size_px, opts.dark) {
        (Some(_), Some(_)) => None,
        _ => Some(survey(
            image,
            opts.kind,
            opts.size_px,
            opts.dark,
            opts.min_snr,
        )?),
    };
    let (s, dark) = match &surveyed {
        Some(sv) => (sv.size_px, sv.dark),
        None => (opts.size_px.unwrap_or(1.0), opts.dark.unwrap_or(false)),
    };
    let sign = if dark { -1.0 } else { 1.0 };
    if s * 6.0 > h.min(w) as f64 {
        return Err(DewarpError::InvalidInput(format!(
            "marker detection: marker size {s:.1} px is too large for a {h} x {w} image"
        )));
    }
    let d = ((s / 2.5).floor() as usize).max(1);
    let coarse = block_mean(image, d, sign);
    let sc = s / d as f64;
    let corr = correlate_marker(&coarse, opts.kind, sc);
    let noise = correlation_noise(&coarse, &corr, d, coarse::is_integer::<T>());
    let (hc, wc) = corr.dim();
    let r = ((1.5 * sc).round() as usize).max(1);
    let cmax = corr.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    // The threshold's reference: the lattice's median level when surveyed (glare and
    // vignetting leave it alone), else the strongest peak.
    let reference = surveyed.as_ref().map_or(cmax, |sv| sv.level);
    let thr = (opts.threshold * reference).max(opts.min_snr * noise.max(1e-300));
    if cmax.is_nan() || cmax <= thr {
        return Err(DewarpError::InvalidInput(
            "marker detection: no marker-like peaks found (blank image or wrong marker kind)"
                .into(),
        ));
    }
    let peaks = local_maxima(&corr, 1.0, thr, r);
    let off = 0.5 * (d as f64 - 1.0);
    let sub = |a: f64, b: f64, c: f64| {
        let den = a - 2.0 * b + c;
        if den < 0.0 {
            (0.5 * (a - c) / den).clamp(-0.5, 0.5)
        } else {
            0.0
        }
    };
    // Coarse peak -> full-resolution start of the fit.
    let starts: Vec<(f64, f64, f64)> = peaks
        .iter()
        .map(|&(y, x, v)| {
            let fx = if x > 0 && x + 1 < wc {
                sub(corr[[y, x - 1]], v, corr[[y, x + 1]])
            } else {
                0.0
            };
            let fy = if y > 0 && y + 1 < hc {
                sub(corr[[y - 1, x]], v, corr[[y + 1, x]])
            } else {
                0.0
            };
            let x0 = (x as f64 + fx) * d as f64 + off;
            let y0 = (y as f64 + fy) * d as f64 + off;
            (x0, y0, v)
        })
        .collect();
    // The survey's size is a ladder step: refine it from the strongest markers' fitted widths,
    // and choose the dot profile from the same fits.
    let base = if opts.kind == MarkerKind::Cross {
        Profile::Cross
    } else {
        Profile::Gauss
    };
    let auto = opts.kind == MarkerKind::Dot && opts.profile == DotProfile::Auto;
    // Fit windows stay within half the lattice's pitch (a dense lattice's neighbours out).
    let max_hw = surveyed
        .as_ref()
        .map_or(0, |sv| (0.5 * sv.pitch_px).floor().max(3.0) as usize);
    // Which starts the coarse lattices hold (all when they form none).
    let on_lattice = coarse_lattices(&starts, [0.5 * (w as f64 - 1.0), 0.5 * (h as f64 - 1.0)]);
    let to_fit = &on_lattice;
    let (width, auto_profile) = if auto || opts.size_px.is_none() {
        sample_fits(image, &starts, &on_lattice, s, sign, base, max_hw)
    } else {
        (s, base)
    };
    // A dot is smaller than a fifth of the pitch in sigma (its template stays within a pitch).
    let s = match (&surveyed, opts.size_px) {
        (Some(sv), None) => width.min(0.2 * sv.pitch_px),
        (None, None) => width,
        (_, Some(_)) => s,
    };
    let profile = match (opts.kind, opts.profile) {
        (MarkerKind::Cross, _) => Profile::Cross,
        (MarkerKind::Dot, DotProfile::Gaussian) => Profile::Gauss,
        (MarkerKind::Dot, DotProfile::Disc) => Profile::Disc,
        (MarkerKind::Dot, DotProfile::Auto) => auto_profile,
    };
    // One scratch (LM solver, border buffer, disc table) per rayon job: no allocation per
    // marker once sized.
    // Starts off the coarse lattice (clutter, glare, noise) are reported, not fitted: a junk
    // blob never costs a fit (when the starts form no lattice, every start is fitted).
    let rejected: Vec<[f64; 2]> = starts
        .iter()
        .zip(to_fit)
        .filter(|(_, &on)| !on)
        .map(|(st, _)| [st.0, st.1])
        .collect();
    let mut markers: Vec<Marker> = starts
        .par_iter()
        .zip(to_fit.par_iter())
        .filter(|(_, &on)| on)
        .map_init(
            || BlobScratch::with_budget(FIT_MAX_EVALS).windows(2.5, max_hw),
            |scratch, (&(x0, y0, v), _)| {
                let f = fit_blob(image, x0, y0, s, sign, profile, scratch)?;
                // A fit that cannot place its centre (a degenerate profile on a blob that is no
                // dot) is no marker: its sigma would poison every average of the markers'.
                let worst = f.cov[0][0].max(f.cov[1][1]).sqrt();
                if worst.is_nan() || worst > s.max(1.0) {
                    return None;
                }
                Some(Marker {
                    x: f.p[1],
                    y: f.p[2],
                    sigma_x: f.cov[0][0].sqrt(),
                    sigma_y: f.cov[1][1].sqrt(),
                    cov_xy: f.cov[0][1],
                    amplitude: sign * f.p[0],
                    width: f.p[3],
                    radius: f.p[7],
                    strength: v / cmax,
                })
            },
        )
        .flatten()
        .collect();
    // Merge duplicates (two peaks converging on one blob): keep the stronger.
    markers.sort_by(|a, b| b.strength.total_cmp(&a.strength));
    let mut kept: Vec<Marker> = Vec::with_capacity(markers.len());
    for m in markers {
        if kept.iter().all(|k| (k.x - m.x).hypot(k.y - m.y) > s) {
            kept.push(m);
        }
    }
    if kept.is_empty() {
        return Err(DewarpError::InvalidInput(
            "marker detection: no marker survived the sub-pixel fit".into(),
        ));
    }
    kept.sort_by(|a, b| a.y.total_cmp(&b.y).then(a.x.total_cmp(&b.x)));
    Ok(Detection {
        markers: kept,
        size_px: s,
        downsample: d,
        profile: match profile {
            Profile::Gauss => "gaussian",
            Profile::Cross => "cross",
            Profile::Disc | Profile::DiscTilted => "disc",
        },
        dark,
        survey: surveyed,
        rejected,
    })
}

/// The [`PROFILE_SAMPLE`] strongest starts on the coarse lattice (by coarse correlation):
/// markers, not clutter or glare.
/// At most this many lattices of one step are looked for among the coarse starts.
const MAX_LATTICES: usize = 4;

/// Which starts lie on a lattice: the grid indexed from `centre`, then, among the starts it left
/// out, up to [`MAX_LATTICES`] - 1 more grids of at least 12 points whose steps are within 20 %
/// of the first's (a stepped or 3-D target's other sections, a two-level plate's other level
/// seen obliquely: they are fitted and the plate analysis decides; clutter forms none). Each
/// grid is extended by one ring: a start within 0.3 of a step of the site beyond its edge,
/// extrapolated from the sites before it, is on it too (edge markers the indexing pruned:
/// a two-level plate's corners touch one marker of the union). All starts when they form no
/// lattice.
fn coarse_lattices(starts: &[(f64, f64, f64)], centre: [f64; 2]) -> Vec<bool> {
    let mut on = vec![false; starts.len()];
    let mut left: Vec<usize> = (0..starts.len()).collect();
    let mut step0 = None;
    for _ in 0..MAX_LATTICES {
        let pts: Vec<[f64; 2]> = left.iter().map(|&k| [starts[k].0, starts[k].1]).collect();
        let Ok(g) = crate::grid::index_grid(&pts, centre, 0.3) else {
            break;
        };
        let n = g.index.iter().filter(|i| i.is_some()).count();
        let step = 0.5 * (g.a1[0].hypot(g.a1[1]) + g.a2[0].hypot(g.a2[1]));
        match step0 {
            None => step0 = Some(step),
            Some(s0) if n < 12 || (step / s0 - 1.0).abs() > 0.2 => break,
            Some(_) => {}
        }
        let mut sites: std::collections::HashMap<(i32, i32), usize> = Default::default();
        for (q, i) in g.index.iter().enumerate() {
            if let Some(ij) = i {
                on[left[q]] = true;
                sites.insert(*ij, left[q]);
            }
        }
        left.retain(|&k| !on[k]);
        extend_ring(starts, &sites, &mut left, &mut on);
        if left.len() < 12 {
            break;
        }
    }
    if step0.is_none() {
        return vec![true; starts.len()];
    }
    on
}

/// One ring of sites beyond a grid's edge (see [`coarse_lattices`]): starts of `left` taken
/// onto it are marked `on` and removed from `left`.
fn extend_ring(
    starts: &[(f64, f64, f64)],
    sites: &std::collections::HashMap<(i32, i32), usize>,
    left: &mut Vec<usize>,
    on: &mut [bool],
) {
    let p = |k: usize| [starts[k].0, starts[k].1];
    // In site order: the result does not depend on the map's iteration order.
    let mut order: Vec<((i32, i32), usize)> = sites.iter().map(|(&ij, &k)| (ij, k)).collect();
    order.sort_unstable();
    for ((i, j), k) in order {
        for (di, dj) in [(1, 0), (-1, 0), (0, 1), (0, -1)] {
            if sites.contains_key(&(i + di, j + dj)) {
                continue;
            }
            let Some(&b) = sites.get(&(i - di, j - dj)) else {
                continue;
            };
            // The step two back crosses between the same parity classes as the one predicted
            // (a two-level union's parallax cancels, see crate::grid); else the last step.
            let (pk, pb) = (p(k), p(b));
            let back = sites.get(&(i - 2 * di, j - 2 * dj)).map(|&c| p(c));
            let pred = match back {
                Some(pc) => [pk[0] + pb[0] - pc[0], pk[1] + pb[1] - pc[1]],
                None => [2.0 * pk[0] - pb[0], 2.0 * pk[1] - pb[1]],
            };
            let tol = 0.3 * (pk[0] - pb[0]).hypot(pk[1] - pb[1]);
            let best = left
                .iter()
                .enumerate()
                .map(|(n, &q)| (n, (p(q)[0] - pred[0]).hypot(p(q)[1] - pred[1])))
                .filter(|&(_, d)| d < tol)
                .min_by(|a, b| a.1.total_cmp(&b.1));
            if let Some((n, _)) = best {
                on[left[n]] = true;
                left.swap_remove(n);
            }
        }
    }
}

fn strongest(starts: &[(f64, f64, f64)], on_lattice: &[bool]) -> Vec<usize> {
    let mut order: Vec<usize> = (0..starts.len()).filter(|&k| on_lattice[k]).collect();
    order.sort_by(|&a, &b| starts[b].2.total_cmp(&starts[a].2));
    order.truncate(PROFILE_SAMPLE);
    order
}

/// The strongest markers' fits with `profile` (Gauss or Cross): their median width (`s` if
/// fewer than 3 fits succeed) and, for dots, the profile to fit: the blurred disc when the
/// median flat-top score of the Gaussian fits exceeds [`FLAT_TOP_THRESHOLD`] (failed Gaussian
/// fits count as flat-topped), tilted when the discs are flat-topped (radius at least
/// [`TILT_FLATNESS`] blur sigmas), else the Gaussian.
fn sample_fits<T: Pixel>(
    image: ArrayView2<T>,
    starts: &[(f64, f64, f64)],
    on_lattice: &[bool],
    s: f64,
    sign: f64,
    profile: Profile,
    max_hw: usize,
) -> (f64, Profile) {
    // Wide windows (4 s): a disc's flat top and its background ring both in view.
    let budget = || BlobScratch::with_budget(SAMPLE_MAX_EVALS).windows(4.0, max_hw);
    let sample = strongest(starts, on_lattice);
    let fits: Vec<Option<(f64, f64)>> = sample
        .par_iter()
        .map_init(budget, |scratch, &k| {
            let (x0, y0, _) = starts[k];
            fit_blob(image, x0, y0, s, sign, profile, scratch).map(|f| (f.p[3], f.flat_top))
        })
        .collect();
    let mut widths: Vec<f64> = fits.iter().flatten().map(|f| f.0).collect();
    let width = if widths.len() >= 3 {
        coarse::median_mut(&mut widths)
    } else {
        s
    };
    if profile != Profile::Gauss {
        return (width, profile);
    }
    let mut scores: Vec<f64> = fits
        .iter()
        .map(|f| f.map_or(f64::INFINITY, |f| f.1))
        .collect();
    if scores.is_empty() || coarse::median_mut(&mut scores) <= FLAT_TOP_THRESHOLD {
        return (width, Profile::Gauss);
    }
    let mut flat: Vec<f64> = sample[..sample.len().min(8)]
        .par_iter()
        .map_init(budget, |scratch, &k| {
            let (x0, y0, _) = starts[k];
            fit_blob(image, x0, y0, width, sign, Profile::Disc, scratch).map(|f| f.p[7] / f.p[3])
        })
        .flatten()
        .collect();
    if flat.is_empty() {
        return (width, Profile::Gauss);
    }
    let tilted = coarse::median_mut(&mut flat) >= TILT_FLATNESS;
    (
        width,
        if tilted {
            Profile::DiscTilted
        } else {
            Profile::Disc
        },
    )
}

#[cfg(test)]
mod tests;
