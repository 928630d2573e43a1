//! The settings of a PIV evaluation: passes, how windows follow the predictor, interpolation,
//! validation; and their one vocabulary.
//!
//! The vocabulary is the one of the Python `rspiv.PivSettings`, the campaign file's `[piv]`
//! section and `rspiv-engine piv --settings FILE.json` ([`PivSettings::from_json`]):
//!
//! | key              | JSON value                 | meaning                                        |
//! |------------------|----------------------------|------------------------------------------------|
//! | passes           | `[[w, h], ...]`            | window px, coarse to fine; w along x           |
//! | overlap          | number or one per pass     | fraction in `[0, 1)`                           |
//! | iterations       | integer or one per pass    | `>= 1` correlations per pass                   |
//! | deformation      | `"symmetric"`, `"offset"`  | [`Mode::Deform`], [`Mode::Offset`]             |
//! | interpolation    | `"bspline"`, `"bspline3"`, `"keys"` | [`Interpolation`]                     |
//! | subpixel         | `"gauss3"`, `"gauss2d"`    | [`SubPixel`]                                   |
//! | weighting        | `"tophat"`, `"gaussian"`, `"blackman"` | [`Weighting`] of the windows       |
//! | validate         | bool                       | normalised median test                         |
//! | median_eps       | number, px                 | noise level of the median test                 |
//! | median_threshold | number                     | threshold of the median test                   |
//! | min_peak_ratio   | number                     | reject below this peak ratio (0: off)          |
//! | peak_candidates  | 1, 2 or 3                  | correlation peaks tried per vector (see below) |
//! | uncertainty      | bool                       | per-vector uncertainty (`PivField::sigma_u`)   |
//! | roi              | `[x0, y0, x1, y1]` or null | region of interest, px ([`Roi`])               |
//!
//! `peak_candidates`: when a vector fails the median test (or its peak is rejected), its
//! second and then third correlation peaks ([`crate::correlate::Peak::alt`]) are tried, up to
//! this many peaks in all, before it is interpolated from its neighbours: the first that passes
//! the median test against the same neighbours is kept (a valid vector, not `replaced`; its
//! `peak_choice` says which). 1 turns this off. Only with `validate`.
//!
//! Missing keys take the defaults ([`PivSettings::default`]); unknown keys are an error. The
//! string values parse case-insensitively through the enums' `FromStr` and print (`Display`) as
//! the vocabulary's lowercase names.

use super::roi::Roi;
use crate::correlate::SubPixel;
use crate::error::{PivError, Result};
use crate::weighting::Weighting;
use serde::{Deserialize, Serialize};
use std::fmt;
use std::str::FromStr;

/// How the windows follow the predictor.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Mode {
    /// Full symmetric image deformation (B-spline interpolation, see [`Interpolation`]).
    #[default]
    Deform,
    /// Symmetric sub-pixel window offset.
    Offset,
}

/// Interpolation of the frames at the fractional positions of deformed or offset windows.
///
/// Interpolating a sub-pixel shift of 2-3 px particles (whose spectrum reaches the Nyquist
/// frequency) shifts them by slightly less or more than asked; the symmetric deformation
/// moves each frame by `d/2`, so the residual measured in the deformed pair carries a bias that
/// is periodic in the fractional part of `d/2` (zero at 0 and 0.5). With 2.5 px particles its
/// amplitude is about 0.018 px for the cubic B-spline, 0.006 px for the quintic one and a few
/// 0.01 px for Keys. Across a field whose displacement varies it shows up as random error.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Interpolation {
    /// Quintic B-spline on prefiltered coefficients (default, 6 x 6 taps).
    #[default]
    BSpline,
    /// Cubic B-spline on prefiltered coefficients (4 x 4 taps).
    BSpline3,
    /// Keys cubic convolution (a = -0.5, 4 x 4 pixels, no prefilter).
    Keys,
}

/// One pass: window `w` px wide (x) by `h` px tall (y), fractional overlap, iterations.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Pass {
    pub w: usize,
    pub h: usize,
    pub overlap: f64,
    pub iterations: usize,
}

impl Pass {
    /// A pass of `w` x `h` windows (w along x), 50 % overlap, one iteration.
    pub fn new(w: usize, h: usize) -> Pass {
        Pass {
            w,
            h,
            overlap: 0.5,
            iterations: 1,
        }
    }
}

/// Settings of a PIV evaluation.
#[derive(Debug, Clone, PartialEq)]
pub struct PivSettings {
    /// Passes from coarse to fine (the grid of the last one is the output grid).
    pub passes: Vec<Pass>,
    pub mode: Mode,
    pub subpixel: SubPixel,
    pub interpolation: Interpolation,
    /// Weighting window of every pass's windows ([`Weighting`]); the top-hat.
    pub weighting: Weighting,
    /// Run the normalised median test (replacement of failed correlations always happens).
    pub validate: bool,
    /// Normalised median test: noise level epsilon (px), 0.1.
    pub median_eps: f64,
    /// Normalised median test: threshold, 2.
    pub median_threshold: f64,
    /// Vectors whose peak ratio is below this are rejected (0 disables the test).
    pub min_peak_ratio: f64,
    /// Correlation peaks tried per vector, 1 to 3 (module docs); 3.
    pub peak_candidates: usize,
    /// Estimate every vector's uncertainty on the last iteration of the last pass
    /// ([`crate::PivField::sigma_u`]); true. Off, the sigmas are NaN.
    pub uncertainty: bool,
    /// The region of interest: every pass on the whole frame's grid cut to it, only it and a
    /// margin read
    /// ([`Roi`], `roi.rs`); `None`, the whole frame.
    pub roi: Option<Roi>,
}

impl Default for PivSettings {
    fn default() -> Self {
        PivSettings {
            passes: vec![Pass::new(64, 64), Pass::new(32, 32), Pass::new(32, 8)],
            mode: Mode::Deform,
            subpixel: SubPixel::Gauss3,
            interpolation: Interpolation::BSpline,
            weighting: Weighting::TopHat,
            validate: true,
            median_eps: 0.1,
            median_threshold: 2.0,
            min_peak_ratio: 0.0,
            peak_candidates: 3,
            uncertainty: true,
            roi: None,
        }
    }
}

impl PivSettings {
    /// Check the settings (every entry point runs this first): at least one pass, windows of
    /// at least 4 x 4 px, overlaps in `[0, 1)`, iterations >= 1, finite non-negative validation
    /// parameters. [`PivError::InvalidInput`] names the offending value.
    pub fn validate(&self) -> Result<()> {
        if self.passes.is_empty() {
            return Err(PivError::InvalidInput("passes is empty".into()));
        }
        for p in &self.passes {
            if p.iterations == 0 {
                return Err(PivError::InvalidInput(format!(
                    "pass {} x {} has 0 iterations",
                    p.w, p.h
                )));
            }
            if p.w < 4 || p.h < 4 {
                return Err(PivError::InvalidInput(format!(
                    "window {} x {} px is too small (at least 4 x 4)",
                    p.w, p.h
                )));
            }
            if !(0.0..1.0).contains(&p.overlap) {
                return Err(PivError::InvalidInput(format!(
                    "overlap {} is outside [0, 1)",
                    p.overlap
                )));
            }
        }
        let ok = |x: f64| x.is_finite() && x >= 0.0;
        if !ok(self.median_eps) || !ok(self.median_threshold) || !ok(self.min_peak_ratio) {
            return Err(PivError::InvalidInput(
                "median_eps, median_threshold and min_peak_ratio must be finite and >= 0".into(),
            ));
        }
        if !(1..=3).contains(&self.peak_candidates) {
            return Err(PivError::InvalidInput(format!(
                "peak_candidates {} is outside 1 ..= 3",
                self.peak_candidates
            )));
        }
        if let Some(r) = &self.roi {
            r.validate()?;
        }
        Ok(())
    }
}

/// `FromStr` (case-insensitive, the vocabulary's names) and `Display` (the canonical name) of a
/// settings enum.
macro_rules! vocabulary_enum {
    ($ty:ty, $key:literal, $(($name:literal, $variant:expr)),+ $(,)?) => {
        impl FromStr for $ty {
            type Err = PivError;
            fn from_str(s: &str) -> Result<Self> {
                let low = s.trim().to_ascii_lowercase();
                $(if low == $name {
                    return Ok($variant);
                })+
                let names = [$(format!("{:?}", $name)),+];
                Err(PivError::InvalidInput(format!(
                    "{} {:?}: use {}",
                    $key,
                    s,
                    names.join(", ")
                )))
            }
        }
        impl fmt::Display for $ty {
            fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
                $(if *self == $variant {
                    return f.write_str($name);
                })+
                unreachable!("every variant has a name")
            }
        }
    };
}

vocabulary_enum!(
    Mode,
    "deformation",
    ("symmetric", Mode::Deform),
    ("offset", Mode::Offset)
);
vocabulary_enum!(
    Interpolation,
    "interpolation",
    ("bspline", Interpolation::BSpline),
    ("bspline3", Interpolation::BSpline3),
    ("keys", Interpolation::Keys)
);
vocabulary_enum!(
    Weighting,
    "weighting",
    ("tophat", Weighting::TopHat),
    ("gaussian", Weighting::Gaussian),
    ("blackman", Weighting::Blackman)
);
vocabulary_enum!(
    SubPixel,
    "subpixel",
    ("gauss3", SubPixel::Gauss3),
    ("gauss2d", SubPixel::Gauss2d)
);

/// A value given once for every pass or once per pass.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(untagged)]
enum PerPass<T> {
    One(T),
    Each(Vec<T>),
}

impl<T: Copy + fmt::Debug> PerPass<T> {
    fn expand(&self, n: usize, key: &str) -> Result<Vec<T>> {
        match self {
            PerPass::One(v) => Ok(vec![*v; n]),
            PerPass::Each(v) if v.len() == n => Ok(v.clone()),
            PerPass::Each(v) => Err(PivError::InvalidInput(format!(
                "{key} has {} values for {n} passes",
                v.len()
            ))),
        }
    }

    /// One value when all passes share it, else the list.
    fn of(values: Vec<T>) -> PerPass<T>
    where
        T: PartialEq,
    {
        if values.windows(2).all(|w| w[0] == w[1]) && !values.is_empty() {
            PerPass::One(values[0])
        } else {
            PerPass::Each(values)
        }
    }
}

/// The JSON form of [`PivSettings`] (the vocabulary's keys).
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
struct SettingsJson {
    passes: Vec<(usize, usize)>,
    overlap: PerPass<f64>,
    iterations: PerPass<usize>,
    deformation: String,
    interpolation: String,
    subpixel: String,
    weighting: String,
    validate: bool,
    median_eps: f64,
    median_threshold: f64,
    min_peak_ratio: f64,
    peak_candidates: usize,
    uncertainty: bool,
    roi: Option<Roi>,
}

impl Default for SettingsJson {
    fn default() -> Self {
        SettingsJson::from(&PivSettings::default())
    }
}

impl From<&PivSettings> for SettingsJson {
    fn from(s: &PivSettings) -> Self {
        SettingsJson {
            passes: s.passes.iter().map(|p| (p.w, p.h)).collect(),
            overlap: PerPass::of(s.passes.iter().map(|p| p.overlap).collect()),
            iterations: PerPass::of(s.passes.iter().map(|p| p.iterations).collect()),
            deformation: s.mode.to_string(),
            interpolation: s.interpolation.to_string(),
            subpixel: s.subpixel.to_string(),
            weighting: s.weighting.to_string(),
            validate: s.validate,
            median_eps: s.median_eps,
            median_threshold: s.median_threshold,
            min_peak_ratio: s.min_peak_ratio,
            peak_candidates: s.peak_candidates,
            uncertainty: s.uncertainty,
            roi: s.roi,
        }
    }
}

impl PivSettings {
    /// Settings from the JSON object of the vocabulary (module docs): missing keys take the
    /// defaults; unknown keys, wrong types, bad names and values out of range are
    /// [`PivError::InvalidInput`] naming the key.
    pub fn from_json(text: &str) -> Result<PivSettings> {
        let j: SettingsJson = serde_json::from_str(text)
            .map_err(|e| PivError::InvalidInput(format!("PIV settings: {e}")))?;
        let n = j.passes.len();
        let overlaps = j.overlap.expand(n, "overlap")?;
        let iterations = j.iterations.expand(n, "iterations")?;
        let s = PivSettings {
            passes: j
                .passes
                .iter()
                .zip(overlaps)
                .zip(iterations)
                .map(|((&(w, h), overlap), iterations)| Pass {
                    w,
                    h,
                    overlap,
                    iterations,
                })
                .collect(),
            mode: j.deformation.parse()?,
            subpixel: j.subpixel.parse()?,
            interpolation: j.interpolation.parse()?,
            weighting: j.weighting.parse()?,
            validate: j.validate,
            median_eps: j.median_eps,
            median_threshold: j.median_threshold,
            min_peak_ratio: j.min_peak_ratio,
            peak_candidates: j.peak_candidates,
            uncertainty: j.uncertainty,
            roi: j.roi,
        };
        s.validate()?;
        Ok(s)
    }

    /// The settings as the vocabulary's JSON object (what [`PivSettings::from_json`] reads).
    pub fn to_json(&self) -> String {
        serde_json::to_string_pretty(&SettingsJson::from(self)).expect("plain data serialises")
    }
}

#[cfg(test)]
mod vocabulary_tests {
    use super::*;

    #[test]
    fn names_parse_in_any_case_and_print_canonically() {
        assert_eq!("Symmetric".parse::<Mode>().unwrap(), Mode::Deform);
        assert_eq!(" OFFSET ".parse::<Mode>().unwrap(), Mode::Offset);
        assert_eq!(
            "BSpline3".parse::<Interpolation>().unwrap(),
            Interpolation::BSpline3
        );
        assert_eq!(
            "keys".parse::<Interpolation>().unwrap(),
            Interpolation::Keys
        );
        assert_eq!("Gauss2D".parse::<SubPixel>().unwrap(), SubPixel::Gauss2d);
        assert_eq!(Mode::Deform.to_string(), "symmetric");
        assert_eq!(Interpolation::BSpline.to_string(), "bspline");
        assert_eq!(SubPixel::Gauss3.to_string(), "gauss3");
        assert_eq!(
            "Gaussian".parse::<Weighting>().unwrap(),
            Weighting::Gaussian
        );
        assert_eq!(Weighting::Blackman.to_string(), "blackman");
        assert!("hann"
            .parse::<Weighting>()
            .unwrap_err()
            .to_string()
            .contains("weighting \"hann\""));
        let e = "cubic".parse::<Interpolation>().unwrap_err().to_string();
        assert!(
            e.contains("interpolation \"cubic\"") && e.contains("\"keys\""),
            "{e}"
        );
    }

    #[test]
    fn json_round_trip_defaults_and_per_pass_values() {
        let d = PivSettings::from_json("{}").unwrap();
        assert_eq!(d, PivSettings::default());
        let s = PivSettings::from_json(
            r#"{"passes": [[64, 64], [32, 8]], "overlap": [0.5, 0.75], "iterations": 2,
                "deformation": "Offset", "interpolation": "keys", "subpixel": "gauss2d",
                "weighting": "blackman",
                "validate": false, "median_eps": 0.2, "median_threshold": 3,
                "min_peak_ratio": 1.2, "uncertainty": false, "roi": [0, 8, 640, 200]}"#,
        )
        .unwrap();
        assert_eq!(
            s.passes[1],
            Pass {
                w: 32,
                h: 8,
                overlap: 0.75,
                iterations: 2
            }
        );
        assert_eq!(s.mode, Mode::Offset);
        assert_eq!(s.interpolation, Interpolation::Keys);
        assert_eq!(s.subpixel, SubPixel::Gauss2d);
        assert_eq!(s.weighting, Weighting::Blackman);
        assert!(!s.validate);
        assert!(!s.uncertainty);
        assert_eq!(s.roi, Some(Roi::from([0, 8, 640, 200])));
        assert_eq!(
            (s.median_eps, s.median_threshold, s.min_peak_ratio),
            (0.2, 3.0, 1.2)
        );
        assert_eq!(PivSettings::from_json(&s.to_json()).unwrap(), s);
        assert_eq!(PivSettings::from_json(&d.to_json()).unwrap(), d);
    }

    #[test]
    fn bad_json_names_the_key() {
        let err = |t: &str| PivSettings::from_json(t).unwrap_err().to_string();
        assert!(err(r#"{"median_epsilon": 0.1}"#).contains("unknown field `median_epsilon`"));
        assert!(err(r#"{"overlap": [0.5]}"#).contains("overlap has 1 values for 3 passes"));
        assert!(err(r#"{"overlap": 1.0}"#).contains("overlap 1 is outside [0, 1)"));
        assert!(err(r#"{"deformation": "warp"}"#).contains("deformation \"warp\""));
        assert!(err(r#"{"iterations": 0}"#).contains("0 iterations"));
        assert!(err(r#"{"passes": []}"#).contains("passes is empty"));
        assert!(err("[1, 2]").contains("PIV settings"));
        assert!(err(r#"{"roi": [5, 0, 5, 10]}"#).contains("roi [5, 0, 5, 10] is empty"));
        assert!(err(r#"{"roi": [5, 0, 10]}"#).contains("PIV settings"));
    }
}
