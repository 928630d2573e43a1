//! piv-core: multigrid/multipass FFT cross-correlation PIV.
//!
//! Coordinates: pixel frame with x = column, y = row, origin at the centre of the top-left
//! pixel, y growing downward; displacements (u, v) follow the same axes, in pixels.
//!
//! A window `(w, h)` is `w` px wide (along x, columns) and `h` px tall (along y, rows): `(32, 8)`
//! is 32 px streamwise by 8 px wall-normal when the flow runs along x.
//!
//! - [`multipass::piv`]: multipass PIV on a regular grid (window deformation or offset,
//!   validation, masks);
//! - [`multipass::piv_at`]: the same at arbitrary image positions with given predictors
//!   (Method II);
//! - [`correlate::Correlator`]: one window pair's normalised FFT cross-correlation;
//! - [`weighting`]: the windows' weighting (top-hat, Gaussian, Blackman) and its spatial
//!   response;
//! - [`ensemble`]: correlation planes summed over many pairs (mean displacement and Reynolds
//!   stresses from the summed peak);
//! - [`moments`]: per-vector central sums of orders 3-8 (the statistics' skewness and
//!   flatness);
//! - [`particle_size`]: the particle images' diameter from the correlation peaks, and the
//!   peak-locking check;
//! - [`ptv`]: particle images found with sub-pixel centres and paired between the frames
//!   through a PIV predictor (particle tracking at the wall);
//! - [`seeding`]: each block's background and noise, and the particle images standing out of
//!   them (the seeding density);
//! - [`synth::render_particles`]: synthetic particle images;
//! - [`vortex_fit`]: Lamb-Oseen vortices fitted to the vectors about vortex cores.
//! - [`vortex_joint`]: neighbouring Lamb-Oseen vortices fitted together.

pub mod condition;
pub mod correlate;
pub mod ensemble;
pub mod ensemble_pixel;
pub mod error;
pub(crate) mod gaussian_filter;
pub mod grid;
pub mod image;
pub mod moments;
pub mod multipass;
pub mod particle_size;
pub mod ptv;
pub mod seeding;
pub mod synth;
pub mod validate;
pub mod vortex_fit;
pub mod vortex_joint;
pub mod weighting;

pub use condition::{condition, conditioned, conditioned_into, Conditioning};
pub use correlate::{Correlator, Peak, SubPixel, Uncertainty};
pub use error::PivError;
pub use grid::Grid;
pub use image::{GridField, Pixel};
pub use multipass::{
    piv, piv_at, piv_cropped, piv_with_final_points, roi_margin, Interpolation, Mode, Pass,
    PivField, PivSettings, Predictor, RingGrid, Roi, ROI_RINGS,
};
pub use synth::render_particles;
pub use weighting::Weighting;
