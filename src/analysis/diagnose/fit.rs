//! Step 5 of the analysis: the centred least squares (base fit per fold,
//! joint fit with a candidate) and the held-out verdict on a candidate.
//!
//! Why a file of its own: the numerics (scaled, truncated normal equations)
//! are shared by the judging and by the extended model's linear
//! coefficients and their standard errors.

use nalgebra::{DMatrix, DVector};

use super::data::Data;
use super::family::Family;

fn dot_rows(a: &[f64], b: &[f64], train: &[bool]) -> f64 {
    let mut s = 0.0;
    for (i, &t) in train.iter().enumerate() {
        if t {
            s += a[2 * i] * b[2 * i] + a[2 * i + 1] * b[2 * i + 1];
        }
    }
    s
}

/// Minimum-norm least squares from the normal equations, columns scaled to
/// unit norm and small eigenvalues truncated (unidentifiable combinations
/// get no coefficient instead of a huge one).
fn solve_normal(g: &DMatrix<f64>, r: &DVector<f64>) -> DVector<f64> {
    if g.nrows() == 0 {
        return DVector::zeros(0);
    }
    ScaledEigen::new(g).solve(r)
}

/// The eigendecomposition of a Gram matrix with its columns scaled to unit
/// norm: computed once, it gives both the truncated minimum-norm solution
/// and the parameter variances.
struct ScaledEigen {
    scale: Vec<f64>,
    eig: nalgebra::SymmetricEigen<f64, nalgebra::Dyn>,
    lmax: f64,
}

impl ScaledEigen {
    fn new(g: &DMatrix<f64>) -> Self {
        let p = g.nrows();
        let scale: Vec<f64> = (0..p)
            .map(|i| {
                let v = g[(i, i)];
                if v > 0.0 {
                    1.0 / v.sqrt()
                } else {
                    0.0
                }
            })
            .collect();
        let gs = DMatrix::from_fn(p, p, |i, j| g[(i, j)] * scale[i] * scale[j]);
        let eig = nalgebra::SymmetricEigen::new(gs);
        let lmax = eig.eigenvalues.iter().cloned().fold(0.0, f64::max);
        Self { scale, eig, lmax }
    }

    /// Whether eigenvalue `l` is kept (the rest are unidentifiable).
    fn kept(&self, l: f64) -> bool {
        l > 1e-10 * self.lmax && l > 0.0
    }

    fn solve(&self, r: &DVector<f64>) -> DVector<f64> {
        let p = self.scale.len();
        let rs = DVector::from_fn(p, |i, _| r[i] * self.scale[i]);
        let mut x = DVector::zeros(p);
        for k in 0..p {
            let l = self.eig.eigenvalues[k];
            if self.kept(l) {
                let v = self.eig.eigenvectors.column(k);
                let c = v.dot(&rs) / l;
                x += v * c;
            }
        }
        DVector::from_fn(p, |i, _| x[i] * self.scale[i])
    }

    /// Diagonal of the pseudo-inverse of the unscaled Gram matrix.
    fn inverse_diagonal(&self) -> Vec<f64> {
        let p = self.scale.len();
        let mut diag = vec![0.0; p];
        for k in 0..p {
            let l = self.eig.eigenvalues[k];
            if self.kept(l) {
                for (i, dv) in diag.iter_mut().enumerate() {
                    let v = self.eig.eigenvectors[(i, k)];
                    *dv += v * v / l;
                }
            }
        }
        for (i, dv) in diag.iter_mut().enumerate() {
            *dv *= self.scale[i] * self.scale[i];
        }
        diag
    }
}

/// Per fold: the base Gram matrix and right-hand side on the training rows.
pub(super) struct FoldBase {
    pub(super) train: Vec<bool>,
    pub(super) gbb: DMatrix<f64>,
    pub(super) rb: DVector<f64>,
    /// Residual of every row after the fold's base fit.
    pub(super) resid: Vec<f64>,
    /// The base Gram matrix's decomposition (`None` without base columns).
    eig: Option<ScaledEigen>,
    /// Residual variance over the training rows' measured components.
    sigma2: f64,
}

impl FoldBase {
    /// `G⁺ x` for the fold's base Gram matrix `G` (empty without base
    /// columns).
    pub(super) fn gram_solve(&self, x: &DVector<f64>) -> DVector<f64> {
        match &self.eig {
            Some(e) => e.solve(x),
            None => DVector::zeros(0),
        }
    }
}

pub(super) fn fold_base(d: &Data, base: &[Vec<f64>], train: Vec<bool>) -> FoldBase {
    let p = base.len();
    let mut gbb = DMatrix::zeros(p, p);
    for j in 0..p {
        for k in j..p {
            let v = dot_rows(&base[j], &base[k], &train);
            gbb[(j, k)] = v;
            gbb[(k, j)] = v;
        }
    }
    let rb = DVector::from_fn(p, |j, _| dot_rows(&base[j], &d.r0, &train));
    let eig = (p > 0).then(|| ScaledEigen::new(&gbb));
    let beta = eig
        .as_ref()
        .map_or_else(|| DVector::zeros(0), |e| e.solve(&rb));
    let mut resid = d.r0.clone();
    for (j, col) in base.iter().enumerate() {
        let b = beta[j];
        if b != 0.0 {
            for (r, c) in resid.iter_mut().zip(col) {
                *r -= b * c;
            }
        }
    }
    let (mut ss, mut k) = (0.0, 0usize);
    for (i, &t) in train.iter().enumerate() {
        if t && !d.excluded[i] {
            for c in (0..2).filter(|&c| d.measured[c]) {
                ss += resid[2 * i + c] * resid[2 * i + c];
                k += 1;
            }
        }
    }
    let dof = k.saturating_sub(p).max(1);
    FoldBase {
        train,
        gbb,
        rb,
        resid,
        eig,
        sigma2: ss / dof as f64,
    }
}

/// Joint fit of base + candidate columns on the fold's training rows;
/// returns the residual of every row and the candidate's coefficients.
pub(super) fn fit_with(
    d: &Data,
    base: &[Vec<f64>],
    fb: &FoldBase,
    cand: &[Vec<f64>],
) -> (Vec<f64>, Vec<f64>) {
    let p = base.len();
    let k = cand.len();
    let mut g = DMatrix::zeros(p + k, p + k);
    g.view_mut((0, 0), (p, p)).copy_from(&fb.gbb);
    let mut r = DVector::zeros(p + k);
    r.rows_mut(0, p).copy_from(&fb.rb);
    for a in 0..k {
        for j in 0..p {
            let v = dot_rows(&cand[a], &base[j], &fb.train);
            g[(p + a, j)] = v;
            g[(j, p + a)] = v;
        }
        for b in a..k {
            let v = dot_rows(&cand[a], &cand[b], &fb.train);
            g[(p + a, p + b)] = v;
            g[(p + b, p + a)] = v;
        }
        r[p + a] = dot_rows(&cand[a], &d.r0, &fb.train);
    }
    let beta = solve_normal(&g, &r);
    let mut resid = d.r0.clone();
    for (j, col) in base.iter().chain(cand.iter()).enumerate() {
        let b = beta[j];
        if b != 0.0 {
            for (rr, c) in resid.iter_mut().zip(col) {
                *rr -= b * c;
            }
        }
    }
    (resid, beta.iter().skip(p).cloned().collect())
}

/// Squared error of `r` (every entry: centred vectors are zero on the
/// rows and components no fit sees) after the least-squares fit of
/// `cols` to it.
pub(super) fn sse_after(r: &[f64], cols: &[Vec<f64>]) -> f64 {
    let dot = |a: &[f64], b: &[f64]| a.iter().zip(b).map(|(x, y)| x * y).sum::<f64>();
    let k = cols.len();
    let mut g = DMatrix::zeros(k, k);
    for a in 0..k {
        for b in a..k {
            let v = dot(&cols[a], &cols[b]);
            g[(a, b)] = v;
            g[(b, a)] = v;
        }
    }
    let rhs = DVector::from_fn(k, |a, _| dot(&cols[a], r));
    let beta = solve_normal(&g, &rhs);
    r.iter()
        .enumerate()
        .map(|(i, v)| {
            let e = v - (0..k).map(|a| beta[a] * cols[a][i]).sum::<f64>();
            e * e
        })
        .sum()
}

/// Copies the held-out rows (`!train[i]`, index `2i + c`) of `src` into
/// `dst`: pooled over the folds, this assembles every point's held-out
/// residual. Only judged rows ([`Data::judged`]) of measured components
/// are copied: `dst` starts as NaN ([`unjudged`]) and what stays NaN is
/// left out of [`rms_comp`] and [`paired_z`].
pub(super) fn keep_heldout(d: &Data, dst: &mut [f64], src: &[f64], train: &[bool]) {
    for (i, &t) in train.iter().enumerate() {
        if !t && d.judged[i] {
            for c in 0..2 {
                if d.measured[c] {
                    dst[2 * i + c] = src[2 * i + c];
                }
            }
        }
    }
}

/// A pooled held-out vector before any fold is kept: every entry NaN (not
/// judged).
pub(super) fn unjudged(d: &Data) -> Vec<f64> {
    vec![f64::NAN; 2 * d.n]
}

/// Held-out verdict on one family.
#[derive(Clone)]
pub(super) struct Verdict {
    pub(super) family: Family,
    /// Pooled held-out residual after, `2i + c`.
    pub(super) after: Vec<f64>,
    pub(super) reduction: f64,
    pub(super) z: f64,
    pub(super) gain_pct: f64,
    pub(super) rms_before: f64,
    pub(super) rms_after: f64,
    /// For a table family: z of the held-out per-target χ² against the
    /// replicates' σ (`tables::heldout_chi_z`); −∞ for other families.
    pub(super) table_z: f64,
}

/// Paired held-out test of `after` against `before` on component `c`:
/// `(sum, z)`, the summed reduction of squared error `b² − a²` over the
/// judged rows and its mean over its standard error. The variance of the
/// sum is the rows' own (their sample variance, `m` of them) plus
/// `base_var`: the part the rows share because the held-out residuals
/// carry the error of the base fitted on the other folds (see
/// [`base_share`]; 0 for a comparison where both sides carry the same
/// base).
pub(super) fn paired_z(before: &[f64], after: &[f64], c: usize, base_var: f64) -> (f64, f64) {
    let diffs: Vec<f64> = before
        .iter()
        .zip(after)
        .skip(c)
        .step_by(2)
        .map(|(b, a)| b * b - a * a)
        .filter(|v| *v != 0.0 && v.is_finite())
        .collect();
    let m = diffs.len();
    if m < 3 {
        return (0.0, 0.0);
    }
    let sum: f64 = diffs.iter().sum();
    let mean = sum / m as f64;
    let var = diffs.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (m - 1) as f64;
    let var_sum = m as f64 * var + base_var.max(0.0);
    let z = if var_sum > 0.0 {
        sum / var_sum.sqrt()
    } else {
        0.0
    };
    (sum, z)
}

/// The variance the held-out rows of fold `fb` share in a candidate's
/// summed reduction `Σ (b² − a²)` on component `c`, through the base's
/// estimation error: `4·σ²·wᵀ G⁺ w`, `w = Σ_held-out x_i·u_i` (the base
/// columns `x_i` at the held-out rows weighted by the candidate's change
/// of prediction `u_i = b_i − a_i`), `G` the fold's base Gram matrix and
/// `σ²` its training residual variance.
///
/// Why: a held-out residual is `b_i = ε_i + e_i`, its noise plus the
/// error `e_i = x_i·(β̂ − β)` of the base fitted on the other folds. The
/// reduction is `Σ (2 b_i u_i − u_i²)`; its part `2 Σ e_i u_i` is one
/// random number for the whole fold (`e` is one smooth function over
/// the held-out cycle, an extrapolation in time for the first and the
/// last cycle), which the rows' sample variance counts as `m` independent
/// pieces of evidence. A candidate whose prediction change follows the
/// base's extrapolation error (a y drift against a thermal offset fitted
/// on the other cycles) then looks significant on a clean stage: a
/// clean random stage's first cycle gave such a drift a row-wise z of 6.4.
/// `Var(Σ e_i u_i) = σ²·wᵀ G⁻¹ w` is that part's variance.
pub(super) fn base_share(
    d: &Data,
    base: &[Vec<f64>],
    fb: &FoldBase,
    after: &[f64],
    c: usize,
) -> f64 {
    let Some(eig) = &fb.eig else {
        return 0.0;
    };
    let p = base.len();
    let mut w = DVector::zeros(p);
    for i in 0..d.n {
        if fb.train[i] || !d.judged[i] {
            continue;
        }
        let u = fb.resid[2 * i + c] - after[2 * i + c];
        if u == 0.0 || !u.is_finite() {
            continue;
        }
        for (j, col) in base.iter().enumerate() {
            w[j] += col[2 * i + c] * u;
        }
    }
    let x = eig.solve(&w);
    4.0 * fb.sigma2 * w.dot(&x)
}

/// RMS of component `c` of `v` (index `2i + c`) over its finite entries
/// (NaN = not judged, see [`keep_heldout`]); 0 when there is none.
pub(super) fn rms_comp(v: &[f64], c: usize) -> f64 {
    let (s, k) = v
        .iter()
        .skip(c)
        .step_by(2)
        .filter(|x| x.is_finite())
        .fold((0.0, 0usize), |(s, k), x| (s + x * x, k + 1));
    (s / k.max(1) as f64).sqrt()
}

/// [`solve_normal`] plus the diagonal of the pseudo-inverse of `g` (the
/// parameter variances per unit residual variance).
pub(super) fn solve_with_cov(g: &DMatrix<f64>, r: &DVector<f64>) -> (DVector<f64>, Vec<f64>) {
    if g.nrows() == 0 {
        return (DVector::zeros(0), Vec::new());
    }
    let se = ScaledEigen::new(g);
    (se.solve(r), se.inverse_diagonal())
}

/// The diagonal of the pseudo-inverse of `g` (the parameter variances per
/// unit residual variance), `None` for a parameter the Gram matrix does not
/// determine: a zero column, or one whose weight on the directions the
/// pseudo-inverse drops exceeds [`NULL_WEIGHT`].
///
/// Why not [`solve_with_cov`]'s diagonal: the pseudo-inverse leaves the
/// dropped directions out, so a parameter that lies along one gets a small
/// (or zero) variance instead of none; a place or width the log cannot
/// fix would be printed with a confident σ.
pub(super) fn determined_variances(g: &DMatrix<f64>) -> Vec<Option<f64>> {
    if g.nrows() == 0 {
        return Vec::new();
    }
    let se = ScaledEigen::new(g);
    let diag = se.inverse_diagonal();
    (0..g.nrows())
        .map(|i| {
            let null: f64 = (0..g.nrows())
                .filter(|&k| !se.kept(se.eig.eigenvalues[k]))
                .map(|k| se.eig.eigenvectors[(i, k)].powi(2))
                .sum();
            (se.scale[i] > 0.0 && null <= NULL_WEIGHT).then_some(diag[i])
        })
        .collect()
}

/// Largest weight of a parameter on the unidentifiable directions for it
/// to count as determined (the rule of the model's own fit,
/// `model::fit`).
const NULL_WEIGHT: f64 = 1e-2;

/// Base-fit model selection: which groups of base columns (one group per
/// model term, or per term and axis where its parameters name one) the
/// log supports. Backward elimination on the pooled
/// held-out squared error over the judged rows of the measured components:
/// starting from every group, the group whose removal leaves the smallest
/// held-out error is removed as long as that error is not larger than with
/// it; the empty base (the model as given) competes at the end. Why: a
/// base fit with more free parameters than the log can resolve (a 400 µm
/// screw's harmonics on targets 10 mm apart, or on one cycle's short range)
/// predicts held-out data worse than the model's own values; such
/// parameters stay at the model's value instead.
///
/// Returns the indices (into `cols`) of the kept columns, in order.
pub(super) fn select_base(d: &Data, names: &[String], cols: &[Vec<f64>]) -> Vec<usize> {
    let p = cols.len();
    if p == 0 {
        return Vec::new();
    }
    // Groups by term name, and within a term by the axis a parameter
    // names (`x_…`/`y_…`, e.g. the thermal term's per-axis coefficients):
    // one axis's part is kept or dropped on its own evidence.
    let mut groups: Vec<(String, Vec<usize>)> = Vec::new();
    for (j, name) in names.iter().enumerate() {
        let term = match name.split_once('.') {
            Some((t, p)) if p.starts_with("x_") || p.starts_with("y_") => {
                format!("{t}.{}", &p[..1])
            }
            Some((t, _)) => t.to_string(),
            None => name.clone(),
        };
        match groups.iter_mut().find(|(t, _)| *t == term) {
            Some((_, v)) => v.push(j),
            None => groups.push((term, vec![j])),
        }
    }
    // Per fold: Gram matrix and right-hand side over the training rows.
    let folds: Vec<(Vec<bool>, DMatrix<f64>, DVector<f64>)> = (0..d.nfolds)
        .map(|f| {
            let train: Vec<bool> = d.fold.iter().map(|&k| k != f).collect();
            let mut g = DMatrix::zeros(p, p);
            for j in 0..p {
                for k in j..p {
                    let v = dot_rows(&cols[j], &cols[k], &train);
                    g[(j, k)] = v;
                    g[(k, j)] = v;
                }
            }
            let r = DVector::from_fn(p, |j, _| dot_rows(&cols[j], &d.r0, &train));
            (train, g, r)
        })
        .collect();
    let sse = |keep: &[usize]| -> f64 {
        let mut total = 0.0;
        for (train, g, r) in &folds {
            let k = keep.len();
            let beta = if k == 0 {
                DVector::zeros(0)
            } else {
                let gs = DMatrix::from_fn(k, k, |a, b| g[(keep[a], keep[b])]);
                let rs = DVector::from_fn(k, |a, _| r[keep[a]]);
                solve_normal(&gs, &rs)
            };
            for i in 0..d.n {
                if train[i] || !d.judged[i] {
                    continue;
                }
                for c in 0..2 {
                    if !d.measured[c] {
                        continue;
                    }
                    let mut e = d.r0[2 * i + c];
                    for (a, &j) in keep.iter().enumerate() {
                        e -= beta[a] * cols[j][2 * i + c];
                    }
                    total += e * e;
                }
            }
        }
        total
    };
    let flat = |gs: &[usize]| -> Vec<usize> {
        let mut v: Vec<usize> = gs.iter().flat_map(|&g| groups[g].1.clone()).collect();
        v.sort_unstable();
        v
    };
    let mut current: Vec<usize> = (0..groups.len()).collect();
    let mut best = sse(&flat(&current));
    while !current.is_empty() {
        let mut cand: Option<(usize, f64)> = None;
        for k in 0..current.len() {
            let mut without = current.clone();
            without.remove(k);
            let s = sse(&flat(&without));
            if cand.is_none_or(|(_, b)| s < b) {
                cand = Some((k, s));
            }
        }
        match cand {
            Some((k, s)) if s <= best => {
                current.remove(k);
                best = s;
            }
            _ => break,
        }
    }
    if !current.is_empty() && sse(&[]) <= best {
        current.clear();
    }
    flat(&current)
}
