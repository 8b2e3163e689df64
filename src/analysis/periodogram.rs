//! Generalized Lomb–Scargle periodogram (floating mean, Zechmeister &
//! Kürster 2009) of unevenly sampled data.
//!
//! Why not an FFT: a log's positions repeat (forward and backward passes,
//! several cycles), skip (random points) and its times have gaps; the GLS
//! power at frequency f is exactly the fraction of the variance explained by
//! the least-squares fit `a·cos(2πfx) + b·sin(2πfx) + c`, for any sampling.
//!
//! The grid evaluation rotates each sample's phasor by a constant angle per
//! frequency step (one complex multiply instead of a sin/cos), renormalized
//! every 64 steps so rounding does not accumulate.

/// Power `1 − χ²(f)/χ²₀` in `[0, 1]` at each frequency `f0 + k·df`,
/// `k < n`. `x` and `y` must have equal length; fewer than 4 points or zero
/// variance give all zeros.
pub fn gls_grid(x: &[f64], y: &[f64], f0: f64, df: f64, n: usize) -> Vec<f64> {
    let m = x.len().min(y.len());
    let mut out = vec![0.0; n];
    if m < 4 || n == 0 {
        return out;
    }
    let w = 1.0 / m as f64;
    let ybar = y[..m].iter().sum::<f64>() * w;
    let yy: f64 = y[..m].iter().map(|v| (v - ybar) * (v - ybar)).sum::<f64>() * w;
    if yy <= 0.0 || !yy.is_finite() {
        return out;
    }
    // Per-frequency accumulators.
    let mut sy = vec![0.0; n];
    let mut cy = vec![0.0; n];
    let mut ss = vec![0.0; n];
    let mut cc = vec![0.0; n];
    let mut cs = vec![0.0; n];
    let mut s1 = vec![0.0; n];
    let mut c1 = vec![0.0; n];
    let tau = std::f64::consts::TAU;
    for i in 0..m {
        let (mut s, mut c) = (tau * f0 * x[i]).rem_euclid(tau).sin_cos();
        let (ds, dc) = (tau * df * x[i]).rem_euclid(tau).sin_cos();
        let yi = y[i] - ybar;
        for k in 0..n {
            if k % 64 == 0 && k > 0 {
                let ph = (tau * (f0 + k as f64 * df) * x[i]).rem_euclid(tau);
                let (a, b) = ph.sin_cos();
                s = a;
                c = b;
            }
            sy[k] += yi * s;
            cy[k] += yi * c;
            ss[k] += s * s;
            cc[k] += c * c;
            cs[k] += c * s;
            s1[k] += s;
            c1[k] += c;
            let ns = s * dc + c * ds;
            let nc = c * dc - s * ds;
            s = ns;
            c = nc;
        }
    }
    for k in 0..n {
        out[k] = power_from_sums(w, yy, [sy[k], cy[k], ss[k], cc[k], cs[k], s1[k], c1[k]]);
    }
    out
}

fn power_from_sums(w: f64, yy: f64, sums: [f64; 7]) -> f64 {
    let [sy, cy, ss, cc, cs, s1, c1] = sums.map(|v| v * w);
    let (s, c) = (s1, c1);
    let cc_ = cc - c * c;
    let ss_ = ss - s * s;
    let cs_ = cs - c * s;
    let d = cc_ * ss_ - cs_ * cs_;
    if d <= 1e-12 * (cc_ * ss_).abs().max(1e-300) || !d.is_finite() {
        return 0.0;
    }
    // y is centred, so YC = Σ w y cos, YS = Σ w y sin.
    let p = (ss_ * cy * cy + cc_ * sy * sy - 2.0 * cs_ * cy * sy) / (yy * d);
    p.clamp(0.0, 1.0)
}

/// GLS power at one frequency (for refining a grid peak).
pub fn gls_at(x: &[f64], y: &[f64], f: f64) -> f64 {
    gls_grid(x, y, f, 0.0, 1)[0]
}

/// The strongest peak of the GLS periodogram between `f_min` and `f_max`
/// (oversampled `oversample`× relative to `1/span`), refined by
/// golden-section search within one grid step: `(frequency, power)`.
pub fn strongest_peak(
    x: &[f64],
    y: &[f64],
    f_min: f64,
    f_max: f64,
    oversample: f64,
) -> Option<(f64, f64)> {
    if x.len() < 8 || !(f_min > 0.0 && f_max > f_min) {
        return None;
    }
    let (lo, hi) = x
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &v| {
            (a.min(v), b.max(v))
        });
    let span = hi - lo;
    if span <= 0.0 {
        return None;
    }
    let df = 1.0 / (oversample.max(1.0) * span);
    let n = (((f_max - f_min) / df).ceil() as usize + 1).min(200_000);
    let p = gls_grid(x, y, f_min, df, n);
    let (k, _) = p.iter().enumerate().max_by(|a, b| a.1.total_cmp(b.1))?;
    let (mut a, mut b) = (
        (f_min + (k as f64 - 1.0) * df).max(f_min),
        (f_min + (k as f64 + 1.0) * df).min(f_max),
    );
    let g = 0.618_033_988_749_894_9;
    let mut c = b - g * (b - a);
    let mut d = a + g * (b - a);
    let (mut pc, mut pd) = (gls_at(x, y, c), gls_at(x, y, d));
    for _ in 0..30 {
        if pc > pd {
            b = d;
            d = c;
            pd = pc;
            c = b - g * (b - a);
            pc = gls_at(x, y, c);
        } else {
            a = c;
            c = d;
            pc = pd;
            d = a + g * (b - a);
            pd = gls_at(x, y, d);
        }
    }
    let f = 0.5 * (a + b);
    Some((f, gls_at(x, y, f)))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn finds_a_sine_in_uneven_samples() {
        // Uneven positions, period 1600, plus an offset.
        let x: Vec<f64> = (0..400)
            .map(|i| i as f64 * 23.7 + ((i * 7919) % 13) as f64)
            .collect();
        let y: Vec<f64> = x
            .iter()
            .map(|v| 0.8 * (std::f64::consts::TAU * v / 1600.0 + 0.3).sin() + 2.0)
            .collect();
        let (f, p) = strongest_peak(&x, &y, 1.0 / 5000.0, 1.0 / 100.0, 5.0).unwrap();
        assert!((1.0 / f - 1600.0).abs() < 2.0, "period {}", 1.0 / f);
        assert!(p > 0.999, "power {p}");
        // The grid agrees with the single-frequency evaluation.
        let g = gls_grid(&x, &y, 1.0 / 3000.0, 1e-5, 200);
        for (k, v) in g.iter().enumerate().step_by(37) {
            let direct = gls_at(&x, &y, 1.0 / 3000.0 + k as f64 * 1e-5);
            assert!((v - direct).abs() < 1e-9, "{k}: {v} vs {direct}");
        }
    }

    #[test]
    fn degenerate_input_gives_zero_power() {
        assert_eq!(
            gls_grid(&[1.0, 2.0], &[1.0, 2.0], 0.1, 0.1, 3),
            vec![0.0; 3]
        );
        let x: Vec<f64> = (0..10).map(f64::from).collect();
        assert!(gls_grid(&x, &[3.0; 10], 0.1, 0.01, 5)
            .iter()
            .all(|&p| p == 0.0));
        assert!(strongest_peak(&x, &[3.0; 10], 0.2, 0.1, 5.0).is_none());
    }
}
