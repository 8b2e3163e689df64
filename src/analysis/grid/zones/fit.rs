//! The set-ups' least squares, one component at a time: whether the
//! overlaps link every zone to the reference, whether they determine every
//! parameter, the fit, its noise and σ.

use nalgebra::{DMatrix, DVector};

use super::overlap::Equation;
use super::ZoneError;

/// Smallest eigenvalue of the scaled normal matrix, relative to the
/// largest, that counts as determined (a single shared line leaves an
/// exact null direction, rounding makes it ~1e-16).
const RANK_TOL: f64 = 1e-10;

/// Whether every zone is linked to `reference` by a chain of overlaps;
/// `Err(zone)` names the first that is not.
pub(super) fn connected(eqs: &[Equation], zones: usize, reference: usize) -> Result<(), usize> {
    let mut adj = vec![Vec::new(); zones];
    for e in eqs {
        adj[e.node].push(e.other);
        adj[e.other].push(e.node);
    }
    let mut seen = vec![false; zones];
    seen[reference] = true;
    let mut stack = vec![reference];
    while let Some(k) = stack.pop() {
        for &j in &adj[k] {
            if !seen[j] {
                seen[j] = true;
                stack.push(j);
            }
        }
    }
    seen.iter().position(|s| !s).map_or(Ok(()), Err)
}

/// The fit's input: equations, zone centres, the reference.
pub(super) struct Problem<'a> {
    /// Overlap equations.
    pub eqs: &'a [Equation],
    /// Zone centres `[x, y]`, µm.
    pub centres: &'a [[f64; 2]],
    /// The reference zone (no parameters).
    pub reference: usize,
    /// Zone names, for errors.
    pub names: &'a [&'a str],
}

/// One component's fit.
#[derive(Debug, Clone, PartialEq)]
pub(super) struct ComponentFit {
    /// Per zone `[offset µm, slope µrad]` and their σ.
    params: Vec<[(f64, f64); 2]>,
    /// Residual of every equation, µm.
    residuals: Vec<f64>,
    /// Zones of every equation (node, other).
    pairs: Vec<(usize, usize)>,
    /// Covariance of the parameters (offsets µm, slopes µrad), columns
    /// as [`Problem::col`].
    cov: DMatrix<f64>,
    /// The reference zone (no columns).
    reference: usize,
    /// Noise of one reading, µm.
    pub noise_um: f64,
    /// Its degrees of freedom.
    pub dof: f64,
}

impl ComponentFit {
    /// Zone `k`'s parameter `p` (0 offset, 1 slope): value and σ.
    pub fn param(&self, k: usize, p: usize) -> (f64, f64) {
        self.params.get(k).map_or((f64::NAN, f64::NAN), |v| v[p])
    }

    /// Variance of `Σ (ŝ_k − s_k)` over `terms` (zone, arm µm: `y − yc`
    /// for x, `x − xc` for y): how uncertain a sum of fitted set-up terms
    /// is, µm².
    pub fn sum_variance(&self, terms: &[(usize, f64)]) -> f64 {
        let n = self.cov.nrows();
        let mut g = vec![0.0; n];
        for &(k, arm) in terms {
            if k == self.reference {
                continue;
            }
            let j = 2 * (k - usize::from(k > self.reference));
            if j + 1 < n {
                g[j] += 1.0;
                g[j + 1] += 1e-6 * arm;
            }
        }
        (0..n)
            .map(|i| (0..n).map(|j| g[i] * self.cov[(i, j)] * g[j]).sum::<f64>())
            .sum::<f64>()
            .max(0.0)
    }

    /// RMS of the residuals of the equations zone `k` takes part in, µm.
    pub fn zone_rms(&self, k: usize) -> f64 {
        let (ss, n) = self
            .residuals
            .iter()
            .zip(&self.pairs)
            .filter(|(_, &(a, b))| a == k || b == k)
            .fold((0.0, 0usize), |(s, n), (r, _)| (s + r * r, n + 1));
        if n == 0 {
            f64::NAN
        } else {
            (ss / n as f64).sqrt()
        }
    }
}

/// Name of parameter `p` of component `c`, and what the overlap needs to
/// determine it.
fn parameter(c: usize, p: usize) -> (&'static str, &'static str) {
    match (c, p) {
        (0, 0) => ("x offset", "to overlap another zone"),
        (1, 0) => ("y offset", "to overlap another zone"),
        (0, _) => ("d(ex)/dy slope", "nodes on at least two rows (distinct y)"),
        _ => (
            "d(ey)/dx slope",
            "nodes on at least two columns (distinct x)",
        ),
    }
}

impl Problem<'_> {
    /// Unknowns: two per zone but the reference.
    fn unknowns(&self) -> usize {
        2 * (self.centres.len() - 1)
    }

    /// Column of zone `k`'s parameter `p`; `None` for the reference.
    fn col(&self, k: usize, p: usize) -> Option<usize> {
        (k != self.reference).then(|| 2 * (k - usize::from(k > self.reference)) + p)
    }

    /// Zone of column `j`.
    fn zone_of(&self, j: usize) -> usize {
        let rank = j / 2;
        rank + usize::from(rank >= self.reference)
    }

    /// The row of equation `e` for component `c`: `(column, coefficient)`.
    fn row(&self, c: usize, e: &Equation) -> Vec<(usize, f64)> {
        let mut row = Vec::with_capacity(4);
        for (k, sign) in [(e.node, 1.0), (e.other, -1.0)] {
            let arm = if c == 0 {
                e.y_um - self.centres[k][1]
            } else {
                e.x_um - self.centres[k][0]
            };
            for (p, reg) in [(0, 1.0), (1, 1e-6 * arm)] {
                if let Some(j) = self.col(k, p) {
                    row.push((j, sign * reg));
                }
            }
        }
        row
    }

    /// Weighted normal equations of component `c` and the summed weights.
    fn normal(&self, c: usize) -> (DMatrix<f64>, DVector<f64>, f64) {
        let n = self.unknowns();
        let mut nm = DMatrix::zeros(n, n);
        let mut rhs = DVector::zeros(n);
        let mut wsum = 0.0;
        for e in self.eqs {
            let row = self.row(c, e);
            for &(i, a) in &row {
                for &(j, b) in &row {
                    nm[(i, j)] += e.weight * a * b;
                }
                rhs[i] += e.weight * a * e.d_um[c];
            }
            wsum += e.weight;
        }
        (nm, rhs, wsum)
    }

    /// The error naming column `j`'s zone and parameter.
    fn undetermined(&self, c: usize, j: usize) -> ZoneError {
        let (parameter, need) = parameter(c, j % 2);
        ZoneError::Undetermined {
            zone: self.names[self.zone_of(j)].to_owned(),
            parameter,
            need,
        }
    }

    /// Inverse of the normal matrix, or the parameter it cannot determine
    /// (the slope that weighs most in a null direction: once every zone is
    /// linked, only slopes can be free).
    fn inverse(&self, c: usize, nm: &DMatrix<f64>) -> Result<DMatrix<f64>, ZoneError> {
        let n = nm.nrows();
        if let Some(j) = (0..n).find(|&j| nm[(j, j)] <= 0.0 || !nm[(j, j)].is_finite()) {
            return Err(self.undetermined(c, j));
        }
        let d: Vec<f64> = (0..n).map(|j| 1.0 / nm[(j, j)].sqrt()).collect();
        let scaled = DMatrix::from_fn(n, n, |i, j| nm[(i, j)] * d[i] * d[j]);
        let numeric = || ZoneError::Numeric {
            component: if c == 0 { "x" } else { "y" },
        };
        if !scaled.iter().all(|v| v.is_finite()) {
            return Err(numeric());
        }
        let eig = scaled
            .try_symmetric_eigen(f64::EPSILON, 10_000)
            .ok_or_else(numeric)?;
        let lmax = eig.eigenvalues.iter().copied().fold(0.0, f64::max);
        if let Some(i) = (0..n).find(|&i| {
            eig.eigenvalues[i].partial_cmp(&(RANK_TOL * lmax)) != Some(std::cmp::Ordering::Greater)
        }) {
            let v = eig.eigenvectors.column(i);
            let j = (0..n)
                .filter(|j| j % 2 == 1)
                .max_by(|&a, &b| v[a].abs().total_cmp(&v[b].abs()))
                .unwrap_or(0);
            return Err(self.undetermined(c, j));
        }
        let inv_l = DMatrix::from_diagonal(&eig.eigenvalues.map(|l| 1.0 / l));
        let inv_scaled = &eig.eigenvectors * inv_l * eig.eigenvectors.transpose();
        Ok(DMatrix::from_fn(n, n, |i, j| {
            inv_scaled[(i, j)] * d[i] * d[j]
        }))
    }

    /// Fits component `c` (0: `ox`, `a`; 1: `oy`, `b`).
    pub fn solve(&self, c: usize) -> Result<ComponentFit, ZoneError> {
        let (nm, rhs, wsum) = self.normal(c);
        let inv = self.inverse(c, &nm)?;
        let theta = &inv * rhs;
        let n = self.unknowns();
        let dof = 2.0 * wsum - n as f64;
        if dof < 1.0 - 1e-9 {
            return Err(ZoneError::TooLittleOverlap {
                component: if c == 0 { "x" } else { "y" },
                equations: 2.0 * wsum,
                parameters: n,
            });
        }
        let residuals: Vec<f64> = self
            .eqs
            .iter()
            .map(|e| {
                let fit: f64 = self.row(c, e).iter().map(|&(j, a)| a * theta[j]).sum();
                e.d_um[c] - fit
            })
            .collect();
        let ss: f64 = residuals
            .iter()
            .zip(self.eqs)
            .map(|(r, e)| e.weight * r * r)
            .sum();
        let var = ss / dof;
        let params = (0..self.centres.len())
            .map(|k| {
                [0, 1].map(|p| {
                    // The slope's regressor is 1e-6 × arm (µm), so its
                    // coefficient is in µrad already.
                    self.col(k, p).map_or((0.0, 0.0), |j| {
                        (theta[j], (var * inv[(j, j)]).max(0.0).sqrt())
                    })
                })
            })
            .collect();
        Ok(ComponentFit {
            params,
            residuals,
            pairs: self.eqs.iter().map(|e| (e.node, e.other)).collect(),
            cov: inv * var,
            reference: self.reference,
            noise_um: var.sqrt(),
            dof,
        })
    }
}
