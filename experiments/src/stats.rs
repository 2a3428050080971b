//! Means, 95 % confidence intervals and the tests that decide the paper's claims.
//!
//! * [`mean_ci`] / [`summarise`] — a per-run quantity's mean with its 95 % interval
//!   (Student's t);
//! * [`paired_t`] — the two-sided one-sample t-test of paired differences against 0;
//! * [`holm`] — Holm's step-down correction of a family of p-values;
//! * [`signed_rank`] — Wilcoxon's signed-rank test (exact when it can be), for one pooled
//!   decision over per-task differences;
//! * [`sign_test`] — the exact binomial sign test of wins against losses.

use serde::{Deserialize, Serialize};
use statrs::distribution::{Binomial, ContinuousCDF, DiscreteCDF, Normal, StudentsT};

/// Reads a number that JSON may hold as `null`: `serde_json` writes NaN (an interval of no
/// runs, a ratio of a method not run) as `null`, and a summary must read back what it wrote.
pub fn f64_or_nan<'de, D: serde::Deserializer<'de>>(d: D) -> Result<f64, D::Error> {
    Ok(Option::<f64>::deserialize(d)?.unwrap_or(f64::NAN))
}

/// The level every test and interval here is taken at: 5 % (95 % intervals).
pub const ALPHA: f64 = 0.05;

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

/// The two-sided 95 % quantile of Student's t with `df` degrees of freedom.
fn t_quantile(df: usize) -> f64 {
    StudentsT::new(0.0, 1.0, df as f64)
        .map(|t| t.inverse_cdf(1.0 - ALPHA / 2.0))
        .unwrap_or(f64::NAN)
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
    Some(MeanCi {
        mean,
        half_width: t_quantile(n - 1) * standard_error(values, mean),
        n,
    })
}

/// The standard error of the mean of `values` (at least two).
fn standard_error(values: &[f64], mean: f64) -> f64 {
    let n = values.len() as f64;
    let var = values.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (n - 1.0);
    (var / n).sqrt()
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

/// Mean and 95 % interval of a per-run quantity, as the experiments report it.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Summary {
    /// Mean over runs.
    #[serde(deserialize_with = "f64_or_nan")]
    pub mean: f64,
    /// Lower end of the 95 % interval.
    #[serde(deserialize_with = "f64_or_nan")]
    pub lo: f64,
    /// Upper end of the 95 % interval.
    #[serde(deserialize_with = "f64_or_nan")]
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

/// The two-sided p-value of the one-sample t-test of `differences` against a mean of 0 (the
/// paired t-test, when each is one run's difference). 1 with fewer than two differences; with
/// no spread, 0 when the mean is not 0.
pub fn paired_t(differences: &[f64]) -> f64 {
    let n = differences.len();
    if n < 2 {
        return 1.0;
    }
    let mean = differences.iter().sum::<f64>() / n as f64;
    let se = standard_error(differences, mean);
    if se == 0.0 {
        return if mean == 0.0 { 1.0 } else { 0.0 };
    }
    let t = (mean / se).abs();
    StudentsT::new(0.0, 1.0, (n - 1) as f64).map_or(f64::NAN, |d| 2.0 * d.sf(t))
}

/// Holm's step-down adjustment of a family of p-values: `adjusted[i] < α` exactly when
/// Holm's procedure at level α rejects hypothesis `i`, which keeps the chance of any false
/// rejection in the family at most α. Order kept; NaN counts as 1.
pub fn holm(p: &[f64]) -> Vec<f64> {
    let m = p.len();
    let clean = |x: f64| if x.is_nan() { 1.0 } else { x };
    let mut order: Vec<usize> = (0..m).collect();
    order.sort_by(|&a, &b| clean(p[a]).total_cmp(&clean(p[b])));
    let mut adjusted = vec![1.0; m];
    let mut running = 0.0f64;
    for (rank, &i) in order.iter().enumerate() {
        running = running.max(((m - rank) as f64 * clean(p[i])).min(1.0));
        adjusted[i] = running;
    }
    adjusted
}

/// Wilcoxon's signed-rank test of `differences` against a median of 0.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct SignedRank {
    /// Differences that are not 0 (zeros are dropped).
    pub n: usize,
    /// Sum of the ranks of the positive differences.
    #[serde(deserialize_with = "f64_or_nan")]
    pub w_plus: f64,
    /// Sum of the ranks of the negative differences.
    #[serde(deserialize_with = "f64_or_nan")]
    pub w_minus: f64,
    /// Two-sided p-value.
    #[serde(deserialize_with = "f64_or_nan")]
    pub p: f64,
    /// Whether `p` is exact (no ties, at most [`EXACT_SIGNED_RANK`] differences) or from the
    /// normal approximation with tie and continuity corrections.
    pub exact: bool,
}

/// Up to this many differences without ties, [`signed_rank`] counts the exact distribution.
pub const EXACT_SIGNED_RANK: usize = 50;

/// Wilcoxon's signed-rank test: ranks `|d|` (ties get their average rank), sums the ranks of
/// the positive and the negative differences, and gives the two-sided p-value.
pub fn signed_rank(differences: &[f64]) -> SignedRank {
    let mut d: Vec<f64> = differences
        .iter()
        .copied()
        .filter(|x| *x != 0.0 && !x.is_nan())
        .collect();
    d.sort_by(|a, b| a.abs().total_cmp(&b.abs()));
    let n = d.len();
    let (mut w_plus, mut w_minus, mut ties) = (0.0, 0.0, 0.0);
    let mut i = 0;
    while i < n {
        let j = (i..n).take_while(|&j| d[j].abs() == d[i].abs()).count() + i;
        let rank = (i + j + 1) as f64 / 2.0; // ranks i+1 ..= j, averaged
        let t = (j - i) as f64;
        ties += t * t * t - t;
        for x in &d[i..j] {
            if *x > 0.0 {
                w_plus += rank;
            } else {
                w_minus += rank;
            }
        }
        i = j;
    }
    if n == 0 {
        return SignedRank {
            n,
            w_plus,
            w_minus,
            p: 1.0,
            exact: true,
        };
    }
    let exact = ties == 0.0 && n <= EXACT_SIGNED_RANK;
    let p = if exact {
        exact_signed_rank_p(n, w_plus.min(w_minus) as usize)
    } else {
        let nf = n as f64;
        let mean = nf * (nf + 1.0) / 4.0;
        let var = nf * (nf + 1.0) * (2.0 * nf + 1.0) / 24.0 - ties / 48.0;
        let z = ((w_plus - mean).abs() - 0.5).max(0.0) / var.sqrt();
        Normal::new(0.0, 1.0).map_or(f64::NAN, |d| (2.0 * d.sf(z)).min(1.0))
    };
    SignedRank {
        n,
        w_plus,
        w_minus,
        p,
        exact,
    }
}

/// `P(W ≤ w) · 2` (capped at 1) for the signed-rank statistic of `n` untied differences
/// under the null: the number of subsets of ranks `1..=n` summing to at most `w`, over `2ⁿ`.
fn exact_signed_rank_p(n: usize, w: usize) -> f64 {
    let max = n * (n + 1) / 2;
    let mut ways = vec![0.0f64; max + 1];
    ways[0] = 1.0;
    for rank in 1..=n {
        for s in (rank..=max).rev() {
            ways[s] += ways[s - rank];
        }
    }
    let below: f64 = ways[..=w.min(max)].iter().sum();
    (2.0 * below / 2f64.powi(n as i32)).min(1.0)
}

/// The exact two-sided binomial sign test: `wins` against `losses` (draws left out) under a
/// fair coin. 1 when there are neither.
pub fn sign_test(wins: usize, losses: usize) -> f64 {
    let n = wins + losses;
    if n == 0 {
        return 1.0;
    }
    let Ok(b) = Binomial::new(0.5, n as u64) else {
        return f64::NAN;
    };
    let k = wins.min(losses) as u64;
    (2.0 * b.cdf(k)).min(1.0)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn close(a: f64, b: f64, tol: f64) -> bool {
        (a - b).abs() <= tol
    }

    #[test]
    fn intervals_use_students_t() {
        let ci = mean_ci(&[1.0, 2.0, 3.0]).unwrap();
        assert!((ci.mean - 2.0).abs() < 1e-12);
        // sd = 1, n = 3, t(2) = 4.303 → 4.303 / √3.
        assert!(close(ci.half_width, 4.302_653 / 3f64.sqrt(), 1e-5));
        // 100 runs: t(99) = 1.984, not the normal 1.96.
        let hundred: Vec<f64> = (0..100).map(f64::from).collect();
        let se = standard_error(&hundred, 49.5);
        assert!(close(
            mean_ci(&hundred).unwrap().half_width / se,
            1.984_217,
            1e-5
        ));
        assert_eq!(mean_ci(&[5.0]).unwrap().half_width, 0.0);
        assert!(mean_ci(&[]).is_none());
        assert_eq!(median(&[3.0, 1.0, 2.0]), Some(2.0));
        assert_eq!(median(&[4.0, 1.0, 2.0, 3.0]), Some(2.5));
    }

    #[test]
    fn the_paired_t_test_matches_known_values() {
        // mean 1, se 1/√6, n = 4: t = √6, df 3; in closed form for 3 degrees of freedom,
        // p = 1 − (2/π)(θ + sin θ cos θ) with tan θ = t/√3 = √2: 0.091 721.
        let p = paired_t(&[0.0, 1.0, 1.0, 2.0]);
        assert!(close(p, 0.091_721, 1e-6), "{p}");
        // The interval excludes 0 exactly when p < 0.05.
        for shift in [0.0, 0.3, 0.5, 0.7, 1.0] {
            let d: Vec<f64> = [-1.0, 0.5, 1.5, -0.2, 0.9, 0.1]
                .iter()
                .map(|x| x + shift)
                .collect();
            let s = summarise(&d);
            assert_eq!(s.lo > 0.0 || s.hi < 0.0, paired_t(&d) < ALPHA, "{shift}");
        }
        assert_eq!(paired_t(&[1.0]), 1.0);
        assert_eq!(paired_t(&[2.0, 2.0]), 0.0);
        assert_eq!(paired_t(&[0.0, 0.0]), 1.0);
    }

    #[test]
    fn holm_steps_down() {
        // m = 4: sorted 0.01·4 = 0.04, 0.02·3 = 0.06, 0.03·2 = 0.06, 0.5.
        let adj = holm(&[0.03, 0.5, 0.01, 0.02]);
        let want = [0.06, 0.5, 0.04, 0.06];
        for (a, w) in adj.iter().zip(want) {
            assert!(close(*a, w, 1e-12), "{adj:?}");
        }
        assert_eq!(holm(&[f64::NAN, 0.001]), [1.0, 0.002]);
        assert!(holm(&[]).is_empty());
    }

    #[test]
    fn the_signed_rank_test_matches_known_values() {
        // n = 10, every difference positive: W- = 0, exact two-sided p = 2/1024.
        let all_up: Vec<f64> = (1..=10).map(f64::from).collect();
        let r = signed_rank(&all_up);
        assert!(r.exact && r.w_plus == 55.0 && r.w_minus == 0.0);
        assert!(close(r.p, 2.0 / 1024.0, 1e-12));
        // n = 5 with W- = 3 ({1, 2} or {3}): P(W ≤ 3) = 5/32, p = 10/32.
        let r = signed_rank(&[-1.0, -2.0, 3.0, 4.0, 5.0]);
        assert_eq!((r.w_plus, r.w_minus), (12.0, 3.0));
        assert!(close(r.p, 10.0 / 32.0, 1e-12));
        // Zeros are dropped; ties take the normal approximation.
        let r = signed_rank(&[0.0, 1.0, 1.0, -1.0, 2.0, 3.0]);
        assert_eq!(r.n, 5);
        assert!(!r.exact && r.p > 0.05 && r.p <= 1.0);
        assert_eq!(signed_rank(&[]).p, 1.0);
        // 15 tasks, 13 positive: decided.
        let mostly: Vec<f64> = (1..=15)
            .map(|i| if i <= 2 { -f64::from(i) } else { f64::from(i) })
            .collect();
        assert!(signed_rank(&mostly).p < 0.01);
    }

    #[test]
    fn the_sign_test_is_exact() {
        // 7 wins, 3 losses: 2 · P(X ≤ 3 | 10, ½) = 2 · 176/1024.
        assert!(close(sign_test(7, 3), 352.0 / 1024.0, 1e-12));
        assert_eq!(sign_test(0, 0), 1.0);
        assert!(sign_test(70, 30) < 0.001);
        assert_eq!(sign_test(5, 5), 1.0);
    }
}
