//! The names of the correction: methods, displacement mapping, zero fill (the vocabulary of
//! `rspiv.settings`, parsed case-insensitively).

use crate::error::{CorrectionError, Result};
use std::fmt;
use std::str::FromStr;

/// The correction method.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Method {
    /// No correction: PIV of the raw frames in image px.
    None,
    /// Method I: dewarp the frames, then PIV (`"I"`, alias `"images"`).
    One,
    /// Method II: PIV on the raw frames, vectors mapped back (`"II"`, alias `"vectors"`).
    Two,
}

/// How Method II maps a measured image displacement back to the object frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum DisplacementMapping {
    /// Through the exact inverse, symmetric about the window centre (rspiv's default).
    #[default]
    Full,
    /// Positions only: the displacement kept as measured (the paper's correction).
    Positions,
}

/// How Method I treats the dewarped frames' zero fill (object px imaged outside the sensor).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum ZeroFill {
    /// Vectors centred in the fill are not computed (masked).
    #[default]
    Mask,
    /// No mask: the fill's blank windows are not correlated (the blank-window rule).
    Keep,
}

fn unknown(what: &str, s: &str, names: &str) -> CorrectionError {
    CorrectionError::InvalidInput(format!("{what} {s:?}: use {names}"))
}

impl FromStr for Method {
    type Err = CorrectionError;
    fn from_str(s: &str) -> Result<Self> {
        match s.trim().to_ascii_lowercase().as_str() {
            "none" => Ok(Method::None),
            "i" | "images" => Ok(Method::One),
            "ii" | "vectors" => Ok(Method::Two),
            _ => Err(unknown("method", s, "\"I\", \"II\" or \"none\"")),
        }
    }
}

impl fmt::Display for Method {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Method::None => "none",
            Method::One => "I",
            Method::Two => "II",
        })
    }
}

impl FromStr for DisplacementMapping {
    type Err = CorrectionError;
    fn from_str(s: &str) -> Result<Self> {
        match s.trim().to_ascii_lowercase().as_str() {
            "full" => Ok(DisplacementMapping::Full),
            "positions" => Ok(DisplacementMapping::Positions),
            _ => Err(unknown("mapping", s, "\"full\" or \"positions\"")),
        }
    }
}

impl fmt::Display for DisplacementMapping {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            DisplacementMapping::Full => "full",
            DisplacementMapping::Positions => "positions",
        })
    }
}

impl FromStr for ZeroFill {
    type Err = CorrectionError;
    fn from_str(s: &str) -> Result<Self> {
        match s.trim().to_ascii_lowercase().as_str() {
            "mask" => Ok(ZeroFill::Mask),
            "keep" => Ok(ZeroFill::Keep),
            _ => Err(unknown("zero_fill", s, "\"mask\" or \"keep\"")),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_and_aliases() {
        assert_eq!("ii".parse::<Method>().unwrap(), Method::Two);
        assert_eq!("Vectors".parse::<Method>().unwrap(), Method::Two);
        assert_eq!("IMAGES".parse::<Method>().unwrap(), Method::One);
        assert_eq!("None".parse::<Method>().unwrap(), Method::None);
        assert_eq!(Method::Two.to_string(), "II");
        assert_eq!(
            "Positions".parse::<DisplacementMapping>().unwrap(),
            DisplacementMapping::Positions
        );
        assert_eq!("keep".parse::<ZeroFill>().unwrap(), ZeroFill::Keep);
        let e = "III".parse::<Method>().unwrap_err().to_string();
        assert!(e.contains("method \"III\""), "{e}");
        assert!("half".parse::<DisplacementMapping>().is_err());
    }
}
