// The gradient over θ of the UKF log marginal likelihood (Theorem 1, eqs 10-12) by an adjoint
// (reverse) sweep.
//
// Forward sweep: the filter of the value kernel on one θ, in doubles, with the sigma points of
// a gap side by side (coordinate-major arrays of NP ≥ 2n+1 lanes, so that the loops over the
// points vectorise), recording on a tape per gap: every sigma point's positions at each force
// evaluation of the composition, the final momenta, the predicted mean m⁻, the update's
// S⁻¹, gain K = C S⁻¹ and a = S⁻¹ v, and the filtered factor L⁺.
//
// Reverse sweep, gap by gap from the last, with the adjoints m̄⁺ and P̄⁺ of the filtered state
// (zero after the last gap):
//   update (eqs 11-12), for log p = −½ vᵀS⁻¹v − ½ log det S and m⁺ = m⁻ + K v,
//   P⁺ = P⁻ − K Cᵀ:  v̄ = −a + Kᵀm̄⁺,  S̄ = ½(a aᵀ − S⁻¹) − sym(b aᵀ) + Kᵀ P̄⁺ K (b = Kᵀm̄⁺),
//   C̄ = m̄⁺aᵀ − 2 P̄⁺K;  then through ŷ = H m⁻, S = H P⁻Hᵀ + Γ, C = P⁻Hᵀ to m̄⁻, P̄⁻ and Γ̄;
//   moments (eq 10): Σ̄ = diag P̄⁻, D̄_k = 2 wc_k P̄⁻ D_k, Ȳ_k = D̄_k + wm_k (m̄⁻ − Σ_j D̄_j);
//   Ψ (eq 14) backwards substep by substep: a kick p −= κ ∇U(q) gives q̄ −= κ ∇²U(q) p̄ and
//   c̄_m −= κ p̄ · ∂∇U/∂c_m (both in closed form from the polynomial, eq 13), a drift
//   q += h M⁻¹p gives p̄ += h M⁻¹q̄;
//   sigma points: m̄ = Σ_k X̄_k, L̄ = scale (X̄₊ − X̄₋) (lower triangle), and the Cholesky
//   factorisation in reverse, P̄ = L⁻ᵀ ½(Φ(LᵀL̄) + Φ(LᵀL̄)ᵀ) L⁻¹ (Φ: the lower triangle with
//   half the diagonal), which are the previous gap's m̄⁺ and P̄⁺.
// x0 and P0 do not depend on θ: the sweep stops at the first gap's sigma points.
//
// Off the support it follows jax.grad of the JAX tier: a non-positive variance gives −∞ while
// the filter runs on |v| + 1e-12, and a filter that is not finite gives −∞; in both cases the
// gradient is 0 × (the gradient computed), which is zero where that is finite and NaN where not.

#include "ukf_adjoint.h"

#include <algorithm>
#include <cmath>
#include <limits>

namespace symplid {

namespace {

constexpr double kLog2Pi = 1.8378770664093454835606594728112;
constexpr int kPad = 8;  // lanes per point array are a multiple of this (a Vec)

#include "ukf_adjoint_update.h"

// Exponent vector e of the monomial Π q_i^e_i: its index among the program's monomials
// (degree ≥ 1), adding it and its parents where missing; −1 for degree 0.
int monomial(ForceProgram& f, std::vector<std::vector<int>>& exps, std::vector<int> e) {
  int degree = 0, first = -1;
  for (std::size_t i = 0; i < e.size(); ++i) {
    degree += e[i];
    if (e[i] > 0 && first < 0) first = static_cast<int>(i);
  }
  if (degree == 0) return -1;
  for (std::size_t k = 0; k < exps.size(); ++k) {
    if (exps[k] == e) return static_cast<int>(k);
  }
  std::vector<int> parent = e;
  parent[first] -= 1;
  const int pi = monomial(f, exps, parent);
  exps.push_back(e);
  f.mono_parent.push_back(pi);
  f.mono_coord.push_back(first);
  return static_cast<int>(exps.size()) - 1;
}

void build_program(const Settings& s, ForceProgram& f) {
  f = ForceProgram{};
#ifdef SYMPLID_USER_FORCE
  // A user's unit: term t is θ's parameter t (its adjoint accumulates in tacc, as a
  // coefficient's; the force and its derivatives are the unit's, Propagation's kicks).
  for (int m = 0; m < s.ncoef; ++m) {
    f.term_j.push_back(0);
    f.term_m.push_back(m);
    f.term_mult.push_back(1.0);
    f.term_mono.push_back(-1);
  }
  return;
#endif
  std::vector<std::vector<int>> exps;
  const int d = s.d;
  for (int j = 0; j < d; ++j) {
    for (int m = 0; m < s.ncoef; ++m) {
      std::vector<int> e(s.exponents + m * d, s.exponents + (m + 1) * d);
      if (e[j] == 0) continue;
      const double mult = e[j];
      e[j] -= 1;
      f.term_j.push_back(j);
      f.term_m.push_back(m);
      f.term_mult.push_back(mult);
      f.term_mono.push_back(monomial(f, exps, e));
    }
  }
  for (int i = 0; i < d; ++i) {
    for (int j = i; j < d; ++j) {
      for (int m = 0; m < s.ncoef; ++m) {
        std::vector<int> e(s.exponents + m * d, s.exponents + (m + 1) * d);
        if (e[i] == 0) continue;
        double mult = e[i];
        e[i] -= 1;
        if (e[j] == 0) continue;
        mult *= e[j];
        e[j] -= 1;
        f.hess_i.push_back(i);
        f.hess_j.push_back(j);
        f.hess_m.push_back(m);
        f.hess_mult.push_back(mult);
        f.hess_mono.push_back(monomial(f, exps, e));
      }
    }
  }
}


// Ψ over one gap for all points (q, p: d rows of NP lanes), recording q at every force
// evaluation in qs (S + 1 blocks of d·NP) — a composition, kick-drift-kick with the kicks
// between substeps merged, as the value kernel's CompositionMethod.
class Propagation {
 public:
  Propagation(const Settings& s, const Dims& z, const ForceProgram& f, FastPropagation fast,
              const double* tc, const double* hc, double* scratch)
      : s_(s), z_(z), f_(f), fast_(fast), tc_(tc), hc_(hc) {
    mono_ = scratch;
    force_ = mono_ + f.mono_parent.size() * z.NP;
    tmp_ = force_ + z.d * z.NP;
  }
  static std::size_t scratch_size(const Dims& z, const ForceProgram& f) {
    return (f.mono_parent.size() + 2 * z.d) * z.NP;
  }

  // The weights of the gap's substeps: drift h_s, then kick κ_s (κ before the first drift).
  static double drift(const Settings& s, double dt, int sub) { return s.comp_w[sub % s.ncomp] * dt; }
  static double kick(const Settings& s, double dt, int sub, int total) {
    // sub = −1: the first half kick; else the second half of substep sub and the first of
    // the next (none after the last)
    if (sub < 0) return 0.5 * drift(s, dt, 0);
    const double next = sub + 1 < total ? drift(s, dt, sub + 1) : 0.0;
    return 0.5 * drift(s, dt, sub) + 0.5 * next;
  }

  void forward(double dt, int steps, double* q, double* p, double* qs) {
    const int NP = z_.NP, dN = z_.d * z_.NP;
    if (fast_.forward != nullptr) return fast_.forward(s_, dt, steps, NP, q, p, qs, tc_);
    const int total = steps * s_.ncomp;
    std::copy(q, q + dN, qs);
    if (total == 0) return;
    kick_forward(q, p, kick(s_, dt, -1, total));
    for (int sub = 0; sub < total; ++sub) {
      const double h = drift(s_, dt, sub);
      const double* v = velocity(p, tmp_);
      for (int i = 0; i < dN; ++i) q[i] += h * v[i];
      std::copy(q, q + dN, qs + (sub + 1) * dN);
      kick_forward(q, p, kick(s_, dt, sub, total));
    }
    (void)NP;
  }

  // The adjoint of forward: qb, pb (d rows of NP) from the gap's end to its start; the
  // coefficients' adjoint accumulates per force term and lane in tacc.
  void reverse(double dt, int steps, const double* qs, double* qb, double* pb, double* tacc) {
    if (fast_.reverse != nullptr) return fast_.reverse(s_, dt, steps, z_.NP, qs, qb, pb, tc_, tacc);
    const int dN = z_.d * z_.NP;
    const int total = steps * s_.ncomp;
    if (total == 0) return;
    for (int sub = total - 1; sub >= 0; --sub) {
      kick_reverse(qs + (sub + 1) * dN, kick(s_, dt, sub, total), qb, pb, tacc);
      const double h = drift(s_, dt, sub);
      const double* v = velocity(qb, tmp_);
      for (int i = 0; i < dN; ++i) pb[i] += h * v[i];
    }
    kick_reverse(qs, kick(s_, dt, -1, total), qb, pb, tacc);
  }

 private:
  // M⁻¹ x (x itself without a mass matrix); M⁻¹ is symmetric.
  const double* velocity(const double* x, double* out) const {
    if (!s_.has_mass) return x;
    const int d = z_.d, NP = z_.NP;
    for (int i = 0; i < d; ++i) {
      for (int k = 0; k < NP; ++k) out[i * NP + k] = 0.0;
      for (int j = 0; j < d; ++j) {
        const double a = s_.inv_mass[i * d + j];
        for (int k = 0; k < NP; ++k) out[i * NP + k] += a * x[j * NP + k];
      }
    }
    return out;
  }

  void monomials(const double* q) {
    const int NP = z_.NP;
    const int count = static_cast<int>(f_.mono_parent.size());
    for (int c = 0; c < count; ++c) {
      double* out = mono_ + c * NP;
      const double* x = q + f_.mono_coord[c] * NP;
      const int parent = f_.mono_parent[c];
      if (parent < 0) {
        for (int k = 0; k < NP; ++k) out[k] = x[k];
      } else {
        const double* a = mono_ + parent * NP;
        for (int k = 0; k < NP; ++k) out[k] = a[k] * x[k];
      }
    }
  }

#ifdef SYMPLID_USER_FORCE
  // The kicks with a user's force (its unit's policy), eight lanes at a time: p −= κ ∇U(q);
  // reverse: q̄ −= κ ∇²U(q) p̄ and, per parameter t, tacc_t += κ p̄ · ∂∇U/∂θ_t.
  using Force = SYMPLID_USER_FORCE;
  static_assert(kPad == 8, "a lane block is one Vec");
  static void load(const double* x, Vec& v) { __builtin_memcpy(&v, x, sizeof(Vec)); }
  static void store(double* x, const Vec& v) { __builtin_memcpy(x, &v, sizeof(Vec)); }

  void kick_forward(const double* q, double* p, double kappa) {
    const int NP = z_.NP;
    const double* tc = tc_;
    for (int k = 0; k < NP; k += kPad) {
      Vec x[Force::D], f[Force::D], pk;
      for (int i = 0; i < Force::D; ++i) load(q + i * NP + k, x[i]);
      Force::template add<false>(x, [tc](int t) { return Vec{} + tc[t]; }, f);
      for (int i = 0; i < Force::D; ++i) {
        load(p + i * NP + k, pk);
        store(p + i * NP + k, pk - kappa * f[i]);
      }
    }
  }

  void kick_reverse(const double* q, double kappa, double* qb, const double* pb, double* tacc) {
    const int NP = z_.NP;
    const double* tc = tc_;
    for (int k = 0; k < NP; k += kPad) {
      Vec x[Force::D], v[Force::D], hv[Force::D], pg[Force::kTerms > 0 ? Force::kTerms : 1], a;
      for (int i = 0; i < Force::D; ++i) {
        load(q + i * NP + k, x[i]);
        load(pb + i * NP + k, v[i]);
      }
      Force::adjoint(x, [tc](int t) { return Vec{} + tc[t]; }, v, hv, pg);
      for (int i = 0; i < Force::D; ++i) {
        load(qb + i * NP + k, a);
        store(qb + i * NP + k, a - kappa * hv[i]);
      }
      for (int t = 0; t < Force::kTerms; ++t) {
        load(tacc + t * NP + k, a);
        store(tacc + t * NP + k, a + kappa * pg[t]);
      }
    }
  }
#else
  void kick_forward(const double* q, double* p, double kappa) {
    const int NP = z_.NP;
    monomials(q);
    std::fill(force_, force_ + z_.d * NP, 0.0);
    for (std::size_t t = 0; t < f_.term_j.size(); ++t) {
      double* out = force_ + f_.term_j[t] * NP;
      const double c = tc_[t];
      if (f_.term_mono[t] < 0) {
        for (int k = 0; k < NP; ++k) out[k] += c;
      } else {
        const double* mono = mono_ + f_.term_mono[t] * NP;
        for (int k = 0; k < NP; ++k) out[k] += c * mono[k];
      }
    }
    for (int i = 0; i < z_.d * NP; ++i) p[i] -= kappa * force_[i];
  }

  void kick_reverse(const double* q, double kappa, double* qb, const double* pb, double* tacc) {
    const int NP = z_.NP;
    monomials(q);
    for (std::size_t t = 0; t < f_.term_j.size(); ++t) {
      const double* pj = pb + f_.term_j[t] * NP;
      double* acc = tacc + t * NP;
      if (f_.term_mono[t] < 0) {
        for (int k = 0; k < NP; ++k) acc[k] += kappa * pj[k];
      } else {
        const double* mono = mono_ + f_.term_mono[t] * NP;
        for (int k = 0; k < NP; ++k) acc[k] += kappa * pj[k] * mono[k];
      }
    }
    for (std::size_t h = 0; h < f_.hess_i.size(); ++h) {
      const int i = f_.hess_i[h], j = f_.hess_j[h];
      const double c = kappa * hc_[h];
      const double* mono = f_.hess_mono[h] < 0 ? nullptr : mono_ + f_.hess_mono[h] * NP;
      for (int k = 0; k < NP; ++k) {
        const double w = mono ? c * mono[k] : c;
        qb[i * NP + k] -= w * pb[j * NP + k];
        if (i != j) qb[j * NP + k] -= w * pb[i * NP + k];
      }
    }
  }
#endif

  const Settings& s_;
  const Dims& z_;
  const ForceProgram& f_;
  FastPropagation fast_;
  const double* tc_;
  const double* hc_;
  double* mono_;
  double* force_;
  double* tmp_;
};

}  // namespace

bool adjoint_supports(const Settings& s) {
  return s.composition && !s.per_step && s.d >= 1 && s.dy >= 1;
}

namespace {

// The force program for this basis (rebuilt when the basis changes) and the fast propagation.
void prepare_program(const Settings& s, AdjointWorkspace& work) {
  const std::size_t ne = static_cast<std::size_t>(s.ncoef) * s.d;
  if (work.program_dim != s.d || work.program_exponents.size() != ne ||
      !std::equal(s.exponents, s.exponents + ne, work.program_exponents.begin())) {
    build_program(s, work.program);
    work.program_exponents.assign(s.exponents, s.exponents + ne);
    work.program_dim = s.d;
  }
  // (the fast path also depends on the mass matrix and the propagator: chosen every call)
#ifdef SYMPLID_USER_FORCE
  work.fast = FastPropagation{};  // a user's force: Propagation's kicks
#else
  work.fast = select_fast_propagation(s);
#endif
}

// Substeps per gap and each gap's place on the tape.
void layout_tape(const Settings& s, const Dims& z, const TrajectoryData& data,
                 AdjointWorkspace& work) {
  const int gaps = data.num_gaps;
  work.gap_offset.assign(gaps + 1, 0);
  work.steps.resize(gaps);
  for (int k = 0; k < gaps; ++k) {
    const int steps = s.uniform ? s.max_steps : static_cast<int>(data.num_steps[k]);
    work.steps[k] = std::max(0, std::min(steps, s.max_steps));
    work.gap_offset[k + 1] = work.gap_offset[k] + GapRecord::size(z, work.steps[k], s.ncomp);
  }
  work.tape.resize(work.gap_offset[gaps] + 1);
}

// The sigma points m, m ± scale·L[:, c] into x (n rows of NP lanes; padding lanes get m).
template <int NN>
void sigma_points(const Settings& s, const Dims& z, const double* mean, const double* chol,
                  double* x) {
  const int n = NN > 0 ? NN : z.n, NP = z.NP;
  for (int i = 0; i < n; ++i) {
    double* row = x + i * NP;
    for (int k = 0; k < NP; ++k) row[k] = mean[i];
    for (int c = 0; c < n; ++c) {
      const double spread = s.scale * chol[i * n + c];
      row[1 + c] = mean[i] + spread;
      row[1 + n + c] = mean[i] - spread;
    }
  }
}

// Their adjoint: m̄ = Σ_k X̄_k, L̄_ic = scale (X̄_i,1+c − X̄_i,1+n+c) on and below the diagonal.
template <int NN>
void sigma_points_reverse(const Settings& s, const Dims& z, const double* xb, double* mbar,
                          double* lbar) {
  const int n = NN > 0 ? NN : z.n, NP = z.NP, npts = 2 * n + 1;
  for (int i = 0; i < n; ++i) {
    const double* row = xb + i * NP;
    double sum = 0.0;
    for (int k = 0; k < npts; ++k) sum += row[k];
    mbar[i] = sum;
    for (int c = 0; c < n; ++c) lbar[i * n + c] = c <= i ? s.scale * (row[1 + c] - row[1 + n + c]) : 0.0;
  }
}

// Predicted moments, eq (10), of the propagated points x: mean, centred points, covariance
// with Σ and the jitter on the diagonal.
template <int NN>
void moments(const Settings& s, const Dims& z, const double* x, const double* process_var,
             double* mean, double* centred, double* cov) {
  const int n = NN > 0 ? NN : z.n, NP = z.NP, npts = 2 * n + 1;
  for (int i = 0; i < n; ++i) {
    const double* row = x + i * NP;
    double sum = 0.0;
    for (int k = 0; k < npts; ++k) sum += s.wm[k] * row[k];
    mean[i] = sum;
    for (int k = 0; k < npts; ++k) centred[i * NP + k] = row[k] - sum;
  }
  for (int i = 0; i < n; ++i) {
    for (int j = 0; j <= i; ++j) {
      double sum = 0.0;
      for (int k = 0; k < npts; ++k) sum += s.wc[k] * centred[i * NP + k] * centred[j * NP + k];
      cov[i * n + j] = sum;
      cov[j * n + i] = sum;
    }
    cov[i * n + i] += process_var[i] + s.jitter;
  }
}

// Their adjoint into xb (the points' adjoint): Ȳ_k = D̄_k + wm_k (m̄⁻ − Σ_j D̄_j) with
// D̄_k = 2 wc_k P̄⁻ D_k, the centred points D recomputed from the record.
template <int NN>
void moments_reverse(const Settings& s, const Dims& z, const GapRecord& rec, int steps,
                     const double* pbar, const double* mbar, double* centred, double* xb) {
  const int n = NN > 0 ? NN : z.n, d = n / 2, NP = z.NP, npts = 2 * n + 1;
  const double* qend = rec.qs + static_cast<std::size_t>(steps) * s.ncomp * d * NP;
  for (int i = 0; i < n; ++i) {
    const double* row = i < d ? qend + i * NP : rec.pend + (i - d) * NP;
    for (int k = 0; k < npts; ++k) centred[i * NP + k] = row[k] - rec.mpred[i];
  }
  for (int i = 0; i < n; ++i) {
    double* out = xb + i * NP;
    double dsum = 0.0;
    for (int k = 0; k < NP; ++k) out[k] = 0.0;
    for (int k = 0; k < npts; ++k) {
      double sum = 0.0;
      for (int j = 0; j < n; ++j) sum += pbar[i * n + j] * centred[j * NP + k];
      out[k] = 2.0 * s.wc[k] * sum;
      dsum += out[k];
    }
    for (int k = 0; k < npts; ++k) out[k] += s.wm[k] * (mbar[i] - dsum);
  }
}

// ∂ log L/∂θ from the adjoints: the coefficients' from the force terms' accumulators (summed
// over the points), the variances' from Σ̄ and Γ̄; off the support (not ok) 0 × that, which is
// zero where it is finite and NaN where not (jax.grad of the JAX tier's −∞ branch).
void assemble_gradient(const Settings& s, const Dims& z, const ForceProgram& f,
                       const double* tacc, const double* process_bar, const double* obs_bar,
                       bool ok, double* grad) {
  const int nc = z.nc, first_obs = nc + (s.diagonal ? z.n : 1);
  for (int v = 0; v < s.nparams; ++v) grad[v] = 0.0;
  for (std::size_t t = 0; t < f.term_j.size(); ++t) {
    double sum = 0.0;
    for (int k = 0; k < z.npts; ++k) sum += tacc[t * z.NP + k];
    grad[f.term_m[t]] -= f.term_mult[t] * sum;
  }
  for (int i = 0; i < z.n; ++i) grad[nc + (s.diagonal ? i : 0)] += process_bar[i];
  for (int r = 0; r < z.dy; ++r) grad[first_obs + (s.diagonal ? r : 0)] += obs_bar[r];
  if (!ok) {
    for (int v = 0; v < s.nparams; ++v) grad[v] *= 0.0;
  }
}

// adjoint_gradient for a state of NN and observations of DY components (0: at run time).
template <int NN, int DY>
void run_sized(const Settings& s, const TrajectoryData& data, const Member& member, double* grad,
               AdjointWorkspace& work) {
  Dims z{s.d, s.n, s.dy, s.npts, (s.npts + kPad - 1) / kPad * kPad, s.ncoef};
  const int n = NN > 0 ? NN : z.n, d = n / 2, dy = DY > 0 ? DY : z.dy;
  const int NP = z.NP, nc = z.nc;
  prepare_program(s, work);
  const ForceProgram& f = work.program;
  const int nt = static_cast<int>(f.term_j.size()), nh = static_cast<int>(f.hess_i.size());
  const double* theta = member.theta;

  // Variances: non-positive ones are replaced by |v| + 1e-12 (the value is −∞ anyway).
  bool valid = true;
  for (int v = nc; v < s.nparams; ++v) valid = valid && theta[v] > 0.0;
  auto variance = [&](int v) { return theta[v] > 0.0 ? theta[v] : std::fabs(theta[v]) + 1e-12; };

  layout_tape(s, z, data, work);
  const int gaps = data.num_gaps;
  const std::vector<int>& steps_of = work.steps;

  // Scratch: per-lane arrays, small matrices, the coefficients and variances.
  const std::size_t prop_size = Propagation::scratch_size(z, f);
  const std::size_t lanes = 2 * static_cast<std::size_t>(d) * NP;  // q, p (or q̄, p̄)
  const std::size_t mats = 8 * static_cast<std::size_t>(n + dy + 1) * (n + dy + 1);
  work.scratch.assign(prop_size + 2 * lanes + n * NP + nt * NP + mats + nt + nh + 3 * n + 2 * n +
                          2 * dy + nc,
                      0.0);
  double* prop_scratch = work.scratch.data();
  double* x = prop_scratch + prop_size;  // q then p, d x NP each
  double* xb = x + lanes;                // q̄ then p̄
  double* centred = xb + lanes;          // n x NP
  double* tacc = centred + n * NP;       // nt x NP
  double* mat = tacc + nt * NP;          // matrices
  double* tc = mat + mats;               // nt
  double* hc = tc + nt;                  // nh
  double* mean = hc + nh;                // n
  double* mbar = mean + n;               // n
  double* process_var = mbar + n;        // n
  double* process_bar = process_var + n; // n
  double* obs_var = process_bar + n;     // dy
  double* obs_bar = obs_var + dy;        // dy
  for (int t = 0; t < nt; ++t) tc[t] = theta[f.term_m[t]] * f.term_mult[t];
  for (int h = 0; h < nh; ++h) hc[h] = theta[f.hess_m[h]] * f.hess_mult[h];
  const int first_obs = nc + (s.diagonal ? n : 1);
  for (int i = 0; i < n; ++i) process_var[i] = variance(nc + (s.diagonal ? i : 0));
  for (int r = 0; r < dy; ++r) obs_var[r] = variance(first_obs + (s.diagonal ? r : 0));
  double* cov = mat;             // n x n
  double* chol = cov + n * n;    // n x n
  double* pbar = chol + n * n;   // n x n
  double* tmp = pbar + n * n;    // the rest
  Propagation prop(s, z, f, work.fast, tc, hc, prop_scratch);
  double* q = x;
  double* p = x + d * NP;

  // Forward sweep.
  for (int i = 0; i < n; ++i) mean[i] = member.x0[i];
  for (int i = 0; i < n; ++i) {
    for (int k = 0; k < n; ++k) cov[i * n + k] = 0.5 * (member.P0[i * n + k] + member.P0[k * n + i]);
  }
  cholesky<NN>(cov, chol, n);
  double total = 0.0;
  const double* lprev = chol;
  for (int g = 0; g < gaps; ++g) {
    GapRecord rec(work.tape.data() + work.gap_offset[g], z, steps_of[g], s.ncomp);
    sigma_points<NN>(s, z, mean, lprev, x);
    prop.forward(data.step_size[g], steps_of[g], q, p, rec.qs);
    std::copy(p, p + d * NP, rec.pend);
    moments<NN>(s, z, x, process_var, mean, centred, cov);
    total += update_forward<NN, DY>(s, z, data.ys + g * dy, data.masks + g * dy, obs_var, mean,
                                    cov, rec, tmp);
    lprev = rec.lpost;
  }
  const bool ok = valid && std::isfinite(total);
  *member.out = ok ? total : -std::numeric_limits<double>::infinity();

  // Reverse sweep.
  for (int i = 0; i < n; ++i) mbar[i] = 0.0;
  for (int i = 0; i < n * n; ++i) pbar[i] = 0.0;
  double* qb = xb;
  double* pb = xb + d * NP;
  for (int g = gaps - 1; g >= 0; --g) {
    GapRecord rec(work.tape.data() + work.gap_offset[g], z, steps_of[g], s.ncomp);
    update_reverse_for<NN, DY>(s, z, rec, mbar, pbar, obs_bar, tmp);
    for (int i = 0; i < n; ++i) process_bar[i] += pbar[i * n + i];
    moments_reverse<NN>(s, z, rec, steps_of[g], pbar, mbar, centred, xb);
    prop.reverse(data.step_size[g], steps_of[g], rec.qs, qb, pb, tacc);
    if (g == 0) break;  // x0 and P0 do not depend on θ
    double* lbar = tmp;
    sigma_points_reverse<NN>(s, z, xb, mbar, lbar);
    GapRecord prev(work.tape.data() + work.gap_offset[g - 1], z, steps_of[g - 1], s.ncomp);
    cholesky_reverse<NN>(prev.lpost, lbar, pbar, tmp + n * n, n);
  }

  assemble_gradient(s, z, f, tacc, process_bar, obs_bar, ok, grad);
}

}  // namespace

namespace {
// Whether the state size NN is compiled: all of them, or in a user's unit its force's only.
template <int NN>
constexpr bool compiles_state() {
#ifdef SYMPLID_USER_FORCE
  return NN == 2 * SYMPLID_USER_FORCE::D;
#else
  return true;
#endif
}
}  // namespace

void adjoint_gradient(const Settings& s, const TrajectoryData& data, const Member& member,
                      double* grad, AdjointWorkspace& work) {
  if constexpr (compiles_state<4>()) {
    if (s.n == 4 && s.dy == 4) return run_sized<4, 4>(s, data, member, grad, work);
    if (s.n == 4 && s.dy == 2) return run_sized<4, 2>(s, data, member, grad, work);
  }
  if constexpr (compiles_state<2>()) {
    if (s.n == 2 && s.dy == 2) return run_sized<2, 2>(s, data, member, grad, work);
    if (s.n == 2 && s.dy == 1) return run_sized<2, 1>(s, data, member, grad, work);
  }
  if constexpr (compiles_state<6>()) {
    if (s.n == 6 && s.dy == 6) return run_sized<6, 6>(s, data, member, grad, work);
    if (s.n == 6 && s.dy == 3) return run_sized<6, 3>(s, data, member, grad, work);
  }
  run_sized<0, 0>(s, data, member, grad, work);
}

}  // namespace symplid
