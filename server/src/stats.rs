//! Aggregation over training seeds.

use d3il_protocol::Stat;

/// Mean and sample standard deviation (n - 1 in the denominator, as the
/// paper's tables over training seeds). One value has std 0.
pub fn mean_std(values: &[f64]) -> (f64, f64) {
    let n = values.len();
    if n == 0 {
        return (f64::NAN, f64::NAN);
    }
    let mean = values.iter().sum::<f64>() / n as f64;
    if n == 1 {
        return (mean, 0.0);
    }
    let var = values.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (n - 1) as f64;
    (mean, var.sqrt())
}

#[derive(Debug, Default, Clone)]
pub struct Agg {
    pub values: Vec<f64>,
}

impl Agg {
    pub fn push(&mut self, v: f64) {
        self.values.push(v);
    }
    pub fn stat(&self) -> Stat {
        let (mean, std) = mean_std(&self.values);
        Stat { mean, std }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sample_std_uses_n_minus_one() {
        let (m, s) = mean_std(&[1.0, 2.0, 3.0, 4.0]);
        assert!((m - 2.5).abs() < 1e-12);
        // var = (2.25 + 0.25 + 0.25 + 2.25) / 3 = 5/3
        assert!((s - (5.0f64 / 3.0).sqrt()).abs() < 1e-12);
        assert_eq!(mean_std(&[0.7]), (0.7, 0.0));
    }
}
