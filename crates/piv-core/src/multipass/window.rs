//! The work on window pairs: input checks, the blank-block (zero fill) rule of
//! [`signal_fraction`] and the correlation sweep over a list of points.

use crate::correlate::{Correlator, Peak, SubPixel, Uncertainty};
use crate::error::{PivError, Result};
use crate::image::{sample_pair, GridField, Pixel, Source, WindowSpec};
use crate::weighting::Weighting;
use ndarray::ArrayView2;
use rayon::prelude::*;

pub(crate) fn check_pair<T: Pixel>(a: &ArrayView2<T>, b: &ArrayView2<T>) -> Result<()> {
    if a.dim() != b.dim() {
        return Err(PivError::InvalidInput(format!(
            "frame_a ({} x {}) and frame_b ({} x {}) differ in shape (rows x columns)",
            a.nrows(),
            a.ncols(),
            b.nrows(),
            b.ncols()
        )));
    }
    Ok(())
}

pub(crate) fn check_mask(mask: &Option<ArrayView2<'_, bool>>, dim: (usize, usize)) -> Result<()> {
    if let Some(m) = mask {
        if m.dim() != dim {
            return Err(PivError::InvalidInput(format!(
                "mask ({} x {}) differs in shape from the frames ({} x {})",
                m.nrows(),
                m.ncols(),
                dim.0,
                dim.1
            )));
        }
    }
    Ok(())
}

/// Is the point (x, y) not to be computed (mask or outside the image)?
pub(crate) fn excluded(
    mask: &Option<ArrayView2<'_, bool>>,
    dim: (usize, usize),
    x: f64,
    y: f64,
) -> bool {
    let (h, w) = dim;
    if !(x.is_finite() && y.is_finite())
        || x < -0.5
        || y < -0.5
        || x > w as f64 - 0.5
        || y > h as f64 - 0.5
    {
        return true;
    }
    match mask {
        Some(m) => {
            let i = (x.round() as usize).min(w - 1);
            let j = (y.round() as usize).min(h - 1);
            m[[j, i]]
        }
        None => false,
    }
}

/// Sample the window pair at top-left `(left, top)` offset by `(du, dv)` and deformed by `base`
/// into `c.wa`, `c.wb`; `false` when it is not to be correlated (a sample outside the image
/// comes back NaN, or too little signal: [`signal_fraction`]).
#[inline]
fn sample_usable<T: Pixel, U: Pixel, W: Fn(f32) -> [f32; N] + Copy, const N: usize>(
    src: &Source<'_, '_, '_, T, U, W>,
    c: &mut Correlator,
    keep: &mut FillScratch,
    (left, top, du, dv): (f64, f64, f64, f64),
    base: Option<&GridField>,
    rule: BlankRule,
) -> bool {
    let (w, h) = (c.w, c.h);
    let spec = WindowSpec {
        left,
        top,
        du,
        dv,
        field: base,
    };
    let (wa, wb) = (&mut c.wa, &mut c.wb);
    sample_pair(src, w, h, &spec, wa, wb);
    signal_fraction(wa, wb, keep, w, h, rule) >= MIN_SIGNAL_FRACTION
}

/// One correlation sweep over a list of points: `base` (deformation field) and per-point extra
/// displacement `du`, `dv`. Returns the peaks (FAILED where `skip`), with the uncertainties
/// that `uncertainty` asks for ([`Uncertainty`]).
pub(crate) fn sweep<T: Pixel, U: Pixel, W: Fn(f32) -> [f32; N] + Copy + Sync, const N: usize>(
    src: &Source<'_, '_, '_, T, U, W>,
    w: usize,
    h: usize,
    xs: &[f64],
    ys: &[f64],
    du: &[f64],
    dv: &[f64],
    skip: &[bool],
    base: Option<&GridField>,
    (sub, weighting): (SubPixel, Weighting),
    uncertainty: Uncertainty,
    rule: BlankRule,
) -> Vec<Peak> {
    let hw = (w as f64 - 1.0) / 2.0;
    let hh = (h as f64 - 1.0) / 2.0;
    (0..xs.len())
        .into_par_iter()
        .map_init(
            || {
                let mut c = Correlator::new(w, h);
                c.min_var = rule.floor;
                c.uncertainty = uncertainty;
                c.set_weighting(weighting);
                (c, FillScratch::new(w * h))
            },
            |(c, keep), k| {
                let spec = (xs[k] - hw, ys[k] - hh, du[k], dv[k]);
                if skip[k] || !sample_usable(src, c, keep, spec, base, rule) {
                    return Peak::FAILED;
                }
                c.correlate(sub)
            },
        )
        .collect()
}

/// A sweep over a list of points as [`sweep`] (windows offset by `du`, `dv` and deformed by
/// `base`) whose work per window is `f(correlator, out_k)`
/// with the window pair sampled into `correlator.wa`, `correlator.wb` (already checked by
/// [`signal_fraction`]) and `out_k = out[k * stride..(k + 1) * stride]`, the point's own part
/// of `out` (no locks, no allocation per window); windows that are skipped, reach outside the
/// image or are blank are left out (`out_k` untouched). Returns how many were used.
#[allow(clippy::too_many_arguments)]
pub(crate) fn sweep_into<T, U, W, F, const N: usize>(
    src: &Source<'_, '_, '_, T, U, W>,
    w: usize,
    h: usize,
    (xs, ys): (&[f64], &[f64]),
    (du, dv): (&[f64], &[f64]),
    base: Option<&GridField>,
    skip: &[bool],
    rule: BlankRule,
    out: &mut [f64],
    stride: usize,
    f: F,
) -> usize
where
    T: Pixel,
    U: Pixel,
    W: Fn(f32) -> [f32; N] + Copy + Sync,
    F: Fn(&mut Correlator, &mut [f64]) + Sync,
{
    let hw = (w as f64 - 1.0) / 2.0;
    let hh = (h as f64 - 1.0) / 2.0;
    out[..xs.len() * stride]
        .par_chunks_mut(stride)
        .enumerate()
        .map_init(
            || {
                let mut c = Correlator::new(w, h);
                c.min_var = rule.floor;
                (c, FillScratch::new(w * h))
            },
            |(c, keep), (k, o)| {
                let spec = (xs[k] - hw, ys[k] - hh, du[k], dv[k]);
                if skip[k] || !sample_usable(src, c, keep, spec, base, rule) {
                    return 0usize;
                }
                f(c, o);
                1
            },
        )
        .sum()
}

/// Blocks of a window: `(number, size)` along an axis of `n` px: blocks of an eighth of the
/// window, 2 to 4 px (more for windows above 64 px: at most 16 blocks), the last one taking
/// the remainder.
pub(crate) fn blocks(n: usize) -> (usize, usize) {
    let size = (n / 8).clamp(2, 4).max(n.div_ceil(16)).min(n);
    (n / size, size)
}

/// The pixel span `start..end` of block `b` of `nb` blocks of `size` px along an axis of `len`
/// px (the last block takes the remainder, see [`blocks`]).
fn block_span(b: usize, nb: usize, size: usize, len: usize) -> (usize, usize) {
    (b * size, if b + 1 == nb { len } else { (b + 1) * size })
}

/// A window pair needs signal over at least this fraction of its area (see
/// `signal_fraction`); otherwise it is not correlated (`valid = false`).
pub const MIN_SIGNAL_FRACTION: f64 = 0.75;

/// No NaN or infinity in `x` (a finite sum, 8 accumulators; the values are pixel levels).
pub(crate) fn all_finite(x: &[f32]) -> bool {
    let mut acc = [0.0f32; 8];
    let mut it = x.chunks_exact(8);
    for c in &mut it {
        for k in 0..8 {
            acc[k] += c[k];
        }
    }
    (acc.iter().sum::<f32>() + it.remainder().iter().sum::<f32>()).is_finite()
}

/// Scratch of [`signal_fraction`] for `w * h` windows.
pub(crate) struct FillScratch {
    keep: Vec<bool>,
    stack: Vec<usize>,
    /// Per-column extremes of a block row's rows after its first ([`blank_blocks`]).
    col_lo: Vec<f32>,
    col_hi: Vec<f32>,
    /// Per block, row-major: the extremes of all its rows.
    ext: Vec<[f32; 2]>,
}

impl FillScratch {
    pub(crate) fn new(n: usize) -> FillScratch {
        FillScratch {
            keep: vec![true; n],
            stack: Vec::with_capacity(n),
            col_lo: Vec::new(),
            col_hi: Vec::new(),
            ext: Vec::new(),
        }
    }
}

/// Sets the blank flags (row-major `nby` x `nbx`, all `false` on entry) of the blocks of one
/// window `win` (`w` x `h`, all values finite) by the test of [`signal_fraction`]; returns
/// whether any block is blank.
///
/// A block is not blank when the range of its first row, or of all its rows, exceeds what the
/// variance floor allows (the variance is at least `range^2 / (2 m)` for `m` pixels:
/// `range^2 > 2 m (floor + 1e-8 top^2 + 1e-12)`, `top` the larger magnitude of the
/// extremes); otherwise it is blank when constant, or when its variance (at most
/// `range^2 / 4`, else summed) is under the limit. Which blocks pass the range tests follows
/// the particles, so the tests run on every block without a branch (a data-dependent branch
/// per block mispredicted about as often as not and cost more than the tests); only the
/// blocks that fail them are looked at further. The vector path branches once per row of
/// blocks: when every block passes its first row's test (camera noise alone does), the row's
/// other pixel rows are not read.
pub(crate) fn blank_blocks(
    win: &[f32],
    (w, h): (usize, usize),
    (nbx, bw): (usize, usize),
    (nby, bh): (usize, usize),
    floor: f32,
    scratch: &mut FillScratch,
    flags: &mut [bool; 256],
) -> bool {
    let wide = |lo: f32, hi: f32, m: f64| {
        let (range, top) = ((hi - lo) as f64, lo.abs().max(hi.abs()) as f64);
        range * range > 2.0 * m * (floor as f64 + 1e-8 * top * top + 1e-12)
    };
    let FillScratch {
        col_lo,
        col_hi,
        ext,
        ..
    } = scratch;
    ext.clear();
    // the blocks that fail both range tests, as bits
    let mut open = [0u64; 4];
    #[cfg(target_arch = "x86_64")]
    let simd = bw == 4 && nbx * 4 == w && w % 8 == 0 && std::arch::is_x86_feature_detected!("avx2");
    for by in 0..nby {
        let (y0, y1) = block_span(by, nby, bh, h);
        #[cfg(target_arch = "x86_64")]
        if simd {
            // SAFETY: AVX2 is present; `w` is a multiple of 8 and rows y0..y1 lie in `win`
            let mut bits = unsafe { open_blocks4_avx2(win, w, (y0, y1), floor, ext) };
            while bits != 0 {
                let k = by * nbx + bits.trailing_zeros() as usize;
                bits &= bits - 1;
                open[k >> 6] |= 1 << (k & 63);
            }
            continue;
        }
        col_lo.clear();
        col_lo.resize(w, f32::INFINITY);
        col_hi.clear();
        col_hi.resize(w, f32::NEG_INFINITY);
        for row in win[(y0 + 1) * w..y1 * w].chunks_exact(w) {
            for ((l, u), &v) in col_lo.iter_mut().zip(col_hi.iter_mut()).zip(row) {
                *l = if v < *l { v } else { *l };
                *u = if v > *u { v } else { *u };
            }
        }
        let first = &win[y0 * w..(y0 + 1) * w];
        for bx in 0..nbx {
            let (x0, x1) = block_span(bx, nbx, bw, w);
            let (mut l1, mut u1) = (f32::INFINITY, f32::NEG_INFINITY);
            for &v in &first[x0..x1] {
                l1 = if v < l1 { v } else { l1 };
                u1 = if v > u1 { v } else { u1 };
            }
            let (mut l, mut u) = (l1, u1);
            for (&a, &b) in col_lo[x0..x1].iter().zip(&col_hi[x0..x1]) {
                l = if a < l { a } else { l };
                u = if b > u { b } else { u };
            }
            let m = ((x1 - x0) * (y1 - y0)) as f64;
            let k = by * nbx + bx;
            let failed = !(wide(l1, u1, m) | wide(l, u, m));
            open[k >> 6] |= (failed as u64) << (k & 63);
            ext.push([l, u]);
        }
    }
    let mut any = false;
    for (i, &bits) in open.iter().enumerate() {
        let mut bits = bits;
        while bits != 0 {
            let k = i * 64 + bits.trailing_zeros() as usize;
            bits &= bits - 1;
            let [lo, hi] = ext[k];
            let (xs, ys) = (
                block_span(k % nbx, nbx, bw, w),
                block_span(k / nbx, nby, bh, h),
            );
            flags[k] = lo == hi || low_variance(win, w, xs, ys, (lo, hi), floor);
            any |= flags[k];
        }
    }
    any
}

/// [`blank_blocks`] on one block row (rows `y0..y1`) of a window `w` px wide, `w` a multiple
/// of 8, in blocks of 4 px: pushes each block's extremes to `ext` (those of its first row
/// when every block passes the first row's test: none is then open, and the other rows are not
/// read) and returns the blocks that fail both range tests as bits (bit `bx`). The same extremes (the values are finite, so
/// `min`/`max` give the same values in any order, up to the sign of a zero extreme, which no
/// test sees) and the same f64 tests as the scalar loop, 8 columns (2 blocks) per register and
/// the tests 4 blocks at a time.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn open_blocks4_avx2(
    win: &[f32],
    w: usize,
    (y0, y1): (usize, usize),
    floor: f32,
    ext: &mut Vec<[f32; 2]>,
) -> u32 {
    use std::arch::x86_64::*;
    let nbx = w / 4;
    let rows = &win[y0 * w..y1 * w];
    // per block: extremes of its first row and of all its rows (16 blocks at most)
    let mut lf = [0.0f32; 16];
    let mut hf = [0.0f32; 16];
    let mut la = [0.0f32; 16];
    let mut ha = [0.0f32; 16];
    // min / max over each group of 4 lanes, left in the group's first lane; the results of
    // the two groups of a register go to blocks 2c and 2c + 1
    macro_rules! groups {
        ($v:expr, $op:ident, $out:ident, $c:expr) => {{
            let a = $op($v, _mm256_permute_ps::<0b10_11_00_01>($v));
            let a = $op(a, _mm256_permute_ps::<0b01_00_11_10>(a));
            $out[2 * $c] = _mm256_cvtss_f32(a);
            $out[2 * $c + 1] = _mm_cvtss_f32(_mm256_extractf128_ps::<1>(a));
        }};
    }
    // 8 values from `i` (bounds checked)
    let load8 = |v: &[f32], i: usize| {
        let s = &v[i..i + 8];
        // SAFETY: `s` holds 8 values; AVX2 is enabled in this function
        unsafe { _mm256_loadu_ps(s.as_ptr()) }
    };
    let load4 = |v: &[f32; 16], i: usize| {
        let s = &v[i..i + 4];
        // SAFETY: `s` holds 4 values
        unsafe { _mm_loadu_ps(s.as_ptr()) }
    };
    // the first row's extremes and test first: where every block of the row passes it (a
    // particle image with camera noise), no block is blank and the other rows are not read
    for c in 0..w / 8 {
        let f = load8(rows, 8 * c);
        groups!(f, _mm256_min_ps, lf, c);
        groups!(f, _mm256_max_ps, hf, c);
    }
    // range^2 > 2 m (floor + 1e-8 top^2 + 1e-12), top = max(|lo|, |hi|), as `blank_blocks`
    let twice_m = _mm256_set1_pd(2.0 * (4 * (y1 - y0)) as f64);
    let (fl, tiny, eps) = (
        _mm256_set1_pd(floor as f64),
        _mm256_set1_pd(1e-8),
        _mm256_set1_pd(1e-12),
    );
    let magnitude = _mm_castsi128_ps(_mm_set1_epi32(0x7fff_ffff));
    macro_rules! wide {
        ($lo:ident, $hi:ident, $i:expr) => {{
            let (l, u) = (load4(&$lo, $i), load4(&$hi, $i));
            let range = _mm256_cvtps_pd(_mm_sub_ps(u, l));
            let top = _mm256_cvtps_pd(_mm_max_ps(
                _mm_and_ps(l, magnitude),
                _mm_and_ps(u, magnitude),
            ));
            let lim = _mm256_add_pd(
                _mm256_add_pd(fl, _mm256_mul_pd(_mm256_mul_pd(tiny, top), top)),
                eps,
            );
            _mm256_cmp_pd::<_CMP_GT_OQ>(_mm256_mul_pd(range, range), _mm256_mul_pd(twice_m, lim))
        }};
    }
    let all = (1u32 << nbx) - 1;
    let mut first = 0u32;
    for i in (0..nbx).step_by(4) {
        first |= ((_mm256_movemask_pd(wide!(lf, hf, i)) & 0xf) as u32) << i;
    }
    if first & all == all {
        // only the open blocks' extremes are read (`blank_blocks`): none here
        ext.extend((0..nbx).map(|b| [lf[b], hf[b]]));
        return 0;
    }
    for c in 0..w / 8 {
        let mut lo = load8(rows, 8 * c);
        let mut hi = lo;
        for r in 1..y1 - y0 {
            let v = load8(rows, r * w + 8 * c);
            lo = _mm256_min_ps(lo, v);
            hi = _mm256_max_ps(hi, v);
        }
        groups!(lo, _mm256_min_ps, la, c);
        groups!(hi, _mm256_max_ps, ha, c);
    }
    ext.extend((0..nbx).map(|b| [la[b], ha[b]]));
    let mut bits = 0u32;
    for i in (0..nbx).step_by(4) {
        bits |= ((!_mm256_movemask_pd(wide!(la, ha, i)) & 0xf) as u32) << i;
    }
    bits & !first & all
}

/// Whether the block `x0..x1` x `y0..y1` of a `w`-wide window, of extremes `lo < hi`, has a
/// per-pixel variance `<= floor + 1e-8 mean^2 + 1e-12` (sums in f64). The variance is at most
/// `range^2 / 4`: when that is under the limit (taken with the smallest magnitude the mean can
/// have) by a margin far above the sums' rounding, the block is blank without the sums, as
/// the sums would decide.
fn low_variance(
    win: &[f32],
    w: usize,
    (x0, x1): (usize, usize),
    (y0, y1): (usize, usize),
    (lo, hi): (f32, f32),
    floor: f32,
) -> bool {
    let least = if lo > 0.0 {
        lo
    } else if hi < 0.0 {
        -hi
    } else {
        0.0
    } as f64;
    let range = (hi - lo) as f64;
    if range * range / 4.0 <= 0.99 * (floor as f64 + 1e-8 * least * least + 1e-12) {
        return true;
    }
    let m = ((x1 - x0) * (y1 - y0)) as f64;
    let (mut s, mut s2) = (0.0f64, 0.0f64);
    for r in y0..y1 {
        for &v in &win[r * w + x0..r * w + x1] {
            let v = v as f64;
            s += v;
            s2 += v * v;
        }
    }
    let mean = s / m;
    let var = (s2 / m - mean * mean).max(0.0);
    var <= floor as f64 + 1e-8 * mean * mean + 1e-12
}

/// How [`signal_fraction`] tells blank blocks: `floor`, the per-pixel variance at or below
/// which a block is blank, and `background`, the level of a noise-free background when the
/// frames have one ([`clean_background`]): blank blocks at that level are particle-free
/// background, not fill.
#[derive(Debug, Clone, Copy)]
pub(crate) struct BlankRule {
    pub floor: f32,
    pub background: Option<f32>,
}

#[cfg(test)]
impl BlankRule {
    /// The rule for frames with camera noise (no clean background).
    pub(crate) const fn noisy(floor: f32) -> BlankRule {
        BlankRule {
            floor,
            background: None,
        }
    }
}

/// Shortest and longest run of pixels at a frame's minimum counted by [`clean_background`]
/// wherever it lies.
const CLEAN_RUN: (usize, usize) = (4, 48);
/// Longest gap between sparse particle images counted by [`clean_background`] (runs longer
/// than [`CLEAN_RUN`] that end on pixels above the level on both sides).
const SPARSE_RUN: usize = 512;
/// Fraction of a frame's pixels in such runs from which its background is clean.
pub const CLEAN_BACKGROUND: f64 = 0.35;

/// The level of a frame's noise-free background, if it has one: a noise-free render, a
/// background subtracted and clipped hard at zero. Its minimum, when at least
/// [`CLEAN_BACKGROUND`] of the pixels of (up to 256 evenly spaced) rows lie in runs at that
/// level between particle images:
///
/// - runs of 4 to 48 px anywhere (the gaps between particle images). Camera noise breaks such
///   runs: a background clipped at zero in half of its pixels has 16 % of them in runs of 4 or
///   more, in 60 % of them 28 %. Longer runs are not counted so, so that a zero fill (the
///   outside of a dewarped frame) does not make a noisy frame clean;
/// - and, when the stretches above the level are particle images (48 px long on average at
///   most: camera noise that seldom reaches the level leaves long stretches), runs of 49 to
///   512 px inside a row (the gaps between sparse particle images: 80-170 px on average at
///   0.002-0.004 particles/px, which before this rule left every window of a noise-free
///   render blank). A fill that reaches a row's end, or one wider than 512 px, is still
///   not counted.
pub(crate) fn clean_background<T: Pixel>(px: &[T], width: usize, height: usize) -> Option<f32> {
    let step = height.div_ceil(256).max(1);
    // the sampled rows in parallel (each row's minimum and runs are its own; the minima
    // combine in row order, so the first of equal minima wins as in one sequential scan)
    let rows = || {
        (0..height)
            .into_par_iter()
            .step_by(step)
            .map(|r| &px[r * width..(r + 1) * width])
    };
    let min = |m: f32, v: f32| if v < m { v } else { m };
    let level = rows()
        .map(|row| row.iter().map(|p| p.to_f32()).fold(f32::INFINITY, min))
        .reduce(|| f32::INFINITY, min);
    let runs = rows()
        .map(|row| {
            let mut r = LevelRuns::default();
            // the run at the level so far, and whether it started at the row's start
            let (mut run, mut from_start) = (0usize, true);
            let mut above = false;
            for v in row.iter().map(|p| Some(p.to_f32())).chain([None]) {
                if v == Some(level) {
                    run += 1;
                    above = false;
                    continue;
                }
                if (CLEAN_RUN.0..=CLEAN_RUN.1).contains(&run) {
                    r.short += run;
                } else if run > CLEAN_RUN.1 && run <= SPARSE_RUN && !from_start && v.is_some() {
                    r.long += run;
                }
                (run, from_start) = (0, false);
                if v.is_some() {
                    r.above += 1;
                    r.stretches += usize::from(!above);
                    above = true;
                }
            }
            r.n = row.len();
            r
        })
        .reduce(LevelRuns::default, LevelRuns::add);
    let enough = |px: usize| runs.n > 0 && px as f64 >= CLEAN_BACKGROUND * runs.n as f64;
    let particles = runs.above <= CLEAN_RUN.1 * runs.stretches;
    (enough(runs.short) || (particles && enough(runs.short + runs.long))).then_some(level)
}

/// What [`clean_background`] counts in its rows: pixels, pixels in runs at the level of
/// [`CLEAN_RUN`] length and in longer runs inside a row (up to [`SPARSE_RUN`]), pixels above
/// the level and the stretches they form.
#[derive(Default, Clone, Copy)]
struct LevelRuns {
    n: usize,
    short: usize,
    long: usize,
    above: usize,
    stretches: usize,
}

impl LevelRuns {
    fn add(self, o: LevelRuns) -> LevelRuns {
        LevelRuns {
            n: self.n + o.n,
            short: self.short + o.short,
            long: self.long + o.long,
            above: self.above + o.above,
            stretches: self.stretches + o.stretches,
        }
    }
}

/// Clears the flags of the blank blocks of `win` (`w` px wide, blocks `(nbx, bw)` x `(nby,
/// bh)`) at the frames' clean background `level` (within the blank test's tolerance for
/// `floor`): particle-free stretches of a noise-free background, which correlate like the
/// rest of it. A zero fill at another level, or a saturated region, stays blank.
fn background_blocks(
    win: &[f32],
    flags: &mut [bool; 256],
    w: usize,
    (nbx, bw): (usize, usize),
    (nby, bh): (usize, usize),
    (level, floor): (f32, f32),
) {
    let tol = 2.0 * (floor as f64 + 1e-8 * (level as f64).powi(2) + 1e-12).sqrt();
    for by in 0..nby {
        for bx in 0..nbx {
            let k = by * nbx + bx;
            // a blank block is (near) constant: its first pixel is its level
            if flags[k] && ((win[(by * bh) * w + bx * bw] - level) as f64).abs() <= tol {
                flags[k] = false;
            }
        }
    }
}

/// The fraction of a window pair's area that carries signal; 0 when a sample lies outside the
/// frame; the pixels without signal are neutralised.
///
/// - A window pair with a sample outside the frame (NaN, see [`sample_pair`]) is not
///   correlated: returns 0.
/// - The window (`h` rows of `w`) is split into about 8 x 8 blocks of 2 to 4 px a side (see
///   [`blocks`]). A block that is constant, or whose per-pixel variance is
///   `<= floor + 1e-8 mean^2 + 1e-12`, in either window is blank: zero fill of a dewarped
///   frame, a blank or saturated region. The signal fraction is the area fraction of the
///   other blocks.
/// - When it is at least [`MIN_SIGNAL_FRACTION`] the pair is correlated over its signal part
///   only: the blank blocks, and the pixels of the blocks next to them that are connected to
///   them through values equal in both windows to the blank ones (the rest of a fill that a
///   block boundary cuts), are set in both windows to the mean of that window's other
///   pixels, so that they drop out of the mean-free correlation and the fill's stationary
///   edge does not pull the peak towards zero displacement.
///
/// With deformation, the fill edge moves against the particles in the deformed pair (each
/// frame is shifted by half the displacement) and is no longer stationary: a window part-way
/// into the fill keeps a bias of a few 0.01 px towards minus the displacement; give a mask to
/// drop such vectors. With no blank block the windows are untouched and 1 is returned. Particle images with
/// camera noise have no blank block. A fill narrower than a block (under 4 px of a 32 px
/// window) is not detected and is correlated with the rest (its edge biases the vector by a
/// few 0.01 px).
///
/// Clean images (noise-free renders, a background subtracted and clipped hard at zero) have
/// many particle-free blocks at exactly the background level: at 0.03 particles/px with 1.5
/// px particle images a third of the 4 x 4 px blocks. When both frames have such a clean
/// background ([`clean_background`], `rule.background`), blank blocks at its level are not
/// fill ([`background_blocks`]) and are correlated as they are: neutralising them would put
/// steps between the background and the window's mean, and counting them refused whole
/// windows (all 49 of the first pass of a noise-free 256 x 256 render at 0.03 ppp, after
/// which the last pass locked on to a zero predictor).
pub(crate) fn signal_fraction(
    wa: &mut [f32],
    wb: &mut [f32],
    scratch: &mut FillScratch,
    w: usize,
    h: usize,
    rule: BlankRule,
) -> f64 {
    if !(all_finite(wa) && all_finite(wb)) {
        return 0.0;
    }
    let floor = rule.floor;
    let ((nbx, bw), (nby, bh)) = (blocks(w), blocks(h));
    // blank flags of the (at most 16 x 16) blocks, per window
    let mut blank_in = [[false; 256]; 2];
    let mut any = false;
    for (flags, win) in blank_in.iter_mut().zip([&*wa, &*wb]) {
        any |= blank_blocks(win, (w, h), (nbx, bw), (nby, bh), floor, scratch, flags);
    }
    if !any {
        return 1.0;
    }
    // blank blocks at the frames' clean background level are particle-free background, not
    // fill: they make no step against the rest and are correlated as they are
    if let Some(level) = rule.background {
        for (flags, win) in blank_in.iter_mut().zip([&*wa, &*wb]) {
            background_blocks(win, flags, w, (nbx, bw), (nby, bh), (level, rule.floor));
        }
    }
    let FillScratch { keep, stack, .. } = scratch;
    let mut is_blank = [false; 256];
    let mut blank_px = 0usize;
    for by in 0..nby {
        let ys = block_span(by, nby, bh, h);
        for bx in 0..nbx {
            let (k, xs) = (by * nbx + bx, block_span(bx, nbx, bw, w));
            if blank_in[0][k] || blank_in[1][k] {
                is_blank[k] = true;
                blank_px += (xs.1 - xs.0) * (ys.1 - ys.0);
            }
        }
    }
    if blank_px == 0 {
        return 1.0;
    }
    let fraction = 1.0 - blank_px as f64 / (w * h) as f64;
    if fraction < MIN_SIGNAL_FRACTION {
        return fraction;
    }
    let block_of = |i: usize| {
        let (r, c) = (i / w, i % w);
        ((r / bh).min(nby - 1), (c / bw).min(nbx - 1))
    };
    let next_to_blank = |(by, bx): (usize, usize)| {
        (by.saturating_sub(1)..=(by + 1).min(nby - 1))
            .any(|j| (bx.saturating_sub(1)..=(bx + 1).min(nbx - 1)).any(|i| is_blank[j * nbx + i]))
    };
    stack.clear();
    for (i, k) in keep.iter_mut().enumerate() {
        let (by, bx) = block_of(i);
        *k = !is_blank[by * nbx + bx];
        if !*k {
            stack.push(i);
        }
    }
    // the fill beyond the blank blocks: 4-connected, equal values, blocks next to blank ones
    while let Some(i) = stack.pop() {
        let (r, c) = (i / w, i % w);
        let nb = [
            (r > 0).then(|| i - w),
            (r + 1 < h).then(|| i + w),
            (c > 0).then(|| i - 1),
            (c + 1 < w).then(|| i + 1),
        ];
        for j in nb.into_iter().flatten() {
            if keep[j] && wa[j] == wa[i] && wb[j] == wb[i] && next_to_blank(block_of(j)) {
                keep[j] = false;
                stack.push(j);
            }
        }
    }
    let kept = keep.iter().filter(|&&k| k).count().max(1);
    for win in [&mut *wa, &mut *wb] {
        let s: f64 = win
            .iter()
            .zip(keep.iter())
            .filter(|(_, &k)| k)
            .map(|(&v, _)| v as f64)
            .sum();
        let m = (s / kept as f64) as f32;
        for (v, &k) in win.iter_mut().zip(keep.iter()) {
            if !k {
                *v = m;
            }
        }
    }
    fraction
}
