//! Numbers in messages: every digit a value needs to read back, and no more.

/// Shows an `f64` as its shortest text that reads back to the same number, in exponent form
/// outside `[1e-4, 1e15)` (`1e308`, `5e-324`): Rust's `{}` writes `1e300` with 300 zeros, which
/// buries an error message.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Num(pub f64);

impl std::fmt::Display for Num {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let x = self.0;
        if x == 0.0 || !x.is_finite() || (1e-4..1e15).contains(&x.abs()) {
            write!(f, "{x}")
        } else {
            write!(f, "{x:e}")
        }
    }
}

#[cfg(test)]
mod tests {
    use super::Num;

    #[test]
    fn extreme_numbers_print_in_a_few_characters() {
        let show = |x: f64| Num(x).to_string();
        assert_eq!(show(1e308), "1e308");
        assert_eq!(show(-1e300), "-1e300");
        assert_eq!(show(5e-324), "5e-324");
        assert_eq!(show(1e-6), "1e-6");
        assert_eq!(show(0.05), "0.05");
        assert_eq!(show(15.0), "15");
        assert_eq!(show(-0.2), "-0.2");
        assert_eq!(show(0.0), "0");
        assert_eq!(show(f64::NAN), "NaN");
        assert_eq!(show(1.5e301), "1.5e301");
        for x in [1e308, 5e-324, 0.1, 123456.789, 1e-300] {
            assert_eq!(show(x).parse::<f64>().unwrap(), x);
        }
    }
}
