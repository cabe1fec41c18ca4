//! Per-tick work of the delay-aware identification, written the way the core
//! would hold it (fixed-size arrays, no allocation), to count instructions:
//! the history ring, the delay search's accumulators on the coarse (31 x 31)
//! and fine (21 x 21) grids, the evaluation of a few pairs' 3x3 normal
//! equations per tick (round robin), and one 6-state linear Kalman filter
//! (the delay-aware stage 1 at the chosen delays).
//!
//! `partner_delay_cost <work> <ticks>`, work one of `ring`, `coarse`, `fine`,
//! `eval`, `kf`, `gains_tick` (ring + coarse + eval + kf), `fine_tick`.
use std::hint::black_box;

const CAP: usize = 512;

/// The measured samples `[x_m - tau, v_m, x_m - tau_h, x_m]` of the last `CAP` ticks.
struct Ring {
    buf: [[f64; 4]; CAP],
    head: usize,
}

impl Ring {
    fn push(&mut self, y: [f64; 4]) {
        self.head = (self.head + 1) % CAP;
        self.buf[self.head] = y;
    }
    /// The sample `d` ticks ago (`d < CAP`).
    fn ago(&self, d: usize) -> &[f64; 4] {
        &self.buf[(self.head + CAP - d) % CAP]
    }
}

/// Lower Cholesky factor of a 3x3 symmetric matrix; `None` unless positive definite.
fn chol3(a: &[[f64; 3]; 3]) -> Option<[[f64; 3]; 3]> {
    let mut l = [[0.0f64; 3]; 3];
    for c in 0..3 {
        let mut d = a[c][c];
        for k in 0..c {
            d -= l[c][k] * l[c][k];
        }
        if !(d > 0.0) {
            return None;
        }
        l[c][c] = d.sqrt();
        for r in c + 1..3 {
            let mut t = a[r][c];
            for k in 0..c {
                t -= l[r][k] * l[c][k];
            }
            l[r][c] = t / l[c][c];
        }
    }
    Some(l)
}

/// Running sums of the least-squares fit of every pair `dv[i] x dp[j]`.
struct PairGrid<const KV: usize, const KP: usize> {
    dv: [usize; KV],
    dp: [usize; KP],
    /// A11, A13, A33, b1, b3 per dv.
    s_v: [[f64; KV]; 5],
    /// A22, b2 per dp.
    s_p: [[f64; KP]; 2],
    a12: [[f64; KP]; KV],
    a23: [[f64; KP]; KV],
    rr: f64,
    n: u64,
}

impl<const KV: usize, const KP: usize> PairGrid<KV, KP> {
    fn new(dv0: usize, dp0: usize, step: usize) -> Self {
        PairGrid {
            dv: core::array::from_fn(|i| dv0 + i * step),
            dp: core::array::from_fn(|j| dp0 + j * step),
            s_v: [[0.0; KV]; 5],
            s_p: [[0.0; KP]; 2],
            a12: [[0.0; KP]; KV],
            a23: [[0.0; KP]; KV],
            rr: 0.0,
            n: 0,
        }
    }

    /// One residual `r` (weight `w`) whose regressors end one tick ago.
    fn add(&mut self, ring: &Ring, r: f64, w: f64) {
        let sw = w.sqrt();
        let m = -r * sw;
        let mut e = [0.0; KV];
        let mut eh = [0.0; KV];
        let mut v = [0.0; KP];
        for i in 0..KV {
            let y = ring.ago(1 + self.dv[i]);
            e[i] = y[0] * sw;
            eh[i] = y[2] * sw;
        }
        for j in 0..KP {
            v[j] = ring.ago(1 + self.dp[j])[1] * sw;
        }
        for i in 0..KV {
            self.s_v[0][i] += e[i] * e[i];
            self.s_v[1][i] += e[i] * eh[i];
            self.s_v[2][i] += eh[i] * eh[i];
            self.s_v[3][i] += e[i] * m;
            self.s_v[4][i] += eh[i] * m;
        }
        for j in 0..KP {
            self.s_p[0][j] += v[j] * v[j];
            self.s_p[1][j] += v[j] * m;
        }
        for i in 0..KV {
            let (ei, ehi) = (e[i], eh[i]);
            let (a12, a23) = (&mut self.a12[i], &mut self.a23[i]);
            for j in 0..KP {
                a12[j] += ei * v[j];
                a23[j] += v[j] * ehi;
            }
        }
        self.rr += m * m;
        self.n += 1;
    }

    /// `(l, L)` of pair `(i, j)`: Cholesky solve of the 3x3 normal equations;
    /// `None` when they are not positive definite (that pair is skipped).
    fn eval(&self, i: usize, j: usize) -> Option<(f64, [f64; 3])> {
        let a = [
            [self.s_v[0][i], self.a12[i][j], self.s_v[1][i]],
            [self.a12[i][j], self.s_p[0][j], self.a23[i][j]],
            [self.s_v[1][i], self.a23[i][j], self.s_v[2][i]],
        ];
        let b = [self.s_v[3][i], self.s_p[1][j], self.s_v[4][i]];
        let l = chol3(&a)?;
        let mut z = [0.0; 3];
        for r in 0..3 {
            let mut s = b[r];
            for k in 0..r {
                s -= l[r][k] * z[k];
            }
            z[r] = s / l[r][r];
        }
        let explained: f64 = z.iter().map(|x| x * x).sum();
        let mut g = [0.0; 3];
        for r in (0..3).rev() {
            let mut s = z[r];
            for k in r + 1..3 {
                s -= l[k][r] * g[k];
            }
            g[r] = s / l[r][r];
        }
        let rss = (self.rr - explained).max(1e-300);
        let n = self.n.max(1) as f64;
        Some((-0.5 * n * (rss / n).ln(), g))
    }
}

/// The delay-aware stage 1: `z' = F z + b`, `P' = F P F' + Q` with `F` the
/// identity but for rows 0..2 (columns 1 and 3..5), then the update with
/// `H = [I3 0]`.
struct DelayedKf {
    x: [f64; 6],
    p: [[f64; 6]; 6],
    q: [f64; 6],
    r: [f64; 3],
    dx_f: f64,
    v_f: f64,
    dt: f64,
}

impl DelayedKf {
    fn predict(&mut self, phi: [f64; 3], u: f64, dtau: f64, dtau_h: f64) {
        // F rows 0..2: e' = e + dt v - dx_f phi.L ; v' = v - v_f phi.L ; eh' = eh + dt v - dx_f phi.L
        let coef = [self.dx_f, self.v_f, self.dx_f];
        let vcol = [self.dt, 1.0, self.dt];
        let mut f = [[0.0; 6]; 3];
        for r in 0..3 {
            f[r][r] = 1.0;
            if r == 1 {
                f[r][1] = 1.0;
            } else {
                f[r][1] = vcol[r];
            }
            for c in 0..3 {
                f[r][3 + c] = -coef[r] * phi[c];
            }
        }
        let ph = phi[0] * self.x[3] + phi[1] * self.x[4] + phi[2] * self.x[5];
        let x = self.x;
        for r in 0..3 {
            let mut s = 0.0;
            for c in 0..6 {
                s += f[r][c] * x[c];
            }
            self.x[r] = s;
        }
        let _ = ph;
        self.x[0] += self.dx_f * u - dtau;
        self.x[1] += self.v_f * u;
        self.x[2] += self.dx_f * u - dtau_h;
        // FP for the moving rows; P rows 3..5 unchanged.
        let mut fp = [[0.0; 6]; 3];
        for r in 0..3 {
            for c in 0..6 {
                let mut s = 0.0;
                for k in 0..6 {
                    s += f[r][k] * self.p[k][c];
                }
                fp[r][c] = s;
            }
        }
        let mut np = self.p;
        for r in 0..3 {
            for c in 0..6 {
                if c < 3 {
                    let mut s = 0.0;
                    for k in 0..6 {
                        s += fp[r][k] * f[c][k];
                    }
                    np[r][c] = s;
                } else {
                    np[r][c] = fp[r][c];
                }
                np[c][r] = np[r][c];
            }
        }
        for d in 0..6 {
            np[d][d] += self.q[d];
        }
        self.p = np;
    }

    fn update(&mut self, y: [f64; 3]) -> Option<f64> {
        let mut s = [[0.0; 3]; 3];
        for r in 0..3 {
            for c in 0..3 {
                s[r][c] = self.p[r][c];
            }
            s[r][r] += self.r[r];
        }
        let l = chol3(&s)?;
        let nu = [y[0] - self.x[0], y[1] - self.x[1], y[2] - self.x[2]];
        // K' = S^-1 (P H')' : solve for each of the 6 states
        let mut k = [[0.0; 3]; 6];
        for st in 0..6 {
            let mut z = [0.0; 3];
            for r in 0..3 {
                let mut t = self.p[st][r];
                for q in 0..r {
                    t -= l[r][q] * z[q];
                }
                z[r] = t / l[r][r];
            }
            for r in (0..3).rev() {
                let mut t = z[r];
                for q in r + 1..3 {
                    t -= l[q][r] * k[st][q];
                }
                k[st][r] = t / l[r][r];
            }
        }
        for st in 0..6 {
            self.x[st] += k[st][0] * nu[0] + k[st][1] * nu[1] + k[st][2] * nu[2];
        }
        let ph = self.p;
        for r in 0..6 {
            for c in r..6 {
                let v =
                    self.p[r][c] - (k[r][0] * ph[0][c] + k[r][1] * ph[1][c] + k[r][2] * ph[2][c]);
                self.p[r][c] = v;
                self.p[c][r] = v;
            }
        }
        // innovation log-likelihood (for the log; 3 logs)
        let mut w = [0.0; 3];
        for r in 0..3 {
            let mut t = nu[r];
            for q in 0..r {
                t -= l[r][q] * w[q];
            }
            w[r] = t / l[r][r];
        }
        Some(-0.5 * (w[0] * w[0] + w[1] * w[1] + w[2] * w[2]) - (l[0][0] * l[1][1] * l[2][2]).ln())
    }
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let work = args
        .get(1)
        .map(String::as_str)
        .unwrap_or("gains_tick")
        .to_string();
    let ticks: usize = args.get(2).and_then(|s| s.parse().ok()).unwrap_or(1000);
    let mut ring = Box::new(Ring {
        buf: [[0.0; 4]; CAP],
        head: 0,
    });
    let mut coarse = Box::new(PairGrid::<31, 31>::new(0, 0, 10));
    let mut fine = Box::new(PairGrid::<21, 21>::new(90, 30, 1));
    let mut kf = DelayedKf {
        x: [0.0; 6],
        p: core::array::from_fn(|i| core::array::from_fn(|j| if i == j { 1.0 } else { 0.0 })),
        q: [1e-2, 1e-2, 1e-2, 1e-6, 1e-6, 1e-6],
        r: [1e-7; 3],
        dx_f: 0.5e-6 / 0.0035,
        v_f: 1e-3 / 0.0035,
        dt: 1e-3,
    };
    let mut acc = 0.0;
    let mut cursor = 0usize;
    // Sums with data in them, so the evaluation does the whole solve.
    for t in 0..400 {
        let tt = t as f64 * 1e-3;
        ring.push([
            (tt * 3.0).sin(),
            (tt * 5.0).cos() * 10.0,
            (tt * 2.0).sin(),
            tt,
        ]);
        coarse.add(&ring, (tt * 7.0).sin(), 1.0);
        fine.add(&ring, (tt * 7.0).sin(), 1.0);
    }
    for t in 0..ticks {
        let tt = t as f64 * 1e-3;
        let y = [
            (tt * 3.0).sin(),
            (tt * 5.0).cos() * 10.0,
            (tt * 2.0).sin(),
            tt,
        ];
        let r = black_box((tt * 7.0).sin());
        match work.as_str() {
            "ring" => ring.push(black_box(y)),
            "coarse" => {
                ring.push(y);
                coarse.add(&ring, r, 1.0)
            }
            "fine" => {
                ring.push(y);
                fine.add(&ring, r, 1.1)
            }
            "eval" => {
                for _ in 0..8 {
                    let (i, j) = (cursor / 31 % 31, cursor % 31);
                    cursor += 1;
                    if let Some((l, g)) = coarse.eval(i, j) {
                        acc += l + g[0];
                    }
                }
            }
            "kf" => {
                kf.predict([y[0], y[1], y[2]], r, 1e-3, 1e-3);
                acc += kf.update([y[0], y[1], y[2]]).unwrap_or(0.0);
            }
            "gains_tick" | "fine_tick" => {
                ring.push(y);
                let ki = if work == "gains_tick" { 31 } else { 21 };
                if work == "gains_tick" {
                    coarse.add(&ring, r, 1.0);
                } else {
                    fine.add(&ring, r, 1.1);
                }
                for _ in 0..8 {
                    let (i, j) = (cursor / ki % ki, cursor % ki);
                    cursor += 1;
                    let e = if work == "gains_tick" {
                        coarse.eval(i, j)
                    } else {
                        fine.eval(i, j)
                    };
                    if let Some((l, g)) = e {
                        acc += l + g[0];
                    }
                }
                let d = ring.ago(37);
                let p = ring.ago(12);
                kf.predict([d[0], p[1], d[2]], r, 1e-3, 1e-3);
                acc += kf.update([y[0], y[1], y[2]]).unwrap_or(0.0);
            }
            _ => panic!("unknown work {work}"),
        }
    }
    black_box((&coarse, &fine, &kf.x));
    println!("{work} {ticks} {acc}");
}
