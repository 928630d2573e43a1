//! The survey: the marker size and polarity read from the image, with no hand tuning.
//!
//! A target is a lattice of equal dots; clutter (plate edges, frames, glare, dirt) is not.
//! The survey therefore asks, for each candidate size on a geometric ladder
//! `s_k = 1.5^k px` (Gaussian sigma, dots ~2.5 s across; `k` from coarse to fine) and each
//! polarity, how large a lattice the detections at that size form:
//!
//! 1. the central region of the image (at most `SURVEY_PX` coarse px square) is block-averaged
//!    by `d = max(1, floor(s / 2.5))` and correlated with the zero-mean unit-norm template of
//!    the marker kind at size `s / d` (one FFT serves both polarities: dark dots are the peaks
//!    of the negated correlation);
//! 2. local maxima above `min_snr` x the correlation's robust noise are indexed on a square
//!    grid ([`crate::grid::index_grid`]);
//! 3. the candidate is scored by the number of indexed points and their median
//!    signal-to-noise ratio.
//!
//! At each size the polarity of the stronger lattice is kept (the other polarity's peaks are the
//! template's side lobes between the dots, about half as strong or less). The chosen candidate
//! is the one of highest median SNR (the matched filter peaks at the dots' own size) among those
//! whose lattice is at least half as dense (points per px surveyed) as the densest. The scan
//! stops early once
//! a lattice of at least 12 points is found and two finer sizes in a row fall below half its
//! SNR. The lattice's median correlation level is returned as the reference of the detection
//! threshold (robust to glare and vignetting, unlike the strongest peak).

use super::coarse::{
    block_mean, correlate_marker, correlation_noise, is_integer, local_maxima, median_mut,
};
use super::MarkerKind;
use crate::error::{DewarpError, Result};
use crate::grid::index_grid;
use image_core::Pixel;
use ndarray::{s, ArrayView2};

/// Side (coarse px) of the central region the survey correlates at each size.
pub const SURVEY_PX: usize = 1024;
/// Largest marker size surveyed (Gaussian sigma, px; discs ~100 px across).
pub const SURVEY_MAX_SIZE: f64 = 40.0;

/// What the survey found.
#[derive(Debug, Clone, PartialEq)]
pub struct Survey {
    /// Marker size (Gaussian sigma, px) on the ladder.
    pub size_px: f64,
    /// Markers darker than the background.
    pub dark: bool,
    /// Points of the lattice found, and points detected at that size.
    pub n_lattice: usize,
    pub n_detected: usize,
    /// Median correlation of the lattice's points at that size, in units of the correlation's
    /// robust noise (SNR) and per unit of block-averaged intensity (`level`).
    pub snr: f64,
    pub level: f64,
    /// The lattice's pitch (mean step, px).
    pub pitch_px: f64,
}

struct Candidate {
    s: f64,
    dark: bool,
    n: usize,
    n_det: usize,
    snr: f64,
    level: f64,
    pitch: f64,
}

/// Survey the image; `size_px` and `dark` restrict the search when given.
pub fn survey<T: Pixel>(
    image: ArrayView2<T>,
    kind: MarkerKind,
    size_px: Option<f64>,
    dark: Option<bool>,
    min_snr: f64,
) -> Result<Survey> {
    let (h, w) = image.dim();
    let ladder: Vec<f64> = match size_px {
        Some(s) => vec![s],
        None => {
            let mut v = Vec::new();
            let mut s = 1.0f64;
            while s <= SURVEY_MAX_SIZE && 6.0 * s <= h.min(w) as f64 {
                v.push(s);
                s *= 1.5;
            }
            v.reverse();
            v
        }
    };
    let polarities: Vec<bool> = match dark {
        Some(d) => vec![d],
        None => vec![false, true],
    };
    let mut cands: Vec<Candidate> = Vec::new();
    // The most blobs seen at one size (for the error message).
    let mut most = (0usize, 0.0f64);
    let mut best_snr = 0.0f64;
    let mut below = 0;
    for &s in &ladder {
        let d = ((s / 2.5).floor() as usize).max(1);
        let (ch, cw) = (h.min(SURVEY_PX * d), w.min(SURVEY_PX * d));
        let (y0, x0) = ((h - ch) / 2, (w - cw) / 2);
        let crop = image.slice(s![y0..y0 + ch, x0..x0 + cw]);
        let coarse = block_mean(crop, d, 1.0);
        let sc = s / d as f64;
        let corr = correlate_marker(&coarse, kind, sc);
        let noise = correlation_noise(&coarse, &corr, d, is_integer::<T>());
        let r = ((1.5 * sc).round() as usize).max(1);
        let off = 0.5 * (d as f64 - 1.0);
        let mut step_best = 0.0f64;
        let mut step_cand: Option<Candidate> = None;
        for &dk in &polarities {
            let sign = if dk { -1.0 } else { 1.0 };
            let mut pk: Vec<(f64, [f64; 2])> = local_maxima(&corr, sign, min_snr * noise, r)
                .into_iter()
                .map(|(y, x, v)| {
                    let p = [
                        x0 as f64 + x as f64 * d as f64 + off,
                        y0 as f64 + y as f64 * d as f64 + off,
                    ];
                    (v, p)
                })
                .collect();
            pk.sort_by(|a, b| b.0.total_cmp(&a.0));
            pk.truncate(4000);
            let pts: Vec<[f64; 2]> = pk.iter().map(|p| p.1).collect();
            let centre = [
                x0 as f64 + 0.5 * (cw as f64 - 1.0),
                y0 as f64 + 0.5 * (ch as f64 - 1.0),
            ];
            if pts.len() > most.0 {
                most = (pts.len(), s);
            }
            let Ok(g) = index_grid(&pts, centre, 0.3) else {
                continue;
            };
            let mut vals: Vec<f64> = g
                .index
                .iter()
                .zip(&pk)
                .filter(|(i, _)| i.is_some())
                .map(|(_, p)| p.0)
                .collect();
            let n = vals.len();
            if n < 5 {
                continue;
            }
            let level = median_mut(&mut vals);
            let snr = level / noise;
            step_best = step_best.max(snr);
            let c = Candidate {
                s,
                dark: dk,
                n,
                n_det: pk.len(),
                snr,
                level,
                pitch: 0.5 * (g.a1[0].hypot(g.a1[1]) + g.a2[0].hypot(g.a2[1])),
            };
            // One polarity per size: the stronger lattice. The other polarity's "lattice" is
            // the side lobes of the zero-mean template between the dots, at most about half
            // as strong when the pitch exceeds the template's reach.
            match step_cand.as_ref() {
                Some(prev) if prev.snr >= c.snr => {}
                _ => step_cand = Some(c),
            }
        }
        cands.extend(step_cand);
        // Stop once two finer sizes in a row held lattices of less than half the best SNR
        // (sizes without a lattice do not count: a coarse junk lattice must not end the scan).
        if step_best > best_snr {
            best_snr = step_best;
            below = 0;
        } else if step_best > 0.0 && step_best < 0.5 * best_snr && best_snr > 0.0 {
            below += 1;
            if below >= 2 && cands.iter().any(|c| c.n >= 12) {
                break;
            }
        }
    }
    // The matched size: the strongest lattice (SNR) among those of at least 12 points (5 when
    // none has 12: a small target).
    let n_min = if cands.iter().any(|c| c.n >= 12) {
        12
    } else {
        5
    };
    let best = cands
        .iter()
        .filter(|c| c.n >= n_min)
        .max_by(|a, b| a.snr.total_cmp(&b.snr));
    match best {
        Some(c) => Ok(Survey {
            size_px: c.s,
            dark: c.dark,
            n_lattice: c.n,
            n_detected: c.n_det,
            snr: c.snr,
            level: c.level,
            pitch_px: c.pitch,
        }),
        None => Err(DewarpError::InvalidInput(format!(
            "marker detection: no lattice of marker-like blobs found at any size from {:.1} to \
             {:.1} px (sigma), {}; {} (blank image, particles, not a target, or markers of \
             another kind)",
            ladder.last().copied().unwrap_or(0.0),
            ladder.first().copied().unwrap_or(0.0),
            match dark {
                Some(true) => "dark markers",
                Some(false) => "bright markers",
                None => "either polarity",
            },
            if most.0 > 0 {
                format!(
                    "at most {} blobs at {:.1} px, in no regular lattice",
                    most.0, most.1
                )
            } else {
                "no blobs above the noise".to_string()
            }
        ))),
    }
}
