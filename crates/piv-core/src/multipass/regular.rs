//! Multipass PIV on the regular grid ([`piv`]).

use super::field::*;
use super::frames::*;
use super::settings::*;
use super::window::*;
use crate::correlate::Peak;
use crate::correlate::Uncertainty;
use crate::error::{PivError, Result};
use crate::grid::Grid;
use crate::image::{GridField, Pixel};
use crate::particle_size::{measure_at_most, particle_diameter};
use ndarray::{Array2, ArrayView2};
use rayon::prelude::*;

/// Multipass PIV of a frame pair on the regular grid of the last pass.
///
/// `mask` (same shape as the frames, `true` = excluded) removes the vectors whose centre falls
/// on a masked pixel. Errors: frames of different shapes, NaN/inf pixels, windows larger than the
/// image, bad settings.
pub fn piv<T: Pixel>(
    frame_a: ArrayView2<'_, T>,
    frame_b: ArrayView2<'_, T>,
    mask: Option<ArrayView2<'_, bool>>,
    s: &PivSettings,
) -> Result<PivField> {
    s.validate()?;
    check_pair(&frame_a, &frame_b)?;
    let dim = frame_a.dim();
    check_mask(&mask, dim)?;
    let grids = grids_of(s, dim)?;
    let frames = Frames::new(frame_a, frame_b, s.interpolation)?;
    grid_passes(&frames, dim, &mask, s, grids, 0)
}

/// The grids of the passes of `s` on frames of shape `dim` (rows, columns).
pub(crate) fn grids_of(s: &PivSettings, dim: (usize, usize)) -> Result<Vec<Grid>> {
    s.passes
        .iter()
        .map(|p| Grid::for_windows(dim.1, dim.0, p.w, p.h, p.overlap))
        .collect()
}

/// The passes of [`piv`] on prepared frames (inputs checked, `grids` from [`grids_of`]);
/// `later` passes follow them elsewhere (Method II's pass at the points: see
/// [`coarse_first_pass`]).
pub(crate) fn grid_passes<T: Pixel>(
    frames: &Frames<'_, T>,
    dim: (usize, usize),
    mask: &Option<ArrayView2<'_, bool>>,
    s: &PivSettings,
    grids: Vec<Grid>,
    later: usize,
) -> Result<PivField> {
    let mut pred: Option<GridField> = None;
    let mut last = None;
    let mut spare = None;
    // measured on the first correlation: windows cut from the frames as recorded
    let mut diameter = None;
    for (pass, grid) in s.passes.iter().zip(grids) {
        let n = grid.len();
        let mut xs = Vec::with_capacity(n);
        let mut ys = Vec::with_capacity(n);
        for j in 0..grid.ny {
            for i in 0..grid.nx {
                let (x, y) = grid.xy(j, i);
                xs.push(x);
                ys.push(y);
            }
        }
        let skip: Vec<bool> = xs
            .iter()
            .zip(&ys)
            .map(|(&x, &y)| excluded(mask, dim, x, y))
            .collect();
        let last_pass = std::ptr::eq(pass, s.passes.last().expect("non-empty"));
        let mean = WindowMean::new(pass.w, pass.h, s.weighting);
        for it in 0..pass.iterations {
            // the uncertainty of the vectors returned
            let unc = if s.uncertainty && last_pass && it + 1 == pass.iterations {
                Uncertainty::Peak
            } else {
                Uncertainty::Off
            };
            // the deformation predictor: the latest field averaged over this pass's window
            // (see the module notes)
            let cur = match (&pred, s.mode) {
                (Some(f), Mode::Deform) => Some(f.window_average(pass.w, pass.h)),
                (p, _) => p.clone(),
            };
            // predictor at the centres: for deformation the window mean of the deformation
            // field (the residual a deformed window measures is the window mean of
            // `true - deformation`, see the module notes); the centres in parallel (each
            // independent; 730,513 window means for a 47 MP pair's last pass)
            let centres = || xs.par_iter().zip(ys.par_iter());
            let (pu, pv): (Vec<f64>, Vec<f64>) = match (&cur, s.mode) {
                (Some(f), Mode::Deform) => centres().map(|(&x, &y)| mean.at(f, x, y)).unzip(),
                (Some(f), _) => centres().map(|(&x, &y)| f.at(x, y)).unzip(),
                (None, _) => (vec![0.0; n], vec![0.0; n]),
            };
            let zeros = vec![0.0; n];
            let (du, dv, base) = match s.mode {
                Mode::Deform => (&zeros, &zeros, cur.as_ref()),
                Mode::Offset => (&pu, &pv, None),
            };
            // grid windows sit on integer positions: deform the whole pair once, then the
            // windows are plain copies (the deformed pair's buffers serve the next one)
            let deformed = base.map(|f| frames.deformed(f, spare.take()));
            let sweep = |xs: &[f64], ys: &[f64], du: &[f64], dv: &[f64], skip: &[bool], u| {
                let sub = (s.subpixel, s.weighting);
                match &deformed {
                    Some(d) => d.sweep(pass.w, pass.h, xs, ys, du, dv, skip, None, sub, u),
                    None => frames.sweep(pass.w, pass.h, xs, ys, du, dv, skip, None, sub, u),
                }
            };
            let coarse = it == 0 && coarse_first_pass(s.passes.len() + later, pass, &pred);
            let mut peaks = if coarse {
                binned_sweep(frames, pass, (&xs, &ys), &skip, s)
            } else {
                sweep(&xs, &ys, du, dv, &skip, unc)
            };
            let first = *diameter.get_or_insert_with(|| {
                if coarse {
                    // the frames as recorded, not binned (a sample of whole windows)
                    let (a, b) = frames.views();
                    measure_at_most(a, b, (pass.w, pass.h), *mask, None, COARSE_DIAMETER_WINDOWS)
                        .unwrap_or((f64::NAN, f64::NAN))
                } else {
                    particle_diameter(&peaks)
                }
            });
            let mut u = par_grid((grid.ny, grid.nx), |j, i| {
                let k = j * grid.nx + i;
                pu[k] + peaks[k].dx
            });
            let mut v = par_grid((grid.ny, grid.nx), |j, i| {
                let k = j * grid.nx + i;
                pv[k] + peaks[k].dy
            });
            let checked = validate_replace(&mut u, &mut v, &peaks, &skip, s);
            if let (true, Some(prev)) = (it > 0, &pred) {
                // an extra iteration on this pass's grid (see `RELAXATION`)
                relax(&mut u, &prev.u);
                relax(&mut v, &prev.v);
            }
            if unc != Uncertainty::Off {
                fill_alt_sigmas(
                    &mut peaks,
                    &checked,
                    (&xs, &ys, du, dv),
                    |x, y, u, v, skip| sweep(x, y, u, v, skip, Uncertainty::AllPeaks),
                );
            }
            if let Some(d) = deformed {
                spare = d.into_buffers();
            }
            pred = Some(GridField {
                grid,
                u: u.clone(),
                v: v.clone(),
            });
            last = Some((u, v, peaks, checked, first));
        }
        if let Some((u, v, peaks, checked, first)) = last.take() {
            if last_pass {
                let x = Array2::from_shape_vec((grid.ny, grid.nx), xs).expect("shape");
                let y = Array2::from_shape_vec((grid.ny, grid.nx), ys).expect("shape");
                return Ok(finish(
                    Some(grid),
                    x,
                    y,
                    u,
                    v,
                    &peaks,
                    &skip,
                    first,
                    checked,
                ));
            }
        }
    }
    Err(PivError::InvalidInput("passes is empty".into()))
}

/// The smallest first window (px, both ways) that [`coarse_first_pass`] correlates on frames
/// binned 2 x 2.
pub const COARSE_MIN_WINDOW: usize = 64;

/// Windows [`grid_passes`] measures the particle images' diameter from when its first pass is
/// binned (`crate::particle_size::measure`: windows of the first pass's size cut from the
/// frames as recorded).
const COARSE_DIAMETER_WINDOWS: usize = 1024;

/// Does this pass correlate the frames binned 2 x 2? The first iteration of the first of
/// three passes or more (`passes` in all; `pred` is None), with windows of at least [`COARSE_MIN_WINDOW`] px
/// both ways and of an even size: it only gives the next pass its predictor, to a fraction of
/// a pixel, and the windows of half the size on frames binned 2 x 2 cover the same particle
/// images with the same search range (half the window) for a quarter of the correlation's
/// work. Two passes at least must follow: the next one's error grows with the residual its
/// deformed windows are left with, and a predictor from binned frames leaves more (64 -> 32 on
/// 1.7 px particle images: 0.081 -> 0.101 px RMS), which the pass after it takes away again
/// (64 -> 32 -> 32 x 8: 0.148 -> 0.148 px).
fn coarse_first_pass(passes: usize, pass: &Pass, pred: &Option<GridField>) -> bool {
    std::env::var_os("RSPIV_NO_COARSE").is_none()
        && pred.is_none()
        && passes >= 3
        && pass.w >= COARSE_MIN_WINDOW
        && pass.h >= COARSE_MIN_WINDOW
        && pass.w % 2 == 0
        && pass.h % 2 == 0
}

/// The first pass's correlations on the frames binned 2 x 2 ([`coarse_first_pass`]): windows
/// of `w / 2` x `h / 2` binned px centred on the pass's centres (the binning starts on the
/// parity of the windows' first pixel, so every window is whole binned pixels), no offset;
/// the peaks' displacements in px of the frames.
fn binned_sweep<T: Pixel>(
    frames: &Frames<'_, T>,
    pass: &Pass,
    (xs, ys): (&[f64], &[f64]),
    skip: &[bool],
    s: &PivSettings,
) -> Vec<Peak> {
    let (w, h) = (pass.w, pass.h);
    // the first pixel of every window (integers of one parity per axis on a regular grid)
    let first = |c: f64, n: usize| (c - (n as f64 - 1.0) / 2.0).round() as i64;
    let k = skip.iter().position(|&m| !m).unwrap_or(0);
    let (ox, oy) = (
        first(xs[k], w).rem_euclid(2) as usize,
        first(ys[k], h).rem_euclid(2) as usize,
    );
    let (ba, bb) = frames.binned(ox, oy);
    let binned = match Frames::new(ba.view(), bb.view(), Interpolation::Keys) {
        Ok(f) => f,
        Err(_) => return vec![Peak::FAILED; xs.len()],
    };
    // centre x of the frames = ox + 2 xb + 0.5
    let xb: Vec<f64> = xs.iter().map(|&x| (x - ox as f64 - 0.5) / 2.0).collect();
    let yb: Vec<f64> = ys.iter().map(|&y| (y - oy as f64 - 0.5) / 2.0).collect();
    let zeros = vec![0.0; xs.len()];
    let sub = (s.subpixel, s.weighting);
    let (bw, bh) = (w / 2, h / 2);
    let mut peaks = binned.sweep(
        bw,
        bh,
        &xb,
        &yb,
        &zeros,
        &zeros,
        skip,
        None,
        sub,
        Uncertainty::Off,
    );
    peaks.par_iter_mut().for_each(|p| {
        p.dx *= 2.0;
        p.dy *= 2.0;
        for a in p.alt.iter_mut() {
            a.dx *= 2.0;
            a.dy *= 2.0;
        }
        p.width = (2.0 * p.width.0, 2.0 * p.width.1);
    });
    peaks
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::synth::render_particles;
    use rand::{Rng, SeedableRng};

    /// A particle pair of 2.5 px images moved by `disp` (at the midpoint).
    fn pair(
        h: usize,
        w: usize,
        disp: impl Fn(f64, f64) -> (f64, f64),
    ) -> (Array2<u16>, Array2<u16>) {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(11);
        let n = (0.03 * ((h + 40) * (w + 40)) as f64) as usize;
        let (mut xa, mut ya, mut xb, mut yb, mut it) = (vec![], vec![], vec![], vec![], vec![]);
        for _ in 0..n {
            let x = rng.random::<f64>() * (w + 40) as f64 - 20.0;
            let y = rng.random::<f64>() * (h + 40) as f64 - 20.0;
            let (u, v) = disp(x, y);
            xa.push(x - u / 2.0);
            ya.push(y - v / 2.0);
            xb.push(x + u / 2.0);
            yb.push(y + v / 2.0);
            it.push(2000.0 + 1000.0 * rng.random::<f64>());
        }
        let a = render_particles(h, w, &xa, &ya, &it, &[2.5], 40.0, 4095, 1).unwrap();
        let b = render_particles(h, w, &xb, &yb, &it, &[2.5], 40.0, 4095, 2).unwrap();
        (a, b)
    }

    /// The first pass on frames binned 2 x 2 finds the full-resolution first pass's
    /// displacements to a fraction of a pixel, for grids whose windows start on even and on odd
    /// pixels, and the passes after it end where the full-resolution ones would.
    #[test]
    fn the_binned_first_pass_predicts_as_the_full_one() {
        let disp = |x: f64, y: f64| (6.3 + 2.0 * (y / 90.0).sin(), -2.2 + 1.5 * (x / 140.0).cos());
        let mut parities = std::collections::HashSet::new();
        for (h, w) in [(320usize, 448usize), (321, 449), (322, 451)] {
            let (a, b) = pair(h, w, disp);
            let s = PivSettings {
                passes: vec![Pass::new(64, 64), Pass::new(32, 32), Pass::new(32, 16)],
                ..PivSettings::default()
            };
            let frames = Frames::new(a.view(), b.view(), s.interpolation).unwrap();
            let grid = Grid::for_windows(w, h, 64, 64, 0.5).unwrap();
            let (mut xs, mut ys) = (vec![], vec![]);
            for j in 0..grid.ny {
                for i in 0..grid.nx {
                    let (x, y) = grid.xy(j, i);
                    xs.push(x);
                    ys.push(y);
                }
            }
            parities.insert(((xs[0] - 31.5) as i64 % 2, (ys[0] - 31.5) as i64 % 2));
            let skip = vec![false; xs.len()];
            let zeros = vec![0.0; xs.len()];
            let sub = (s.subpixel, s.weighting);
            let full = frames.sweep(
                64,
                64,
                &xs,
                &ys,
                &zeros,
                &zeros,
                &skip,
                None,
                sub,
                Uncertainty::Off,
            );
            let binned = binned_sweep(&frames, &s.passes[0], (&xs, &ys), &skip, &s);
            let (mut worst, mut d2) = (0.0f64, 0.0f64);
            for (p, q) in full.iter().zip(&binned) {
                assert!(p.ok && q.ok);
                worst = worst.max((p.dx - q.dx).abs()).max((p.dy - q.dy).abs());
                d2 += (p.dx - q.dx).powi(2) + (p.dy - q.dy).powi(2);
            }
            let rms_d = (d2 / full.len() as f64).sqrt();
            assert!(
                rms_d < 0.1 && worst < 0.4,
                "{h} x {w}: {rms_d} RMS, {worst} px at most"
            );
            // the three passes (the first binned) against the truth
            assert!(coarse_first_pass(3, &s.passes[0], &None));
            let f = piv(a.view(), b.view(), None, &s).unwrap();
            let mut e2 = 0.0;
            for ((x, y), (u, v)) in f.x.iter().zip(&f.y).zip(f.u.iter().zip(&f.v)) {
                let (tu, tv) = disp(*x, *y);
                e2 += (u - tu).powi(2) + (v - tv).powi(2);
            }
            let rms = (e2 / f.u.len() as f64).sqrt();
            assert!(rms < 0.08, "{h} x {w}: rms {rms}");
            let (dx, dy) = f.particle_diameter;
            assert!(
                (dx - 2.7).abs() < 0.25 && (dy - 2.7).abs() < 0.25,
                "{dx} {dy}"
            );
        }
        assert!(parities.len() >= 2, "{parities:?}");
        // two passes, or a first window under 64 px: correlated as recorded
        let two = PivSettings {
            passes: vec![Pass::new(64, 64), Pass::new(32, 32)],
            ..PivSettings::default()
        };
        assert!(!coarse_first_pass(two.passes.len(), &two.passes[0], &None));
        let small = PivSettings {
            passes: vec![Pass::new(48, 48), Pass::new(32, 32), Pass::new(16, 16)],
            ..PivSettings::default()
        };
        assert!(!coarse_first_pass(
            small.passes.len(),
            &small.passes[0],
            &None
        ));
    }
}
