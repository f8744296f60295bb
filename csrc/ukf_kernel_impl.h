// The UKF log marginal likelihood (Theorem 1, eqs 10-12) of a polynomial Hamiltonian model,
// compiled for one instruction set.
//
// This file is included once by each instruction set's translation unit (ukf_kernel_avx512.cc,
// ukf_kernel_avx2.cc, ukf_kernel_baseline.cc), inside a `#pragma GCC target(...)` region and
// with SYMPLID_ISA_NS naming the namespace. It includes only ukf_basis.h (the compile-time
// polynomial bases, into the same namespace): the types it uses (Settings, TrajectoryData,
// Member) and the standard headers come from ukf_kernel.h, which those files include before
// the region.
//
// Layout. A "lane" is one sigma point of one parameter vector θ; lanes come in vectors of
// eight (Vec). One θ puts its 2n+1 sigma points in consecutive lanes (the last vector padded);
// a group of eight θ that share the data puts sigma point k of member g in lane 8k + g, so
// each vector is one sigma point of the eight. Arrays over lanes are coordinate-major,
// x[i * C + c] for C vectors per coordinate; C is a compile-time constant for common sizes.
//
// Every formula is the JAX reference's, but not always associated the same way: where it
// shortens a dependent chain (the force's sums, the leapfrog's kicks, the joint update's
// factorisation) the kernel reorders sums and fuses multiply-adds, so the two agree to
// rounding (1e-12 relative in log L where the reference is well conditioned), not bit for bit.

namespace symplid {
namespace SYMPLID_ISA_NS {

constexpr int kWidth = 8;  // lanes per Vec
// Whether a Vec is one of 32 registers (AVX-512), so that several blocks of sigma points fit
// in registers at once; SYMPLID_MANY_REGISTERS is set by ukf_kernel.cc per instruction set.
constexpr bool kManyRegisters = SYMPLID_MANY_REGISTERS;

template <int N>
struct FixedChunks {
  static constexpr int count() { return N; }
};

struct RuntimeChunks {
  int n;
  int count() const { return n; }
};

// ---------------------------------------------------------------- force for small d and ℓ
#include "ukf_basis.h"

using GradientFn = void (*)(const Vec*, Vec*, const Vec*);

// The compile-time force for C vectors per coordinate, or nullptr (then the generic one).
template <int C>
GradientFn fixed_gradient(const Settings& s) {
#ifdef SYMPLID_USER_FORCE
  (void)s;  // a user's unit: its force only (Propagator::gradient)
  return nullptr;
#endif
#define SYMPLID_TRY_BASIS(D, ORDER) \
  if (FixedBasis<D, ORDER>::matches(s)) return &FixedBasis<D, ORDER>::template gradient<C>;
  if (s.d == 1 && (C == 1 || C == 5)) {
    SYMPLID_TRY_BASIS(1, 2) SYMPLID_TRY_BASIS(1, 3) SYMPLID_TRY_BASIS(1, 4) SYMPLID_TRY_BASIS(1, 5)
  }
  if (s.d == 2 && (C == 2 || C == 9)) {
    SYMPLID_TRY_BASIS(2, 2) SYMPLID_TRY_BASIS(2, 3) SYMPLID_TRY_BASIS(2, 4) SYMPLID_TRY_BASIS(2, 5)
  }
  if (s.d == 3 && (C == 2 || C == 13)) {  // degree 4 and 5: 35 and 55 terms, rare, slow to build
    SYMPLID_TRY_BASIS(3, 2) SYMPLID_TRY_BASIS(3, 3)
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
#ifdef SYMPLID_USER_FORCE
    return user_gradient(x, out);
#endif
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

#ifdef SYMPLID_USER_FORCE
  // ∂U/∂q of a user's U(q; θ) (its unit's force policy), one vector of lanes at a time;
  // term_coef holds θ's parameters per lane.
  void user_gradient(const Vec* __restrict__ x, Vec* __restrict__ out) const {
    using Force = SYMPLID_USER_FORCE;
    const int C = chunks_.count();
    const Vec* tc = term_coef;
    for (int c = 0; c < C; ++c) {
      Vec xs[Force::D], f[Force::D];
      for (int i = 0; i < Force::D; ++i) xs[i] = x[i * C + c];
      Force::template add<false>(xs, [tc](int t) { return tc[t]; }, f);
      for (int i = 0; i < Force::D; ++i) out[i * C + c] = f[i];
    }
  }
#endif

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

// ---------------------------------------------------------------- fast leapfrog propagation
// The hot loop of the kernel is Ψ over a gap: `steps` leapfrog compositions of every sigma
// point. Sigma points do not interact during a gap, so instead of sweeping all lanes through
// memory once per substep (a force call through a pointer, powers and forces stored and
// reloaded every time), the fast path keeps a few vectors of sigma points in registers for the
// whole gap: a Block holds the state of one vector (or one scalar) of lanes, and several
// blocks are advanced in the same loop body so that the processor overlaps their dependency
// chains. The arithmetic is the reference's, associated for short chains: the force is a
// Horner program (FixedBasis::horner_add), and a merged kick folds the momentum and the kick's
// size into it (CompositionMethod), so that a leapfrog substep's dependent chain is one drift
// and the force's (degree + d − 1) multiply-adds.

// An explicit Runge–Kutta tableau of S stages for one step size h: h a_ij and h b_i, with
// flags for the entries that are not zero (Propagator::runge_kutta skips those that are).
template <int S>
struct RkTableau {
  double a[S][S] = {};
  bool use_a[S][S] = {};
  double b[S] = {};
  bool use_b[S] = {};

  RkTableau(const Settings& s, double h) {
    for (int i = 0; i < S; ++i) {
      for (int j = 0; j < i; ++j) {
        use_a[i][j] = s.rk_a[i * S + j] != 0.0;
        a[i][j] = h * s.rk_a[i * S + j];
      }
      use_b[i] = s.rk_b[i] != 0.0;
      b[i] = h * s.rk_b[i];
    }
  }
};

// The force of the fast propagation as a policy: D coordinates, kTerms per-lane values of θ
// that it reads (a vector of lanes each, Block::tc), kTabled whether a kick scaled by κ is the
// same program with every value scaled by −κ (linear in them: a polynomial), and
// add<INIT>(x, coef, acc): acc (+)= ∂U/∂q(x) with value t = coef(t) (INIT: acc's values are
// read, as a kick's momentum; only for kTabled forces), kScalarLane whether one θ's lone last
// sigma point is advanced as a scalar (fast_advance). PolynomialForce is the fixed basis's
// Horner program; a user's U(q; θ) supplies its own (the units model/_user_kernel.py makes).
template <int D_, int ORDER>
struct PolynomialForce {
  using Basis = FixedBasis<D_, ORDER>;
  static constexpr int D = D_;
  static constexpr int kTerms = Basis::kTable.start[D];
  static constexpr bool kTabled = true;
  static constexpr bool kScalarLane = true;
  template <bool INIT, class T, class Coef>
  SYMPLID_INLINE static void add(const T (&x)[D], const Coef& coef, T (&acc)[D]) {
    Basis::template horner_add<INIT>(x, coef, acc);
  }
};

// A block of lanes (T = Vec for eight lanes, double for one) for a force policy (above) in
// D coordinates; MASS says whether the velocity is M⁻¹p (else p).
template <class Force, bool MASS, class T>
struct Block {
  static constexpr int D = Force::D;
  static constexpr int kTerms = Force::kTerms;
  static constexpr bool kTabled = Force::kTabled;

  T q[D], p[D];
  const Vec* tc = nullptr;  // c_m e_mj per term (a vector of lanes each)
  int lane = 0;             // a double block's lane within those vectors

  // Term t's entry of a table of one vector per term, for these lanes.
  SYMPLID_INLINE T coef(const Vec* table, int t) const {
    if constexpr (std::is_same<T, Vec>::value) {
      return table[t];
    } else {
      return reinterpret_cast<const double*>(table + t)[lane];
    }
  }

  // ∂U/∂q at x into out, as the force's program.
  SYMPLID_INLINE void force_at(const T (&x)[D], T (&out)[D]) const {
    Force::template add<false>(
        x, [this](int t) __attribute__((always_inline)) { return coef(tc, t); }, out);
  }

  // A kick p ← p − k ∂U/∂q(q) given the table of −k c_m e_mj: the momentum enters the
  // Horner program as its initial value, so the kick adds no step to the dependent chain.
  SYMPLID_INLINE void kick_scaled(const Vec* table) {
    Force::template add<true>(
        q, [this, table](int t) __attribute__((always_inline)) { return coef(table, t); }, p);
  }

  // A kick p ← p − kick ∂U/∂q(q) from the force.
  SYMPLID_INLINE void kick(double kick) {
    T f[D];
    force_at(q, f);
#pragma GCC unroll 16
    for (int i = 0; i < D; ++i) p[i] = p[i] - kick * f[i];
  }

  // A drift q ← q + h M⁻¹p.
  SYMPLID_INLINE void drift(double h, const double* inv_mass) {
    T vp[D];
    velocity(p, vp, inv_mass);
#pragma GCC unroll 16
    for (int i = 0; i < D; ++i) q[i] = q[i] + h * vp[i];
  }

  // M⁻¹ v (v itself without a mass matrix), as Propagator::velocity.
  SYMPLID_INLINE static void velocity(const T (&v)[D], T (&out)[D], const double* inv_mass) {
#pragma GCC unroll 16
    for (int i = 0; i < D; ++i) {
      if (!MASS) {
        out[i] = v[i];
        continue;
      }
      T sum = inv_mass[i * D] * v[0];
#pragma GCC unroll 16
      for (int j = 1; j < D; ++j) sum = sum + inv_mass[i * D + j] * v[j];
      out[i] = sum;
    }
  }

  // One explicit Runge–Kutta step from the tableau (as Propagator::runge_kutta, operation for
  // operation): stage i at (q, p) + Σ_j h a_ij (kq_j, kp_j) over a_ij ≠ 0 in j order, with
  // kq_i = M⁻¹p_i and kp_i = −∂U/∂q(q_i) (eq 7's vector field); then (q, p) += h b_i (kq_i, kp_i)
  // over b_i ≠ 0 in stage order, summed as the stages finish so that no stage outlives its use.
  template <int S>
  SYMPLID_INLINE void rk_step(const RkTableau<S>& tab, const double* inv_mass) {
    T kq[S][D], kp[S][D], nq[D], np[D];
#pragma GCC unroll 16
    for (int i = 0; i < D; ++i) {
      nq[i] = q[i];
      np[i] = p[i];
    }
#pragma GCC unroll 4
    for (int st = 0; st < S; ++st) {
      T sq[D], sp[D];
#pragma GCC unroll 16
      for (int i = 0; i < D; ++i) {
        sq[i] = q[i];
        sp[i] = p[i];
      }
#pragma GCC unroll 4
      for (int j = 0; j < st; ++j) {
        if (!tab.use_a[st][j]) continue;
        const double fa = tab.a[st][j];
#pragma GCC unroll 16
        for (int i = 0; i < D; ++i) {
          sq[i] = sq[i] + fa * kq[j][i];
          sp[i] = sp[i] + fa * kp[j][i];
        }
      }
      velocity(sp, kq[st], inv_mass);
      force_at(sq, kp[st]);
#pragma GCC unroll 16
      for (int i = 0; i < D; ++i) kp[st][i] = -kp[st][i];
      if (!tab.use_b[st]) continue;
      const double fb = tab.b[st];
#pragma GCC unroll 16
      for (int i = 0; i < D; ++i) {
        nq[i] = nq[i] + fb * kq[st][i];
        np[i] = np[i] + fb * kp[st][i];
      }
    }
#pragma GCC unroll 16
    for (int i = 0; i < D; ++i) {
      q[i] = nq[i];
      p[i] = np[i];
    }
  }

  // Moves the lanes between registers and the kernel's arrays (d rows of C vectors): `at` is
  // the vector's index in a row for a Vec block, the lane's index for a double block.
  void load(const Vec* qs, const Vec* ps, const Vec* tcs, int C, int at) {
    for (int i = 0; i < D; ++i) {
      get(qs + i * C, at, q[i]);
      get(ps + i * C, at, p[i]);
    }
    tc = tcs;
    lane = std::is_same<T, Vec>::value ? 0 : at % kWidth;
  }
  void store(Vec* qs, Vec* ps, int C, int at) const {
    for (int i = 0; i < D; ++i) {
      put(qs + i * C, at, q[i]);
      put(ps + i * C, at, p[i]);
    }
  }
  SYMPLID_INLINE static void get(const Vec* row, int at, T& out) {
    if constexpr (std::is_same<T, Vec>::value) {
      out = row[at];
    } else {
      out = reinterpret_cast<const double*>(row)[at];
    }
  }
  SYMPLID_INLINE static void put(Vec* row, int at, const T& v) {
    if constexpr (std::is_same<T, Vec>::value) {
      row[at] = v;
    } else {
      reinterpret_cast<double*>(row)[at] = v;
    }
  }
};

// How a few blocks advance together over `steps` steps of a gap, per kind of propagator, and
// how many vector blocks go together at most (more hide more latency until they spill).
// The composition of leapfrog steps (eqs 5-6, weights w_0..w_(m−1)), kick-drift-kick with
// the half kicks between substeps merged, as Propagator::advance's first-same-as-last: the gap
// opens with a kick of ½w_0 dt, each substep w drifts w_w dt and then kicks ½(w_w + w_(w+1)) dt
// (w_m = w_0: the next step's first half), and the gap's last kick is ½w_(m−1) dt. For up to
// kMaxTables weights, each merged kick has its table of coefficients −kick c_m e_mj, made once
// per gap, and is one Horner program over the momentum (Block::kick_scaled); the gap's first
// and last kicks, and the merged ones of longer compositions, scale the force (Block::kick).
// (Taking the first and last kicks from tables as well, in the same loop, measured slower.)
struct CompositionMethod {
  static constexpr int kMaxBlocks = 3;
  static constexpr int kMaxTables = 4;
  template <class... Blocks>
  SYMPLID_INLINE static void run(const Settings& s, double dt, int steps, const Vec* tc,
                                 Blocks&... blocks) {
    if (steps <= 0) return;
    constexpr int kTerms = std::max({1, Blocks::kTerms...});
    constexpr bool kTabledForce = (Blocks::kTabled && ...);
    const int m = s.ncomp, last = m - 1;
    const bool tabled = kTabledForce && m <= kMaxTables;
    Vec table[kMaxTables][kTerms];
    for (int w = 0; tabled && w < m; ++w) {
      const double kick = 0.5 * (s.comp_w[w] + s.comp_w[w < last ? w + 1 : 0]) * dt;
      for (int t = 0; t < kTerms; ++t) table[w][t] = -kick * tc[t];
    }
    (blocks.kick(0.5 * s.comp_w[0] * dt), ...);
    for (int k = 0; k < steps; ++k) {
      for (int w = 0; w < m; ++w) {
        const double h = s.comp_w[w] * dt;
        (blocks.drift(h, s.inv_mass), ...);
        const bool end = k + 1 == steps && w == last;
        if (tabled && !end) {
          if constexpr (kTabledForce) (blocks.kick_scaled(table[w]), ...);
        } else {
          const double next = end ? 0.0 : s.comp_w[w < last ? w + 1 : 0] * dt;
          (blocks.kick(0.5 * h + 0.5 * next), ...);
        }
      }
    }
  }
};

// An explicit Runge–Kutta method of S stages (Settings::rk_a, rk_b). Its stages hold more
// registers than a leapfrog step: pairs beyond two stages (on the paper's workload, rk2 and
// rk4 time the same with two or three blocks, so the smaller register set is kept for rk4).
template <int S>
struct RungeKuttaMethod {
  static constexpr int kMaxBlocks = S <= 2 ? 3 : 2;
  template <class... Blocks>
  SYMPLID_INLINE static void run(const Settings& s, double dt, int steps, const Vec*,
                                 Blocks&... blocks) {
    const RkTableau<S> tableau(s, dt);
    for (int k = 0; k < steps; ++k) (blocks.template rk_step<S>(tableau, s.inv_mass), ...);
  }
};

// Ψ over one gap for every lane of the arrays q, p (d rows of C vectors): G = 1 takes the
// lanes of one θ (its npts sigma points), G = kWidth one vector per sigma point.
using FastAdvanceFn = void (*)(const Settings&, Vec*, Vec*, const Vec*, int, int, double, int);

// The blocks of a gap for one layout of the lanes, known at compile time: FULL whole vectors
// per row, and after them a lone scalar lane or not. Three (or two) vectors at a time hide the
// latency of one step's chain; the leftovers go in a pair or alone, with the lone lane beside
// them.
template <class Force, bool MASS, class Method, int FULL, bool LONE>
SYMPLID_INLINE void advance_layout(const Settings& s, Vec* q, Vec* p, const Vec* tc, int C,
                                   double dt, int steps) {
  using V = Block<Force, MASS, Vec>;
  using S = Block<Force, MASS, double>;
  constexpr int kGroup = Method::kMaxBlocks >= 3 ? 3 : 2;
  // triples while three are left; pairs while more than two are left
  constexpr int kGroups = kGroup == 3 ? FULL / 3 : (FULL > 2 ? (FULL - 1) / 2 : 0);
  constexpr int kLeft = FULL - kGroups * kGroup;
  for (int g = 0; g < kGroups; ++g) {
    const int c = g * kGroup;
    V a, b;
    a.load(q, p, tc, C, c);
    b.load(q, p, tc, C, c + 1);
    if constexpr (kGroup == 3) {
      V e;
      e.load(q, p, tc, C, c + 2);
      Method::run(s, dt, steps, tc, a, b, e);
      e.store(q, p, C, c + 2);
    } else {
      Method::run(s, dt, steps, tc, a, b);
    }
    a.store(q, p, C, c);
    b.store(q, p, C, c + 1);
  }
  constexpr int c = kGroups * kGroup;
  S x;
  if constexpr (LONE) x.load(q, p, tc, C, FULL * kWidth);
  if constexpr (kLeft == 2) {
    V a, b;
    a.load(q, p, tc, C, c);
    b.load(q, p, tc, C, c + 1);
    if constexpr (LONE) {
      Method::run(s, dt, steps, tc, a, b, x);
    } else {
      Method::run(s, dt, steps, tc, a, b);
    }
    a.store(q, p, C, c);
    b.store(q, p, C, c + 1);
  } else if constexpr (kLeft == 1) {
    V a;
    a.load(q, p, tc, C, c);
    if constexpr (LONE) {
      Method::run(s, dt, steps, tc, a, x);
    } else {
      Method::run(s, dt, steps, tc, a);
    }
    a.store(q, p, C, c);
  } else if constexpr (LONE) {
    Method::run(s, dt, steps, tc, x);
  }
  if constexpr (LONE) x.store(q, p, C, FULL * kWidth);
}

// Only used where the vector registers are many (select_fast_advance): with AVX2 or SSE2 a Vec
// is already two or four registers and register blocks would spill. The state has n = 2D
// components, so 4D + 1 sigma points (select_fast_advance checks): with one θ, whole vectors of
// them, a last partly used vector counting as whole (its padding lanes hold finite copies of
// the centre point) unless it has a single lane, which then goes in a scalar block; with a
// group, one vector per sigma point. So only the block layouts that occur are compiled.
template <class Force, bool MASS, class Method>
void fast_advance(const Settings& s, Vec* q, Vec* p, const Vec* tc, int C, int G, double dt,
                  int steps) {
  if (steps <= 0) return;
  constexpr int kPoints = 4 * Force::D + 1, kRest = kPoints % kWidth;
  if (G == 1) {
    // A lone lane goes in a scalar block where the force's scalar form is cheap (a
    // polynomial); a force that calls functions of the C library (a user's) takes it in one
    // more vector block instead, whose vector functions are faster than the scalar ones.
    constexpr bool kLone = kRest == 1 && Force::kScalarLane;
    advance_layout<Force, MASS, Method, kPoints / kWidth + (kRest > 0 && !kLone), kLone>(
        s, q, p, tc, C, dt, steps);
  } else {
    advance_layout<Force, MASS, Method, kPoints, false>(s, q, p, tc, C, dt, steps);
  }
}

// fast_advance for a fixed basis, by propagator: a composition of leapfrog steps, or an
// explicit Runge–Kutta method of two or four stages (the library's rk2-midpoint, rk2-heun and
// rk4); else nullptr: Propagator::advance.
template <class Force>
FastAdvanceFn fast_advance_for(const Settings& s) {
  if (s.composition) return &fast_advance<Force, false, CompositionMethod>;
  if (s.stages == 2) return &fast_advance<Force, false, RungeKuttaMethod<2>>;
  if (s.stages == 4) return &fast_advance<Force, false, RungeKuttaMethod<4>>;
  return nullptr;
}

// The fast propagation for these settings, or nullptr: then Propagator::advance, which gives
// the same numbers to rounding, 1.5 to 2 times slower
// (about 5 times for Runge–Kutta at d = 3 and degree 4, without a compile-time force table).
// Each fast variant is straight-line code for one basis, propagator and block layout, and
// compiling them all (12 bases x mass matrix or not x 5 propagators) took most of the build,
// so the fast path covers the common shapes only: few vector registers (AVX2, SSE2: a Vec is
// two or four registers and the blocks would spill), a mass matrix, Runge–Kutta methods of one
// or three stages, three coordinates at degree 5, and Runge–Kutta methods for three
// coordinates at degree 4 take the general path (benchmarks/compiled_kernel.py --previous
// times such shapes against a build that had them all).
// A template so that the instruction sets with few registers do not instantiate the blocks.
template <bool MANY = kManyRegisters>
FastAdvanceFn select_fast_advance(const Settings& s) {
  if constexpr (MANY) {
    if (s.has_mass || s.npts != 4 * s.d + 1) return nullptr;
#ifdef SYMPLID_USER_FORCE
    if (s.d == SYMPLID_USER_FORCE::D) return fast_advance_for<SYMPLID_USER_FORCE>(s);
#else
#define SYMPLID_TRY_FAST(D, ORDER) \
  if (FixedBasis<D, ORDER>::matches(s)) return fast_advance_for<PolynomialForce<D, ORDER>>(s);
    SYMPLID_TRY_FAST(1, 2) SYMPLID_TRY_FAST(1, 3) SYMPLID_TRY_FAST(1, 4) SYMPLID_TRY_FAST(1, 5)
    SYMPLID_TRY_FAST(2, 2) SYMPLID_TRY_FAST(2, 3) SYMPLID_TRY_FAST(2, 4) SYMPLID_TRY_FAST(2, 5)
    SYMPLID_TRY_FAST(3, 2) SYMPLID_TRY_FAST(3, 3)
#undef SYMPLID_TRY_FAST
    if (s.composition && FixedBasis<3, 4>::matches(s)) {
      return &fast_advance<PolynomialForce<3, 4>, false, CompositionMethod>;
    }
#endif
  }
  (void)s;
  return nullptr;
}

// ---------------------------------------------------------------- the filter's dense algebra
// The per-gap algebra of eqs (10)-(12) on a lane type T: double for one θ, Vec for a group of
// eight θ sharing the data, lane g holding member g (sigma point k of the group is then the
// vector k of every state row, see run_group). Every lane does the same operations in the same
// order whatever T, so a member's numbers do not depend on its group. Sizes NN (state)
// and DY (observation) are compile-time for the common models, so the small loops unroll
// completely; 0 means "read it from the settings".

// Per-lane square root and logarithm (out-parameters: no Vec crosses a call by value).
SYMPLID_INLINE void lane_sqrt(const double& x, double& r) { r = std::sqrt(x); }
SYMPLID_INLINE void lane_sqrt(const Vec& x, Vec& r) {
#pragma GCC unroll 8
  for (int w = 0; w < kWidth; ++w) r[w] = std::sqrt(x[w]);
}
SYMPLID_INLINE void lane_log(const double& x, double& r) { r = std::log(x); }
SYMPLID_INLINE void lane_log(const Vec& x, Vec& r) {
  for (int w = 0; w < kWidth; ++w) r[w] = std::log(x[w]);
}

// The first `columns` columns of the lower Cholesky factor of the symmetric N x N matrix a
// (row-major, lower triangle read and overwritten), right-looking as in the reference: per
// column j, col = a[:, j] / sqrt(a[j, j]) below the diagonal, then a −= col colᵀ. The factor
// is left in the lower triangle of a; a failed factorisation leaves NaN, never an error. With a
// compile-time N the loops unroll, so the independent divisions and updates of a column
// overlap and only the chain sqrt → division → next diagonal element stays sequential.
template <int FIXED_N, class T>
SYMPLID_INLINE void cholesky_columns(T* __restrict__ a, int runtime_n, int columns) {
  const int N = FIXED_N > 0 ? FIXED_N : runtime_n;
#pragma GCC unroll 16
  for (int j = 0; j < N; ++j) {
    if (j == columns) break;
    T root;
    lane_sqrt(a[j * N + j], root);
#pragma GCC unroll 16
    for (int i = j; i < N; ++i) a[i * N + j] = a[i * N + j] / root;
    if (j == columns - 1) break;
#pragma GCC unroll 16
    for (int i = j + 1; i < N; ++i) {
      const T ci = a[i * N + j];
#pragma GCC unroll 16
      for (int k = j + 1; k <= i; ++k) a[i * N + k] -= ci * a[k * N + j];
    }
  }
}

// The first `columns` pivots of the LDLᵀ factorisation of the symmetric N x N matrix a
// (row-major, lower triangle read), right-looking: per column j the pivot D_j = a_jj, the
// multipliers l_ij = a_ij / D_j below it (left in a's column j), and a −= l a_jᵀ on the
// trailing lower triangle. The Cholesky factor of the reference is l·diag(D)^½, so the two
// agree to rounding; but the dependent chain per column is one division and one multiply-add
// (the square roots are taken off the chain by the caller). A pivot ≤ 0 (not positive definite)
// is left for the caller to detect, as the reference's NaN.
template <int FIXED_N, class T>
SYMPLID_INLINE void ldl_columns(T* __restrict__ a, T* __restrict__ D, int runtime_n,
                                int columns) {
  const int N = FIXED_N > 0 ? FIXED_N : runtime_n;
#pragma GCC unroll 16
  for (int j = 0; j < N; ++j) {
    if (j == columns) break;
    D[j] = a[j * N + j];
    const T inv = 1.0 / D[j];
    if (j < columns - 1) {
#pragma GCC unroll 16
      for (int i = j + 1; i < N; ++i) {
        const T aij = a[i * N + j];
        const T lij = aij * inv;
#pragma GCC unroll 16
        for (int k = j + 1; k < i; ++k) a[i * N + k] -= lij * a[k * N + j];
        a[i * N + i] -= (aij * aij) * inv;  // the next pivot's chain: division, multiply-add
      }
    }
#pragma GCC unroll 16
    for (int i = j + 1; i < N; ++i) a[i * N + j] = a[i * N + j] * inv;
  }
}

// Lane w of a value (the value itself for one lane).
SYMPLID_INLINE double& lane_at(double& v, int) { return v; }
SYMPLID_INLINE double& lane_at(Vec& v, int w) { return reinterpret_cast<double*>(&v)[w]; }
SYMPLID_INLINE double lane_at(const double& v, int) { return v; }
SYMPLID_INLINE double lane_at(const Vec& v, int w) { return v[w]; }

// The sum of a vector's lanes (pairwise: halves, quarters, then the last two).
SYMPLID_INLINE double lane_sum(const Vec& v) {
  typedef double Half __attribute__((vector_size(4 * sizeof(double))));
  typedef double Quarter __attribute__((vector_size(2 * sizeof(double))));
  const Half four = Half{v[0], v[1], v[2], v[3]} + Half{v[4], v[5], v[6], v[7]};
  const Quarter two = Quarter{four[0], four[1]} + Quarter{four[2], four[3]};
  return two[0] + two[1];
}

// ½ Σ_j log x_j per lane: one logarithm of the product where every x_j is positive and the
// product a normal number, else the sum of logarithms (−∞ or NaN for an x_j ≤ 0, as there).
template <class T>
SYMPLID_INLINE void half_log_product(const T* x, int count, T& out) {
  constexpr int lanes = std::is_same<T, Vec>::value ? kWidth : 1;
  for (int w = 0; w < lanes; ++w) {
    double product = 1.0;
    bool positive = true;
    for (int j = 0; j < count; ++j) {
      product = product * lane_at(x[j], w);
      positive = positive && lane_at(x[j], w) > 0.0;
    }
    double sum = 0.0;
    if (positive && product > 1e-300 && product < 1e300) {
      sum = std::log(product);
    } else {
      for (int j = 0; j < count; ++j) sum = sum + std::log(lane_at(x[j], w));
    }
    lane_at(out, w) = 0.5 * sum;
  }
}

// Per-lane filter state (mean, factor, predicted covariance) and the algebra of one gap.
template <class T, int NN, int DY>
class Filter {
 public:
  static constexpr int kJoint = NN > 0 && DY > 0 ? DY + NN + 1 : 0;

  // Members' θ, x0 and P0 per lane (member w % G in lane w); storage from `work`.
  Filter(const Settings& s, const Member* members, int G, T* work) : s_(s) {
    const int n = this->n(), dy = this->dy(), N = dy + n + 1;
    mean = take(work, n);
    chol = take(work, n * n);
    cov = take(work, n * n);
    joint_ = take(work, N * N);
    cross_ = take(work, n * dy);
    predicted_ = take(work, dy);
    s0_ = take(work, dy * dy);
    pivots_ = take(work, N);
    scratch_ = take(work, dy + n);
    centred_ = take(work, n * s.npts);
    process_var_ = take(work, n);
    obs_var_ = take(work, dy);
    x0_ = take(work, n);
    p0_ = take(work, n * n);
    selects_ = selection(s, select_);
    for (int k = 0; kLaneMoments && k < s.npts && k < kRowVectors * kWidth; ++k) {
      wm_lanes_[k / kWidth][k % kWidth] = s.wm[k];
      wc_lanes_[k / kWidth][k % kWidth] = s.wc[k];
    }
    const int first_obs = s.ncoef + (s.diagonal ? n : 1);
    for (int w = 0; w < lanes(); ++w) {
      const Member& m = members[w % G];
      for (int i = 0; i < n; ++i) {
        set(process_var_[i], w, m.theta[s.ncoef + (s.diagonal ? i : 0)]);
        set(x0_[i], w, m.x0[i]);
        for (int k = 0; k < n; ++k) set(p0_[i * n + k], w, m.P0[i * n + k]);
      }
      for (int i = 0; i < dy; ++i) set(obs_var_[i], w, m.theta[first_obs + (s.diagonal ? i : 0)]);
    }
  }

  // T values of workspace the constructor takes.
  static std::size_t workspace(const Settings& s) {
    const int n = s.n, dy = s.dy, N = s.dy + s.n + 1;
    return n + 3 * n * n + N * N + n * dy + 2 * dy + dy * dy + n * s.npts + 2 * n + N +
           dy + n;
  }

  int n() const { return NN > 0 ? NN : s_.n; }
  int dy() const { return DY > 0 ? DY : s_.dy; }

  // x0 and the factor of symmetrise(P0).
  void start() {
    const int n = this->n();
    for (int i = 0; i < n; ++i) mean[i] = x0_[i];
    for (int i = 0; i < n; ++i) {
      for (int k = 0; k < n; ++k) chol[i * n + k] = 0.5 * (p0_[i * n + k] + p0_[k * n + i]);
    }
    cholesky_columns<NN>(chol, n, n);
    zero_upper(chol);
  }

  // The sigma points m, m ± scale·L[:, c]: point k of component i is rows[i][k], where a
  // state row is q's (i < d) or p's row, seen as T values (lanes for one θ, vectors of the
  // group's members otherwise). Padding lanes (one θ) get the centre: finite, never read.
  void sigma_points(Vec* q, Vec* p, int C) const {
    const int n = this->n(), d = n / 2;
#pragma GCC unroll 8
    for (int i = 0; i < n; ++i) {
      T* row = reinterpret_cast<T*>(i < d ? q + i * C : p + (i - d) * C);
      row[0] = mean[i];
#pragma GCC unroll 8
      for (int c = 0; c < n; ++c) {
        const T spread = s_.scale * chol[i * n + c];
        row[1 + c] = mean[i] + spread;
        row[1 + n + c] = mean[i] - spread;
      }
      const int end = static_cast<int>(C * sizeof(Vec) / sizeof(T));
      for (int k = s_.npts; k < end; ++k) row[k] = mean[i];
    }
  }

  // Predicted moments, eq (10): weighted mean and covariance of the propagated points,
  // plus Σ, symmetrised, plus jitter·I (into mean and cov).
  void predicted_moments(const Vec* q, const Vec* p, int C) {
    if constexpr (kLaneMoments) {
      if (C == kRowVectors) return predicted_moments_lanes(q, p);
    }
    const int n = this->n(), d = n / 2, np = NN > 0 ? 2 * NN + 1 : s_.npts;
    const double* wm = s_.wm;
    const double* wc = s_.wc;
    T local_centred[NN > 0 ? NN * (2 * NN + 1) : 1];
    T* __restrict__ c = NN > 0 ? local_centred : centred_;
#pragma GCC unroll 8
    for (int i = 0; i < n; ++i) {
      const T* row = reinterpret_cast<const T*>(i < d ? q + i * C : p + (i - d) * C);
      const T sum = weighted_sum(
          np, [wm](int k) __attribute__((always_inline)) { return wm[k]; },
          [row](int k) __attribute__((always_inline)) { return row[k]; });
      mean[i] = sum;
#pragma GCC unroll 16
      for (int k = 0; k < np; ++k) c[i * np + k] = row[k] - sum;
    }
    // The lower triangle, mirrored (the reference computes both triangles and averages them:
    // equal to rounding); Σ and jitter on the diagonal.
#pragma GCC unroll 8
    for (int i = 0; i < n; ++i) {
      T weighted[NN > 0 ? 2 * NN + 1 : 1];  // wc_k c_ik, shared by the row's entries
      T* wci = NN > 0 ? weighted : joint_;  // (the joint matrix is free until update)
#pragma GCC unroll 16
      for (int k = 0; k < np; ++k) wci[k] = wc[k] * c[i * np + k];
#pragma GCC unroll 8
      for (int j = 0; j <= i; ++j) {
        const T* cj = c + j * np;
        const T sum = weighted_sum(
            np, [wci](int k) __attribute__((always_inline)) { return wci[k]; },
            [cj](int k) __attribute__((always_inline)) { return cj[k]; });
        cov[i * n + j] = sum;
        cov[j * n + i] = sum;
      }
      cov[i * n + i] = (cov[i * n + i] + process_var_[i]) + s_.jitter;
    }
  }

  // Σ_k a_k b_k over the np sigma points. With n known at compile time, in the order of
  // predicted_moments_lanes: per lane position j = k mod kWidth multiply-adds in k from zero,
  // then the kWidth partial sums pairwise as lane_sum; so one θ and a group (T = Vec)
  // give a member the same numbers. Else one chain in k.
  template <class A, class B>
  SYMPLID_INLINE static T weighted_sum(int np, const A& a, const B& b) {
    if constexpr (NN > 0) {
      T acc[kWidth] = {};  // from zero: each sum then holds one product, so contraction into
                          // multiply-adds is the same in every lane type
#pragma GCC unroll 16
      for (int k = 0; k < np; ++k) acc[k % kWidth] = acc[k % kWidth] + a(k) * b(k);
      T four[4];
#pragma GCC unroll 4
      for (int j = 0; j < 4; ++j) four[j] = acc[j] + acc[j + 4];
      const T two0 = four[0] + four[2], two1 = four[1] + four[3];
      return two0 + two1;
    } else {
      T sum{};
      for (int k = 0; k < np; ++k) sum = sum + a(k) * b(k);
      return sum;
    }
  }

  // predicted_moments for one θ with n known at compile time: a row's sigma points are the
  // lanes of kRowVectors vectors, so each weighted sum is lane-wise multiply-adds and one sum
  // across the lanes at the end. The weights are zero on the padding lanes, which hold finite
  // copies of the centre point (sigma_points). The sums are weighted_sum's.
  void predicted_moments_lanes(const Vec* q, const Vec* p) {
    constexpr int n = NN, d = NN / 2, CV = kRowVectors;
    Vec z[NN][CV], wz[NN][CV];
#pragma GCC unroll 8
    for (int i = 0; i < n; ++i) {
      const Vec* row = i < d ? q + i * CV : p + (i - d) * CV;
      Vec acc{};
#pragma GCC unroll 4
      for (int c = 0; c < CV; ++c) acc = acc + wm_lanes_[c] * row[c];
      const double m = lane_sum(acc);
      mean[i] = m;
#pragma GCC unroll 4
      for (int c = 0; c < CV; ++c) {
        z[i][c] = row[c] - m;
        wz[i][c] = wc_lanes_[c] * z[i][c];
      }
    }
#pragma GCC unroll 8
    for (int i = 0; i < n; ++i) {
#pragma GCC unroll 8
      for (int j = 0; j <= i; ++j) {
        Vec acc{};
#pragma GCC unroll 4
        for (int c = 0; c < CV; ++c) acc = acc + wz[i][c] * z[j][c];
        const double sum = lane_sum(acc);
        cov[i * n + j] = sum;
        cov[j * n + i] = sum;
      }
      // Σ and jitter here, as in predicted_moments (a separate pass over the diagonal after
      // both loops measured 10 % slower for one θ)
      cov[i * n + i] = (cov[i * n + i] + process_var_[i]) + s_.jitter;
    }
  }

  // The factor of cov for the next substep's sigma points (noise added per substep).
  void factor_covariance() {
    const int n = this->n();
    for (int i = 0; i < n * n; ++i) chol[i] = cov[i];
    cholesky_columns<NN>(chol, n, n);
    zero_upper(chol);
  }

  // cov = chol cholᵀ (a gap of zero substeps with noise per substep).
  void covariance_from_factor() {
    const int n = this->n();
    for (int i = 0; i < n; ++i) {
      for (int j = 0; j < n; ++j) {
        T sum = T{};
        for (int k = 0; k < n; ++k) sum = sum + chol[i * n + k] * chol[j * n + k];
        cov[i * n + j] = sum;
      }
    }
  }

  // Update and marginalisation, eqs (11)-(12), for the observed components of y: one
  // factorisation of the joint covariance of (y, x) with the innovation as a last row.
  // Adds log p(y_k | y_1..k−1) per lane to total; leaves the filtered mean and factor in mean
  // and chol. (The sum is an out-parameter: no Vec is returned by value.)
  void update(const double* y, const bool* mask, T& total) {
    const int n = this->n(), dy = this->dy(), N = dy + n + 1;
    // With compile-time sizes the joint matrix and the moments are local arrays with constant
    // indices, which the compiler keeps in registers or at fixed stack slots.
    T local_joint[kJoint > 0 ? kJoint * kJoint : 1];
    T local_moments[kJoint > 0 ? NN * DY + DY + DY * DY : 1];
    T* __restrict__ a = kJoint > 0 ? local_joint : joint_;
    T* __restrict__ cross = kJoint > 0 ? local_moments : cross_;
    T* __restrict__ predicted = kJoint > 0 ? cross + NN * DY : predicted_;
    T* __restrict__ s0 = kJoint > 0 ? predicted + DY : s0_;
    observation_moments(predicted, cross, s0);
    int observed = 0;
    for (int i = 0; i < dy; ++i) observed += mask[i] ? 1 : 0;
    // Only the lower triangle is read by the factorisation: every entry of it is set below
    // (zero where a block is masked, and the last row's x columns).
#pragma GCC unroll 8
    for (int i = 0; i < n; ++i) {
#pragma GCC unroll 8
      for (int j = 0; j < dy; ++j) a[(dy + i) * N + j] = T{};
    }
#pragma GCC unroll 8
    for (int j = 0; j < N; ++j) a[(N - 1) * N + j] = T{};
#pragma GCC unroll 8
    for (int i = 0; i < dy; ++i) {  // S block (masked rows and columns → identity)
#pragma GCC unroll 8
      for (int j = 0; j <= i; ++j) {
        T v = T{} + ((i == j) ? 1.0 : 0.0);
        if (mask[i] && mask[j]) {
          const T oi = i == j ? obs_var_[i] : T{};
          v = 0.5 * ((s0[i * dy + j] + oi) + (s0[j * dy + i] + oi));
        }
        a[i * N + j] = v;
      }
    }
#pragma GCC unroll 8
    for (int i = 0; i < n; ++i) {  // C block and P block
#pragma GCC unroll 8
      for (int j = 0; j < dy; ++j) {
        if (mask[j]) a[(dy + i) * N + j] = cross[i * dy + j];
      }
#pragma GCC unroll 8
      for (int j = 0; j <= i; ++j) a[(dy + i) * N + dy + j] = cov[i * n + j];
    }
#pragma GCC unroll 8
    for (int j = 0; j < dy; ++j) {
      if (mask[j]) a[(N - 1) * N + j] = y[j] - predicted[j];
    }
    T pivot[kJoint > 0 ? kJoint : 1];
    T* __restrict__ D = kJoint > 0 ? pivot : pivots_;
    ldl_columns<kJoint>(a, D, N, dy + n);
    // With L = l·diag(D)^½ (the Cholesky factor of the reference): the innovation's row of L
    // is z_j = l_(N−1)j D_j^½, so z·z = Σ l_(N−1)j² D_j; log det L_S = ½ log Π_(j<dy) D_j; the
    // gain's shift is Σ_j L_(dy+i)j z_j = Σ_j l_(dy+i)j (l_(N−1)j D_j); the filtered factor is
    // l_(dy+i)(dy+j) D_(dy+j)^½.
    T zz{}, weighted[kJoint > 0 ? DY : 1];
    T* __restrict__ wz = kJoint > 0 ? weighted : scratch_;
#pragma GCC unroll 8
    for (int j = 0; j < dy; ++j) {
      wz[j] = a[(N - 1) * N + j] * D[j];
      zz = zz + a[(N - 1) * N + j] * wz[j];
    }
    T logdet;
    half_log_product(D, dy, logdet);
    T root[NN > 0 ? NN : 1];
    T* __restrict__ roots = NN > 0 ? root : scratch_ + dy;
#pragma GCC unroll 8
    for (int j = 0; j < n; ++j) lane_sqrt(D[dy + j], roots[j]);
#pragma GCC unroll 8
    for (int i = 0; i < n; ++i) {
      T shift{};
#pragma GCC unroll 8
      for (int j = 0; j < dy; ++j) shift = shift + a[(dy + i) * N + j] * wz[j];
      mean[i] = mean[i] + shift;
#pragma GCC unroll 8
      for (int j = 0; j < n; ++j) {
        chol[i * n + j] = j < i ? a[(dy + i) * N + dy + j] * roots[j] : (j == i ? roots[j] : T{});
      }
    }
    total = total + ((-0.5 * zz - logdet) - 0.5 * observed * kLog2Pi);
  }

  static constexpr int lanes() { return std::is_same<T, Vec>::value ? kWidth : 1; }
  static double get(const T& v, int w) {
    if constexpr (std::is_same<T, Vec>::value) {
      return v[w];
    } else {
      (void)w;
      return v;
    }
  }

 private:
  static constexpr double kLog2Pi = 1.8378770664093454835606594728112;
  // Moments over lanes (predicted_moments_lanes): one θ, n known at compile time.
  static constexpr bool kLaneMoments = std::is_same<T, double>::value && NN > 0;
  static constexpr int kRowVectors = NN > 0 ? (2 * NN + 1 + kWidth - 1) / kWidth : 1;
  Vec wm_lanes_[kRowVectors] = {}, wc_lanes_[kRowVectors] = {};  // zero on padding lanes

  static T* take(T*& work, int size) {
    T* out = work;
    work += size;
    return out;
  }
  static void set(T& v, int w, double x) {
    if constexpr (std::is_same<T, Vec>::value) {
      v[w] = x;
    } else {
      (void)w;
      v = x;
    }
  }

  // ŷ = H m, C = P Hᵀ, S = H C (without Γ): exact moments of a linear observation.
  void observation_moments(T* __restrict__ predicted, T* __restrict__ cross,
                           T* __restrict__ s0) const {
    const int n = this->n(), dy = this->dy();
    const double* H = s_.obs_matrix;
    if (selects_) {  // y = x_sel: the same numbers, without the products by 0 and 1
#pragma GCC unroll 8
      for (int i = 0; i < dy; ++i) predicted[i] = mean[select_[i]];
#pragma GCC unroll 8
      for (int i = 0; i < n; ++i) {
#pragma GCC unroll 8
        for (int j = 0; j < dy; ++j) cross[i * dy + j] = cov[i * n + select_[j]];
      }
#pragma GCC unroll 8
      for (int i = 0; i < dy; ++i) {
#pragma GCC unroll 8
        for (int j = 0; j < dy; ++j) s0[i * dy + j] = cov[select_[i] * n + select_[j]];
      }
      return;
    }
#pragma GCC unroll 8
    for (int i = 0; i < dy; ++i) {
      T sum{};
#pragma GCC unroll 8
      for (int k = 0; k < n; ++k) sum = sum + H[i * n + k] * mean[k];
      predicted[i] = sum;
    }
#pragma GCC unroll 8
    for (int i = 0; i < n; ++i) {
#pragma GCC unroll 8
      for (int j = 0; j < dy; ++j) {
        T sum{};
#pragma GCC unroll 8
        for (int k = 0; k < n; ++k) sum = sum + cov[i * n + k] * H[j * n + k];
        cross[i * dy + j] = sum;
      }
    }
#pragma GCC unroll 8
    for (int i = 0; i < dy; ++i) {
#pragma GCC unroll 8
      for (int j = 0; j < dy; ++j) {
        T sum{};
#pragma GCC unroll 8
        for (int k = 0; k < n; ++k) sum = sum + H[i * n + k] * cross[k * dy + j];
        s0[i * dy + j] = sum;
      }
    }
  }

  void zero_upper(T* a) const {
    const int n = this->n();
    for (int i = 0; i < n; ++i) {
      for (int k = i + 1; k < n; ++k) a[i * n + k] = T{};
    }
  }

  // Whether every row of H is a unit vector (full-state or positions observation), and which.
  static bool selection(const Settings& s, int* select) {
    for (int i = 0; i < s.dy; ++i) {
      int ones = 0, zeros = 0;
      for (int k = 0; k < s.n; ++k) {
        const double h = s.obs_matrix[i * s.n + k];
        ones += h == 1.0 ? 1 : 0;
        zeros += h == 0.0 ? 1 : 0;
        if (h == 1.0 && i < kMaxSelect) select[i] = k;
      }
      if (ones != 1 || zeros != s.n - 1 || i >= kMaxSelect) return false;
    }
    return true;
  }
  static constexpr int kMaxSelect = 64;

  const Settings& s_;
  int select_[kMaxSelect] = {};
  bool selects_ = false;
  T* joint_;
  T* cross_;
  T* predicted_;
  T* s0_;
  T* pivots_;   // the joint factorisation's pivots
  T* scratch_;  // dy + n: the weighted innovation and the pivots' square roots
  T* centred_;
  T* process_var_;  // per component (all equal for isotropic noise)
  T* obs_var_;
  T* x0_;
  T* p0_;

 public:
  T* mean;  // n: filtered (or predicted) mean
  T* chol;  // n x n: lower factor of the filtered covariance
  T* cov;   // n x n: predicted covariance
};

// The filter recursion (Theorem 1) for a group of G members sharing one data set (G is 1, or
// kWidth with T = Vec: then each vector holds one sigma point of the eight members).
template <class Chunks, class T, int NN, int DY>
void run_group(const Settings& s, const TrajectoryData& data, const Member* members, int G,
               Chunks chunks, Workspace& work) {
  using F = Filter<T, NN, DY>;
  const int C = chunks.count();
  Vec* lanes = work.lanes(Propagator<Chunks>::workspace(s, C) +
                          (F::workspace(s) * sizeof(T) + sizeof(Vec) - 1) / sizeof(Vec));
  Propagator<Chunks> prop(s, chunks, lanes);
  const FastAdvanceFn fast = select_fast_advance(s);
  F filter(s, members, G, reinterpret_cast<T*>(lanes + Propagator<Chunks>::workspace(s, C)));

  bool valid[kMaxGroup];
  for (int g = 0; g < G; ++g) {  // variances in θ must be positive
    valid[g] = true;
    for (int v = s.ncoef; v < s.nparams; ++v) valid[g] = valid[g] && members[g].theta[v] > 0.0;
  }
  filter.start();
  for (int t = 0; t < s.num_terms; ++t) {  // c_m e_mj per lane: member g in lane g mod G
    for (int w = 0; w < kWidth; ++w) {
      prop.term_coef[t][w] = members[w % G].theta[s.term_coef_index[t]] * s.term_mult[t];
    }
  }
  auto advance = [&](double dt, int steps) {
    if (fast != nullptr) {
      fast(s, prop.q, prop.p, prop.term_coef, C, G, dt, steps);
    } else {
      prop.advance(dt, steps);
    }
  };
  T total{};
  for (int k = 0; k < data.num_gaps; ++k) {
    const double dt = data.step_size[k];
    int steps = s.uniform ? s.max_steps : static_cast<int>(data.num_steps[k]);
    steps = std::max(0, std::min(steps, s.max_steps));
    if (s.per_step) {
      if (steps == 0) filter.covariance_from_factor();
      for (int st = 0; st < steps; ++st) {
        filter.sigma_points(prop.q, prop.p, C);
        advance(dt, 1);
        filter.predicted_moments(prop.q, prop.p, C);
        filter.factor_covariance();
      }
    } else {
      filter.sigma_points(prop.q, prop.p, C);
      advance(dt, steps);
      filter.predicted_moments(prop.q, prop.p, C);
    }
    filter.update(data.ys + k * s.dy, data.masks + k * s.dy, total);
    bool any_finite = false;
    for (int g = 0; g < G; ++g) {
      any_finite = any_finite || (valid[g] && std::isfinite(F::get(total, g)));
    }
    if (!any_finite) break;  // every member already failed: −∞ for all
  }
  for (int g = 0; g < G; ++g) {
    const double value = F::get(total, g);
    const bool ok = valid[g] && std::isfinite(value);
    *members[g].out = ok ? value : -std::numeric_limits<double>::infinity();
  }
}

// The filter's sizes: compile-time for full-state or position observations of d = 1..3;
// other observations take the run-time sizes and chunk count (one copy of the filter per lane
// type instead of one per chunk count: the fast propagation is the same either way).
template <class Chunks, class T, int NN>
void run_sized(const Settings& s, const TrajectoryData& data, const Member* members, int G,
               Chunks chunks, Workspace& work) {
  if (s.n == NN && s.dy == NN) return run_group<Chunks, T, NN, NN>(s, data, members, G, chunks, work);
  if (s.n == NN && s.dy == NN / 2) {
    return run_group<Chunks, T, NN, NN / 2>(s, data, members, G, chunks, work);
  }
  return run_group<RuntimeChunks, T, 0, 0>(s, data, members, G, RuntimeChunks{chunks.count()},
                                           work);
}

// Entry point for this instruction set: compile-time chunk counts and sizes where common
// (one θ: npts lanes in 1 or 2 vectors; a group: one vector per sigma point).
// (A user's unit compiles the sizes of its force's dimension only.)
constexpr bool compiles_dim(int d) {
#ifdef SYMPLID_USER_FORCE
  return d == SYMPLID_USER_FORCE::D;
#else
  (void)d;
  return true;
#endif
}

void evaluate(const Settings& s, const TrajectoryData& data, const Member* members, int G,
              Workspace& work) {
  const int chunks = (G * s.npts + kWidth - 1) / kWidth;
  if (G == 1) {
    if constexpr (compiles_dim(1)) {
      if (s.d == 1) return run_sized<FixedChunks<1>, double, 2>(s, data, members, G, {}, work);
    }
    if constexpr (compiles_dim(2)) {
      if (s.d == 2) return run_sized<FixedChunks<2>, double, 4>(s, data, members, G, {}, work);
    }
    if constexpr (compiles_dim(3)) {
      if (s.d == 3) return run_sized<FixedChunks<2>, double, 6>(s, data, members, G, {}, work);
    }
    return run_group<RuntimeChunks, double, 0, 0>(s, data, members, G, RuntimeChunks{chunks}, work);
  }
  if constexpr (compiles_dim(1)) {
    if (s.d == 1) return run_sized<FixedChunks<5>, Vec, 2>(s, data, members, G, {}, work);
  }
  if constexpr (compiles_dim(2)) {
    if (s.d == 2) return run_sized<FixedChunks<9>, Vec, 4>(s, data, members, G, {}, work);
  }
  if constexpr (compiles_dim(3)) {
    if (s.d == 3) return run_sized<FixedChunks<13>, Vec, 6>(s, data, members, G, {}, work);
  }
  return run_group<RuntimeChunks, Vec, 0, 0>(s, data, members, G, RuntimeChunks{chunks}, work);
}

}  // namespace SYMPLID_ISA_NS
}  // namespace symplid
