//! Particle tracking assisted by PIV: the particle images of each frame with their sub-pixel
//! centres ([`detect`]), and those of frame A paired with frame B's through a predicted
//! displacement ([`track`]). Binning the tracks by their distance from a wall (Python,
//! `rspiv.ptv`) gives a mean profile and Reynolds stresses at a resolution finer than any
//! window, down to about a particle image's diameter from the wall.

pub mod detect;
pub mod track;

pub use detect::{detect, Particles};
pub use track::{stray_share, track, Matches};
