// The UKF log marginal likelihood (Theorem 1, eqs 10-12) of a polynomial Hamiltonian model,
// compiled for one instruction set.
//
// This file is included several times by ukf_kernel.cc, once per instruction set, each time
// inside a `#pragma GCC target(...)` region and with SYMPLID_ISA_NS naming the namespace. It
// therefore has no include guard and includes nothing itself: the types it uses (Settings,
// TrajectoryData, Member) and the standard headers come from ukf_kernel.cc.
//
// Layout. A "lane" is one sigma point of one parameter vector θ; lanes come in vectors of
// eight (Vec). One θ puts its 2n+1 sigma points in consecutive lanes (the last vector padded);
// a group of eight θ that share the data puts sigma point k of member g in lane 8k + g, so
// each vector is one sigma point of the eight. Arrays over lanes are coordinate-major,
// x[i * C + c] for C vectors per coordinate; C is a compile-time constant for common sizes.
//
// Every formula follows the JAX reference operation for operation (same association of
// products and sums), so the two agree to rounding.

namespace symplid {
namespace SYMPLID_ISA_NS {

constexpr int kWidth = 8;  // lanes per Vec

template <int N>
struct FixedChunks {
  static constexpr int count() { return N; }
};

struct RuntimeChunks {
  int n;
  int count() const { return n; }
};

// ---------------------------------------------------------------- force for small d and ℓ
// For d ≤ 3 and ℓ ≤ 5 the force's term program is built at compile time, so the gradient is
// straight-line code with the lanes in registers. The table is the library's basis order
// (by degree, then the first coordinate's power highest), and it is only used after checking
// that it equals the runtime program (see Propagator's constructor).

template <int D, int ORDER>
struct FixedBasis {
  static constexpr int binomial(int n, int k) {
    int r = 1;
    for (int i = 1; i <= k; ++i) r = r * (n - k + i) / i;
    return r;
  }
  static constexpr int kCoef = binomial(D + ORDER, D) - 1;
  static constexpr int kMaxTerms = D * kCoef;

  struct Table {
    int exps[kCoef][D] = {};
    int start[D + 1] = {};
    int coef_index[kMaxTerms] = {};
    int mult[kMaxTerms] = {};
    int num_factors[kMaxTerms] = {};
    int factor_coord[kMaxTerms][ORDER] = {};
    int factor_power[kMaxTerms][ORDER] = {};
  };

  static constexpr Table table() {
    Table t{};
    int m = 0;
    int e[3] = {0, 0, 0};
    for (int degree = 1; degree <= ORDER; ++degree) {
      for (e[0] = degree; e[0] >= 0; --e[0]) {
        if (D == 1) {
          if (e[0] != degree) continue;
          t.exps[m][0] = e[0];
          ++m;
          continue;
        }
        for (e[1] = degree - e[0]; e[1] >= 0; --e[1]) {
          if (D == 2) {
            if (e[0] + e[1] != degree) continue;
          } else {
            e[2] = degree - e[0] - e[1];
          }
          for (int i = 0; i < D; ++i) t.exps[m][i] = e[i];
          ++m;
        }
      }
    }
    int term = 0;
    for (int j = 0; j < D; ++j) {
      t.start[j] = term;
      for (int c = 0; c < kCoef; ++c) {
        if (t.exps[c][j] == 0) continue;
        t.coef_index[term] = c;
        t.mult[term] = t.exps[c][j];
        int nf = 0;
        for (int i = 0; i < D; ++i) {
          const int power = t.exps[c][i] - (i == j ? 1 : 0);
          if (power > 0) {
            t.factor_coord[term][nf] = i;
            t.factor_power[term][nf] = power;
            ++nf;
          }
        }
        t.num_factors[term] = nf;
        ++term;
      }
    }
    t.start[D] = term;
    return t;
  }

  static constexpr Table kTable = table();

  // True when the runtime program (from the model's exponents) is this table.
  static bool matches(const Settings& s) {
    if (s.d != D || s.order != ORDER || s.ncoef != kCoef || s.num_terms != kTable.start[D]) {
      return false;
    }
    for (int c = 0; c < kCoef; ++c) {
      for (int i = 0; i < D; ++i) {
        if (s.exponents[c * D + i] != kTable.exps[c][i]) return false;
      }
    }
    return true;
  }

  // ∂U/∂q at x into out (d x C vectors each); tc holds c_m e_mj per term.
  template <int C>
  static void gradient(const Vec* __restrict__ x, Vec* __restrict__ out,
                       const Vec* __restrict__ tc) {
    Vec pw[D][ORDER + 1][C];
#pragma GCC unroll 16
    for (int i = 0; i < D; ++i) {
#pragma GCC unroll 16
      for (int c = 0; c < C; ++c) {
        pw[i][1][c] = x[i * C + c];
#pragma GCC unroll 16
        for (int k = 2; k <= ORDER; ++k) pw[i][k][c] = pw[i][k - 1][c] * x[i * C + c];
      }
    }
#pragma GCC unroll 16
    for (int j = 0; j < D; ++j) {
      Vec acc[C];
#pragma GCC unroll 16
      for (int c = 0; c < C; ++c) acc[c] = Vec{};
#pragma GCC unroll 128
      for (int t = kTable.start[j]; t < kTable.start[j + 1]; ++t) {
#pragma GCC unroll 16
        for (int c = 0; c < C; ++c) {
          Vec v = tc[t];
#pragma GCC unroll 8
          for (int f = 0; f < kTable.num_factors[t]; ++f) {
            v = v * pw[kTable.factor_coord[t][f]][kTable.factor_power[t][f]][c];
          }
          acc[c] = acc[c] + v;
        }
      }
#pragma GCC unroll 16
      for (int c = 0; c < C; ++c) out[j * C + c] = acc[c];
    }
  }
};

using GradientFn = void (*)(const Vec*, Vec*, const Vec*);

// The compile-time force for C vectors per coordinate, or nullptr (then the generic one).
template <int C>
GradientFn fixed_gradient(const Settings& s) {
#define SYMPLID_TRY_BASIS(D, ORDER) \
  if (FixedBasis<D, ORDER>::matches(s)) return &FixedBasis<D, ORDER>::template gradient<C>;
  if (s.d == 1 && (C == 1 || C == 5)) {
    SYMPLID_TRY_BASIS(1, 2) SYMPLID_TRY_BASIS(1, 3) SYMPLID_TRY_BASIS(1, 4) SYMPLID_TRY_BASIS(1, 5)
  }
  if (s.d == 2 && (C == 2 || C == 9)) {
    SYMPLID_TRY_BASIS(2, 2) SYMPLID_TRY_BASIS(2, 3) SYMPLID_TRY_BASIS(2, 4) SYMPLID_TRY_BASIS(2, 5)
  }
  if (s.d == 3 && (C == 2 || C == 13)) {
    SYMPLID_TRY_BASIS(3, 2) SYMPLID_TRY_BASIS(3, 3) SYMPLID_TRY_BASIS(3, 4) SYMPLID_TRY_BASIS(3, 5)
  }
#undef SYMPLID_TRY_BASIS
  return nullptr;
}

template <class Chunks>
GradientFn select_gradient(const Settings&) {
  return nullptr;
}
template <>
GradientFn select_gradient<FixedChunks<1>>(const Settings& s) { return fixed_gradient<1>(s); }
template <>
GradientFn select_gradient<FixedChunks<2>>(const Settings& s) { return fixed_gradient<2>(s); }
template <>
GradientFn select_gradient<FixedChunks<5>>(const Settings& s) { return fixed_gradient<5>(s); }
template <>
GradientFn select_gradient<FixedChunks<9>>(const Settings& s) { return fixed_gradient<9>(s); }
template <>
GradientFn select_gradient<FixedChunks<13>>(const Settings& s) { return fixed_gradient<13>(s); }

// The lane-parallel part: the polynomial force and the integrators (eqs 5-6 and eq 14).
// State arrays hold d rows of `chunks` vectors each: x[i * C + c].
template <class Chunks>
class Propagator {
 public:
  Propagator(const Settings& s, Chunks chunks, Vec* work) : s_(s), chunks_(chunks) {
    const int C = chunks_.count();
    const int d = s.d;
    q = take(work, d * C);
    p = take(work, d * C);
    term_coef = take(work, s.num_terms);
    force_ = take(work, d * C);
    force_next_ = take(work, d * C);
    powers_ = take(work, d * (s.order + 1) * C);
    vel_a_ = take(work, d * C);
    vel_b_ = take(work, d * C);
    stage_q_ = take(work, d * C);
    stage_p_ = take(work, d * C);
    kq_ = take(work, s.stages * d * C);
    kp_ = take(work, s.stages * d * C);
    fixed_gradient_ = select_gradient<Chunks>(s);
  }

  // Vectors of workspace the constructor takes.
  static std::size_t workspace(const Settings& s, int C) {
    return static_cast<std::size_t>(C) * (8 * s.d + s.d * (s.order + 1) + 2 * s.stages * s.d) +
           s.num_terms;
  }

  // Ψ over one gap, eq (14): `steps` steps of size `dt` from the state in (q, p).
  void advance(double dt, int steps) {
    if (steps <= 0) return;
    if (s_.composition) {
      // First-same-as-last: the force at the end of a step starts the next one.
      gradient(q, force_);
      for (int k = 0; k < steps; ++k) {
        for (int w = 0; w < s_.ncomp; ++w) leapfrog(s_.comp_w[w] * dt);
      }
    } else {
      for (int k = 0; k < steps; ++k) runge_kutta(dt);
    }
  }

  Vec* q;          // d x C positions
  Vec* p;          // d x C momenta
  Vec* term_coef;  // per gradient term: c_m * e_mj, one value per lane

 private:
  static Vec* take(Vec*& work, int size) {
    Vec* out = work;
    work += size;
    return out;
  }

  // ∂U/∂q of the polynomial (eq 13) at x into out, in the reference's order: powers by
  // repeated multiplication, then per component j the terms (c_m e_mj) Π_i x_i^(e_mi − δ_ij),
  // read from the term program (Settings::term_*), summed in basis order.
  void gradient(const Vec* __restrict__ x, Vec* __restrict__ out) {
    if (fixed_gradient_ != nullptr) return fixed_gradient_(x, out, term_coef);
    const int C = chunks_.count();
    const int d = s_.d;
    const int width = s_.order + 1;
    Vec* __restrict__ pw = powers_;
    for (int i = 0; i < d; ++i) {
      Vec* row = pw + i * width * C;
      for (int c = 0; c < C; ++c) {
        Vec v = x[i * C + c];
        row[C + c] = v;
        for (int k = 2; k < width; ++k) {
          v = v * x[i * C + c];
          row[k * C + c] = v;
        }
      }
    }
    int t = 0;
    for (int j = 0; j < d; ++j) {
      Vec acc[kMaxChunksInRegisters > 0 ? kMaxChunksInRegisters : 1];
      Vec* __restrict__ gj = out + j * C;
      Vec* a = C <= kMaxChunksInRegisters ? acc : gj;
      for (int c = 0; c < C; ++c) a[c] = Vec{} ;
      for (const int last = s_.term_start[j + 1]; t < last; ++t) {
        const Vec coef = term_coef[t];
        const int* f = s_.factor_rows + s_.factor_start[t];
        const int nf = s_.factor_start[t + 1] - s_.factor_start[t];
        for (int c = 0; c < C; ++c) {
          Vec v = coef;
          for (int k = 0; k < nf; ++k) v = v * pw[f[k] * C + c];
          a[c] = a[c] + v;
        }
      }
      if (a != gj) {
        for (int c = 0; c < C; ++c) gj[c] = a[c];
      }
    }
  }

  // M⁻¹ v for the momenta v; v itself when M is the identity.
  const Vec* velocity(const Vec* __restrict__ v, Vec* __restrict__ buffer) {
    if (!s_.has_mass) return v;
    const int C = chunks_.count();
    const int d = s_.d;
    for (int i = 0; i < d; ++i) {
      const double* row = s_.inv_mass + i * d;
      for (int c = 0; c < C; ++c) {
        Vec sum = row[0] * v[c];
        for (int j = 1; j < d; ++j) sum = sum + row[j] * v[j * C + c];
        buffer[i * C + c] = sum;
      }
    }
    return buffer;
  }

  // One leapfrog step of size h at integer steps, eqs (5)-(6), with the force at q given:
  // q⁺ = q + h M⁻¹p − ½h² M⁻¹∂U(q);  p⁺ = p − ½h (∂U(q) + ∂U(q⁺)).
  void leapfrog(double h) {
    const int n = s_.d * chunks_.count();
    const Vec* __restrict__ vp = velocity(p, vel_a_);
    const Vec* __restrict__ vg = velocity(force_, vel_b_);
    const double half_h2 = 0.5 * h * h;
    Vec* __restrict__ qq = q;
    for (int i = 0; i < n; ++i) qq[i] = (qq[i] + h * vp[i]) - half_h2 * vg[i];
    gradient(q, force_next_);
    const double half_h = 0.5 * h;
    Vec* __restrict__ pp = p;
    const Vec* __restrict__ f0 = force_;
    const Vec* __restrict__ f1 = force_next_;
    for (int i = 0; i < n; ++i) pp[i] = pp[i] - half_h * (f0[i] + f1[i]);
    std::swap(force_, force_next_);
  }

  // One explicit Runge-Kutta step from the Butcher tableau (a strictly lower-triangular).
  void runge_kutta(double h) {
    const int n = s_.d * chunks_.count();
    const int S = s_.stages;
    for (int st = 0; st < S; ++st) {
      const Vec* qs = q;
      const Vec* ps = p;
      bool started = false;
      for (int j = 0; j < st; ++j) {
        const double a = s_.rk_a[st * S + j];
        if (a == 0.0) continue;
        const double f = h * a;
        accumulate(started ? stage_q_ : q, kq_ + j * n, f, stage_q_, n);
        accumulate(started ? stage_p_ : p, kp_ + j * n, f, stage_p_, n);
        started = true;
      }
      if (started) {
        qs = stage_q_;
        ps = stage_p_;
      }
      Vec* __restrict__ kq = kq_ + st * n;
      Vec* __restrict__ kp = kp_ + st * n;
      const Vec* __restrict__ v = velocity(ps, vel_a_);
      for (int i = 0; i < n; ++i) kq[i] = v[i];
      gradient(qs, kp);
      for (int i = 0; i < n; ++i) kp[i] = -kp[i];
    }
    for (int st = 0; st < S; ++st) {
      const double b = s_.rk_b[st];
      if (b == 0.0) continue;
      const double f = h * b;
      accumulate(q, kq_ + st * n, f, q, n);
      accumulate(p, kp_ + st * n, f, p, n);
    }
  }

  // out = base + f * k, elementwise (out may be base).
  static void accumulate(const Vec* base, const Vec* __restrict__ k, double f, Vec* out, int n) {
    for (int i = 0; i < n; ++i) out[i] = base[i] + f * k[i];
  }

  static constexpr int kMaxChunksInRegisters = 4;

  const Settings& s_;
  Chunks chunks_;
  Vec* force_;
  Vec* force_next_;
  Vec* powers_;
  Vec* vel_a_;
  Vec* vel_b_;
  Vec* stage_q_;
  Vec* stage_p_;
  Vec* kq_;
  Vec* kp_;
  GradientFn fixed_gradient_ = nullptr;
};

// The first `columns` columns of the lower Cholesky factor of the symmetric N x N matrix a
// (row-major, lower triangle read and overwritten), right-looking as in the reference: per
// column j, col = a[:, j] / sqrt(a[j, j]) below the diagonal, then a −= col colᵀ. The factor
// is left in the lower triangle of a; a failed factorisation leaves NaN, never an error.
inline void cholesky_columns(double* a, int N, int columns) {
  for (int j = 0; j < columns; ++j) {
    const double root = std::sqrt(a[j * N + j]);
    for (int i = j; i < N; ++i) a[i * N + j] = a[i * N + j] / root;
    if (j == columns - 1) break;
    for (int i = j + 1; i < N; ++i) {
      const double ci = a[i * N + j];
      for (int k = j + 1; k <= i; ++k) a[i * N + k] -= ci * a[k * N + j];
    }
  }
}

// Per-member filter state and the small dense algebra of eqs (10)-(12).
class MemberFilter {
 public:
  MemberFilter(const Settings& s, const Member& m, double* work) : s_(s), m_(m) {
    const int n = s.n, dy = s.dy, N = s.dy + s.n + 1;
    mean = work;
    chol = mean + n;
    cov = chol + n * n;
    joint_ = cov + n * n;
    cross_ = joint_ + N * N;
    predicted_ = cross_ + n * dy;
    s0_ = predicted_ + dy;
  }

  static std::size_t workspace(const Settings& s) {
    const int n = s.n, dy = s.dy, N = s.dy + s.n + 1;
    return n + 2 * n * n + N * N + n * dy + dy + dy * dy;
  }

  // x0 and the factor of symmetrise(P0); false when a variance in θ is not positive.
  bool start() {
    const int n = s_.n;
    for (int i = 0; i < n; ++i) mean[i] = m_.x0[i];
    for (int i = 0; i < n; ++i) {
      for (int k = 0; k < n; ++k) chol[i * n + k] = 0.5 * (m_.P0[i * n + k] + m_.P0[k * n + i]);
    }
    cholesky_columns(chol, n, n);
    zero_upper(chol, n);
    for (int v = s_.ncoef; v < s_.nparams; ++v) {
      if (!(m_.theta[v] > 0.0)) return false;
    }
    return true;
  }

  // Write the sigma points m, m ± scale·L[:, c] into this member's lanes: sigma point k of
  // member g is lane k·G + g of rows of `stride` doubles (q rows, then p rows).
  void sigma_points(double* q, double* p, int stride, int G, int g) const {
    const int n = s_.n, d = s_.d;
    for (int i = 0; i < n; ++i) {
      double* row = (i < d ? q + i * stride : p + (i - d) * stride) + g;
      row[0] = mean[i];
      for (int c = 0; c < n; ++c) {
        const double spread = s_.scale * chol[i * n + c];
        row[(1 + c) * G] = mean[i] + spread;
        row[(1 + n + c) * G] = mean[i] - spread;
      }
      if (G == 1) {  // padding lanes: copies of the centre point (finite, never read)
        for (int k = s_.npts; k < stride; ++k) row[k] = mean[i];
      }
    }
  }

  // Predicted moments, eq (10): weighted mean and covariance of the propagated points,
  // plus Σ, symmetrised, plus jitter·I (into mean and cov).
  void predicted_moments(const double* q, const double* p, int stride, int G, int g) {
    const int n = s_.n, d = s_.d, np = s_.npts;
    double centred[kMaxStack];
    double* c = np * n <= kMaxStack ? centred : scratch(np * n);
    for (int i = 0; i < n; ++i) {
      const double* row = (i < d ? q + i * stride : p + (i - d) * stride) + g;
      double sum = 0.0;
      for (int k = 0; k < np; ++k) sum += row[k * G] * s_.wm[k];
      mean[i] = sum;
      for (int k = 0; k < np; ++k) c[i * np + k] = row[k * G] - sum;
    }
    for (int i = 0; i < n; ++i) {
      for (int j = 0; j < n; ++j) {
        double sum = 0.0;
        for (int k = 0; k < np; ++k) sum += s_.wc[k] * c[i * np + k] * c[j * np + k];
        cov[i * n + j] = sum;
      }
      cov[i * n + i] += process_variance(i);
    }
    for (int i = 0; i < n; ++i) {  // symmetrise (Σ + jitter on the diagonal)
      for (int j = 0; j < i; ++j) {
        const double v = 0.5 * (cov[i * n + j] + cov[j * n + i]);
        cov[i * n + j] = v;
        cov[j * n + i] = v;
      }
      cov[i * n + i] = 0.5 * (cov[i * n + i] + cov[i * n + i]) + s_.jitter;
    }
  }

  // The factor of cov for the next substep's sigma points (noise added per substep).
  void factor_covariance() {
    const int n = s_.n;
    for (int i = 0; i < n * n; ++i) chol[i] = cov[i];
    cholesky_columns(chol, n, n);
    zero_upper(chol, n);
  }

  // cov = chol cholᵀ (a gap of zero substeps with noise per substep).
  void covariance_from_factor() {
    const int n = s_.n;
    for (int i = 0; i < n; ++i) {
      for (int j = 0; j < n; ++j) {
        double sum = 0.0;
        for (int k = 0; k < n; ++k) sum += chol[i * n + k] * chol[j * n + k];
        cov[i * n + j] = sum;
      }
    }
  }

  // Update and marginalisation, eqs (11)-(12), for the observed components of y: one
  // factorisation of the joint covariance of (y, x) with the innovation as a last row.
  // Returns log p(y_k | y_1..k−1); leaves the filtered mean and factor in mean and chol.
  double update(const double* y, const bool* mask) {
    const int n = s_.n, dy = s_.dy, N = dy + n + 1;
    double* a = joint_;
    observation_moments();
    int observed = 0;
    for (int i = 0; i < dy; ++i) observed += mask[i] ? 1 : 0;
    for (int i = 0; i < N * N; ++i) a[i] = 0.0;
    for (int i = 0; i < dy; ++i) {  // S block (masked rows and columns → identity)
      for (int j = 0; j <= i; ++j) {
        double v = (i == j) ? 1.0 : 0.0;
        if (mask[i] && mask[j]) {
          v = 0.5 * ((s0_[i * dy + j] + obs_variance(i, j)) + (s0_[j * dy + i] + obs_variance(j, i)));
        }
        a[i * N + j] = v;
      }
    }
    for (int i = 0; i < n; ++i) {  // C block and P block
      for (int j = 0; j < dy; ++j) a[(dy + i) * N + j] = mask[j] ? cross_[i * dy + j] : 0.0;
      for (int j = 0; j <= i; ++j) a[(dy + i) * N + dy + j] = cov[i * n + j];
    }
    for (int j = 0; j < dy; ++j) a[(N - 1) * N + j] = mask[j] ? y[j] - predicted_[j] : 0.0;
    cholesky_columns(a, N, dy + n);
    double zz = 0.0, logdet = 0.0;
    for (int j = 0; j < dy; ++j) {
      const double z = a[(N - 1) * N + j];
      zz += z * z;
      logdet += std::log(a[j * N + j]);
    }
    for (int i = 0; i < n; ++i) {
      double shift = 0.0;
      for (int j = 0; j < dy; ++j) shift += a[(dy + i) * N + j] * a[(N - 1) * N + j];
      mean[i] = mean[i] + shift;
      for (int j = 0; j < n; ++j) chol[i * n + j] = j <= i ? a[(dy + i) * N + dy + j] : 0.0;
    }
    return (-0.5 * zz - logdet) - 0.5 * observed * kLog2Pi;
  }

 private:
  static constexpr int kMaxStack = 512;
  static constexpr double kLog2Pi = 1.8378770664093454835606594728112;

  double process_variance(int i) const {
    return m_.theta[s_.ncoef + (s_.diagonal ? i : 0)];
  }

  double obs_variance(int i, int j) const {
    if (i != j) return 0.0;
    const int first = s_.ncoef + (s_.diagonal ? s_.n : 1);
    return m_.theta[first + (s_.diagonal ? i : 0)];
  }

  // ŷ = H m, C = P Hᵀ, S = H C (without Γ): exact moments of a linear observation.
  void observation_moments() {
    const int n = s_.n, dy = s_.dy;
    const double* H = s_.obs_matrix;
    for (int i = 0; i < dy; ++i) {
      double sum = 0.0;
      for (int k = 0; k < n; ++k) sum += H[i * n + k] * mean[k];
      predicted_[i] = sum;
    }
    for (int i = 0; i < n; ++i) {
      for (int j = 0; j < dy; ++j) {
        double sum = 0.0;
        for (int k = 0; k < n; ++k) sum += cov[i * n + k] * H[j * n + k];
        cross_[i * dy + j] = sum;
      }
    }
    for (int i = 0; i < dy; ++i) {
      for (int j = 0; j < dy; ++j) {
        double sum = 0.0;
        for (int k = 0; k < n; ++k) sum += H[i * n + k] * cross_[k * dy + j];
        s0_[i * dy + j] = sum;
      }
    }
  }

  static void zero_upper(double* a, int n) {
    for (int i = 0; i < n; ++i) {
      for (int k = i + 1; k < n; ++k) a[i * n + k] = 0.0;
    }
  }

  double* scratch(int size) {
    big_.resize(size);
    return big_.data();
  }

  const Settings& s_;
  const Member& m_;
  std::vector<double> big_;
  double* joint_;
  double* cross_;
  double* predicted_;
  double* s0_;

 public:
  double* mean;  // n: filtered (or predicted) mean
  double* chol;  // n x n: lower factor of the filtered covariance
  double* cov;   // n x n: predicted covariance
};

// The filter recursion (Theorem 1) for a group of G members sharing one data set (G is 1 or
// kWidth: then each vector holds one sigma point of the eight members).
template <class Chunks>
void run_group(const Settings& s, const TrajectoryData& data, const Member* members, int G,
               Chunks chunks, Workspace& work) {
  const int C = chunks.count();
  const int stride = C * kWidth;  // doubles per state row
  const std::size_t member_size = MemberFilter::workspace(s);
  Vec* lanes = work.lanes(Propagator<Chunks>::workspace(s, C));
  work.members.resize(G * member_size);
  Propagator<Chunks> prop(s, chunks, lanes);
  double* q = reinterpret_cast<double*>(prop.q);
  double* p = reinterpret_cast<double*>(prop.p);

  std::vector<MemberFilter> filters;
  filters.reserve(G);
  bool valid[kMaxGroup];
  double total[kMaxGroup];
  for (int g = 0; g < G; ++g) {
    filters.emplace_back(s, members[g], work.members.data() + g * member_size);
    valid[g] = filters[g].start();
    total[g] = 0.0;
  }
  for (int t = 0; t < s.num_terms; ++t) {  // c_m e_mj per lane: member g in lane g mod G
    for (int w = 0; w < kWidth; ++w) {
      prop.term_coef[t][w] = members[w % G].theta[s.term_coef_index[t]] * s.term_mult[t];
    }
  }
  for (int k = 0; k < data.num_gaps; ++k) {
    const double dt = data.step_size[k];
    int steps = s.uniform ? s.max_steps : static_cast<int>(data.num_steps[k]);
    steps = std::max(0, std::min(steps, s.max_steps));
    if (s.per_step) {
      if (steps == 0) {
        for (int g = 0; g < G; ++g) filters[g].covariance_from_factor();
      }
      for (int st = 0; st < steps; ++st) {
        for (int g = 0; g < G; ++g) filters[g].sigma_points(q, p, stride, G, g);
        prop.advance(dt, 1);
        for (int g = 0; g < G; ++g) {
          filters[g].predicted_moments(q, p, stride, G, g);
          filters[g].factor_covariance();
        }
      }
    } else {
      for (int g = 0; g < G; ++g) filters[g].sigma_points(q, p, stride, G, g);
      prop.advance(dt, steps);
      for (int g = 0; g < G; ++g) filters[g].predicted_moments(q, p, stride, G, g);
    }
    bool any_finite = false;
    for (int g = 0; g < G; ++g) {
      total[g] += filters[g].update(data.ys + k * s.dy, data.masks + k * s.dy);
      any_finite = any_finite || (valid[g] && std::isfinite(total[g]));
    }
    if (!any_finite) break;  // every member already failed: −∞ for all
  }
  for (int g = 0; g < G; ++g) {
    const bool ok = valid[g] && std::isfinite(total[g]);
    *members[g].out = ok ? total[g] : -std::numeric_limits<double>::infinity();
  }
}

// Entry point for this instruction set: a compile-time chunk count where one is common.
inline void evaluate(const Settings& s, const TrajectoryData& data, const Member* members,
                     int G, Workspace& work) {
  const int chunks = (G * s.npts + kWidth - 1) / kWidth;
  switch (chunks) {
    case 1: return run_group(s, data, members, G, FixedChunks<1>{}, work);
    case 2: return run_group(s, data, members, G, FixedChunks<2>{}, work);
    case 5: return run_group(s, data, members, G, FixedChunks<5>{}, work);
    case 9: return run_group(s, data, members, G, FixedChunks<9>{}, work);
    case 13: return run_group(s, data, members, G, FixedChunks<13>{}, work);
    default: return run_group(s, data, members, G, RuntimeChunks{chunks}, work);
  }
}

}  // namespace SYMPLID_ISA_NS
}  // namespace symplid
