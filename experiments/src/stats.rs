//! Means and 95 % confidence intervals across independent runs.

/// Two-sided 97.5 % quantiles of Student's t for 1..=30 degrees of freedom.
const T975: [f64; 30] = [
    12.706, 4.303, 3.182, 2.776, 2.571, 2.447, 2.365, 2.306, 2.262, 2.228, 2.201, 2.179, 2.160,
    2.145, 2.131, 2.120, 2.110, 2.101, 2.093, 2.086, 2.080, 2.074, 2.069, 2.064, 2.060, 2.056,
    2.052, 2.048, 2.045, 2.042,
];

/// Mean and the half-width of its 95 % confidence interval (Student's t; 0 for one sample).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MeanCi {
    /// Sample mean.
    pub mean: f64,
    /// Half-width of the 95 % interval: the interval is `mean ± half_width`.
    pub half_width: f64,
    /// Number of samples.
    pub n: usize,
}

/// Mean and 95 % interval of `values` (`None` when empty).
pub fn mean_ci(values: &[f64]) -> Option<MeanCi> {
    let n = values.len();
    if n == 0 {
        return None;
    }
    let mean = values.iter().sum::<f64>() / n as f64;
    if n == 1 {
        return Some(MeanCi {
            mean,
            half_width: 0.0,
            n,
        });
    }
    let var = values.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (n - 1) as f64;
    let t = T975.get(n - 2).copied().unwrap_or(1.96);
    Some(MeanCi {
        mean,
        half_width: t * (var / n as f64).sqrt(),
        n,
    })
}

/// Median of `values` (`None` when empty).
pub fn median(values: &[f64]) -> Option<f64> {
    if values.is_empty() {
        return None;
    }
    let mut v = values.to_vec();
    v.sort_by(f64::total_cmp);
    let m = v.len() / 2;
    Some(if v.len() % 2 == 1 {
        v[m]
    } else {
        0.5 * (v[m - 1] + v[m])
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn known_values() {
        let ci = mean_ci(&[1.0, 2.0, 3.0]).unwrap();
        assert!((ci.mean - 2.0).abs() < 1e-12);
        // sd = 1, n = 3, t(2) = 4.303 → 4.303 / √3.
        assert!((ci.half_width - 4.303 / 3f64.sqrt()).abs() < 1e-9);
        assert_eq!(mean_ci(&[5.0]).unwrap().half_width, 0.0);
        assert!(mean_ci(&[]).is_none());
        assert_eq!(median(&[3.0, 1.0, 2.0]), Some(2.0));
        assert_eq!(median(&[4.0, 1.0, 2.0, 3.0]), Some(2.5));
    }
}

/// Mean and 95 % interval of a per-run quantity, as the experiments report it.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct Summary {
    /// Mean over runs.
    pub mean: f64,
    /// Lower end of the 95 % interval.
    pub lo: f64,
    /// Upper end of the 95 % interval.
    pub hi: f64,
    /// Runs.
    pub n: usize,
}

impl Summary {
    /// This summary as a chart point at `x`: the mean with its 95 % interval as the band.
    pub fn at(&self, x: f64) -> crate::svg::BandPoint {
        crate::svg::BandPoint {
            x,
            y: self.mean,
            lo: self.lo,
            hi: self.hi,
        }
    }
}

impl From<MeanCi> for Summary {
    fn from(ci: MeanCi) -> Self {
        Self {
            mean: ci.mean,
            lo: ci.mean - ci.half_width,
            hi: ci.mean + ci.half_width,
            n: ci.n,
        }
    }
}

/// [`Summary`] of `values`; all NaN with `n = 0` when there are none.
pub fn summarise(values: &[f64]) -> Summary {
    mean_ci(values).map_or(
        Summary {
            mean: f64::NAN,
            lo: f64::NAN,
            hi: f64::NAN,
            n: 0,
        },
        Summary::from,
    )
}
