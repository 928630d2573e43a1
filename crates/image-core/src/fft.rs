//! FFT sizing.

/// The smallest length `>= n` (and `>= 1`) whose only prime factors are 2, 3 and 5: the sizes
/// `rustfft` transforms fastest. Used for the zero-padded correlation windows of the PIV and
/// the marker template match of the calibration.
pub fn fast_len(n: usize) -> usize {
    let mut m = n.max(1);
    loop {
        let mut k = m;
        for p in [2, 3, 5] {
            while k % p == 0 {
                k /= p;
            }
        }
        if k == 1 {
            return m;
        }
        m += 1;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn five_smooth_lengths() {
        assert_eq!(fast_len(0), 1);
        assert_eq!(fast_len(97), 100);
        assert_eq!(fast_len(48), 48);
        assert_eq!(fast_len(13), 15);
        assert_eq!(fast_len(7), 8);
        assert_eq!(fast_len(121), 125);
    }
}
