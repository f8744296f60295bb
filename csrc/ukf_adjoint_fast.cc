// The adjoint's propagation over one gap (ukf_adjoint.cc) for the common bases, compiled for
// AVX2 with FMA: the same arithmetic as the adjoint's general Propagation, with the basis's
// term program fixed at compile time (ukf_basis.h, as the value kernel's fast path) and all
// sigma points of a coordinate in NB vectors of four lanes, held in registers for the whole
// gap. The forward sweep records the positions at every force evaluation; the reverse sweep
// reads them back and applies, per kick p −= κ ∇U(q), q̄ −= κ ∇²U(q) p̄ (the force's Jacobian
// from the same monomials, in closed form) and accumulates κ p̄_j monomial_t per force term t
// (the coefficients' adjoint, summed over the lanes by the caller), and per drift q += h p,
// p̄ += h q̄. Used where the processor has AVX2 and FMA and the model has no mass matrix.

#include <cstdlib>
#include <string>

#include "ukf_adjoint.h"

#pragma GCC push_options
#pragma GCC target("avx2,fma")

namespace symplid {
namespace adjoint_fast {

#include "ukf_basis.h"

// Four lanes: one AVX2 register (wider generic vectors are split by the compiler, badly for
// broadcasts of scalars).
typedef double Lanes __attribute__((vector_size(4 * sizeof(double))));

// Unaligned moves between the caller's arrays and registers (no Vec crosses a call by value).
SYMPLID_INLINE void load(const double* x, Lanes& v) { __builtin_memcpy(&v, x, sizeof(Lanes)); }
SYMPLID_INLINE void store(double* x, const Lanes& v) { __builtin_memcpy(x, &v, sizeof(Lanes)); }

constexpr int kLanes = sizeof(Lanes) / sizeof(double);

// Per force term t (component j of ∇U, monomial μ_t) and coordinate i: ∂μ_t/∂q_i =
// pow[t][i] · monomial mono[t][i] (−1: the constant 1), so that ∂²U/∂q_i∂q_j =
// Σ_(t of component j) c_t pow[t][i] monomial.
template <int D, int ORDER>
struct Derivatives {
  using Basis = FixedBasis<D, ORDER>;
  static constexpr auto kBasis = Basis::kTable;
  static constexpr int kTerms = kBasis.start[D];
  struct Table {
    int term_j[kTerms] = {};
    int pow[kTerms][D] = {};
    int mono[kTerms][D] = {};
  };
  static constexpr Table table() {
    Table h{};
    for (int j = 0; j < D; ++j) {
      for (int t = kBasis.start[j]; t < kBasis.start[j + 1]; ++t) h.term_j[t] = j;
    }
    for (int t = 0; t < kTerms; ++t) {
      int e[3] = {0, 0, 0};
      for (int f = 0; f < kBasis.num_factors[t]; ++f) {
        e[kBasis.factor_coord[t][f]] = kBasis.factor_power[t][f];
      }
      for (int i = 0; i < D; ++i) {
        h.pow[t][i] = e[i];
        h.mono[t][i] = -1;
        if (e[i] == 0) continue;
        int g[3] = {e[0], e[1], e[2]};
        g[i] -= 1;
        h.mono[t][i] = g[0] + g[1] + g[2] == 0 ? -1 : Basis::find(kBasis, g);
      }
    }
    return h;
  }
  static constexpr Table kTable = table();
};

template <int D, int ORDER, int NB>
struct FastPsi {
  using Basis = FixedBasis<D, ORDER>;
  using Deriv = Derivatives<D, ORDER>;
  static constexpr auto kBasis = Basis::kTable;
  static constexpr auto kDeriv = Deriv::kTable;
  static constexpr int kTerms = Deriv::kTerms;
  static constexpr int kMono = Basis::kMono > 0 ? Basis::kMono : 1;

  SYMPLID_INLINE static void monomials(const Lanes (&x)[D], Lanes (&mono)[kMono]) {
#pragma GCC unroll 64
    for (int c = 0; c < Basis::kMono; ++c) {
      mono[c] = kBasis.mono_b[c] < 0 ? x[kBasis.mono_a[c]]
                                     : mono[kBasis.mono_a[c]] * mono[kBasis.mono_b[c]];
    }
  }

  // p −= κ ∇U(q) for one block of lanes, the force as Basis's Horner program.
  SYMPLID_INLINE static void kick(const Lanes (&q)[D], Lanes (&p)[D], const Lanes& kappa,
                                  const Lanes (&tc)[kTerms]) {
    Lanes force[D];
    Basis::template horner_add<false>(
        q, [&tc](int t) __attribute__((always_inline)) { return tc[t]; }, force);
#pragma GCC unroll 16
    for (int j = 0; j < D; ++j) p[j] = p[j] - kappa * force[j];
  }

  // The adjoint of kick at q for one block: q̄ −= κ ∇²U(q) p̄, acc_t += κ p̄_j μ_t.
  SYMPLID_INLINE static void kick_reverse(const Lanes (&q)[D], Lanes (&qb)[D], const Lanes (&pb)[D],
                                          Lanes (&acc)[kTerms], const Lanes& kappa,
                                          const Lanes (&hc)[kTerms][D]) {
    Lanes mono[kMono], kp[D];
    monomials(q, mono);
#pragma GCC unroll 16
    for (int j = 0; j < D; ++j) kp[j] = kappa * pb[j];
#pragma GCC unroll 128
    for (int t = 0; t < kTerms; ++t) {
      const int j = kDeriv.term_j[t];
      const int m = kBasis.term_mono[t];
      acc[t] = m < 0 ? acc[t] + kp[j] : acc[t] + kp[j] * mono[m];
#pragma GCC unroll 16
      for (int i = 0; i < D; ++i) {
        if (kDeriv.pow[t][i] == 0) continue;
        const int h = kDeriv.mono[t][i];
        qb[i] = h < 0 ? qb[i] - hc[t][i] * kp[j] : qb[i] - (hc[t][i] * mono[h]) * kp[j];
      }
    }
  }

  static double drift_of(const Settings& s, double dt, int sub) {
    return s.comp_w[sub % s.ncomp] * dt;
  }
  static double kick_of(const Settings& s, double dt, int sub, int total) {
    if (sub < 0) return 0.5 * drift_of(s, dt, 0);
    const double next = sub + 1 < total ? drift_of(s, dt, sub + 1) : 0.0;
    return 0.5 * drift_of(s, dt, sub) + 0.5 * next;
  }

  static void forward(const Settings& s, double dt, int steps, int NP, double* q, double* p,
                      double* qs, const double* tc) {
    const int total = steps * s.ncomp;
    Lanes Q[NB][D], P[NB][D], TC[kTerms];
    for (int t = 0; t < kTerms; ++t) TC[t] = Lanes{} + tc[t];
    for (int b = 0; b < NB; ++b) {
      for (int i = 0; i < D; ++i) {
        load(q + i * NP + b * kLanes, Q[b][i]);
        load(p + i * NP + b * kLanes, P[b][i]);
        store(qs + i * NP + b * kLanes, Q[b][i]);
      }
    }
    if (total == 0) return;
    const Lanes first = Lanes{} + kick_of(s, dt, -1, total);
#pragma GCC unroll 4
    for (int b = 0; b < NB; ++b) kick(Q[b], P[b], first, TC);
    for (int sub = 0; sub < total; ++sub) {
      const Lanes h = Lanes{} + drift_of(s, dt, sub), kappa = Lanes{} + kick_of(s, dt, sub, total);
      double* out = qs + (sub + 1) * D * NP;
#pragma GCC unroll 4
      for (int b = 0; b < NB; ++b) {
#pragma GCC unroll 16
        for (int i = 0; i < D; ++i) {
          Q[b][i] = Q[b][i] + h * P[b][i];
          store(out + i * NP + b * kLanes, Q[b][i]);
        }
        kick(Q[b], P[b], kappa, TC);
      }
    }
    for (int b = 0; b < NB; ++b) {
      for (int i = 0; i < D; ++i) {
        store(q + i * NP + b * kLanes, Q[b][i]);
        store(p + i * NP + b * kLanes, P[b][i]);
      }
    }
  }

  static void reverse(const Settings& s, double dt, int steps, int NP, const double* qs,
                      double* qb, double* pb, const double* tc, double* tacc) {
    const int total = steps * s.ncomp;
    if (total == 0) return;
    Lanes QB[NB][D], PB[NB][D], ACC[NB][kTerms], HC[kTerms][D];
    for (int t = 0; t < kTerms; ++t) {
      for (int i = 0; i < D; ++i) HC[t][i] = Lanes{} + tc[t] * kDeriv.pow[t][i];
    }
    for (int b = 0; b < NB; ++b) {
      for (int i = 0; i < D; ++i) {
        load(qb + i * NP + b * kLanes, QB[b][i]);
        load(pb + i * NP + b * kLanes, PB[b][i]);
      }
      for (int t = 0; t < kTerms; ++t) ACC[b][t] = Lanes{};
    }
    for (int sub = total - 1; sub >= -1; --sub) {
      const Lanes kappa = Lanes{} + kick_of(s, dt, sub, total);
      const Lanes h = Lanes{} + (sub >= 0 ? drift_of(s, dt, sub) : 0.0);
      const double* at = qs + (sub + 1) * D * NP;
#pragma GCC unroll 4
      for (int b = 0; b < NB; ++b) {
        Lanes X[D];
#pragma GCC unroll 16
        for (int i = 0; i < D; ++i) load(at + i * NP + b * kLanes, X[i]);
        kick_reverse(X, QB[b], PB[b], ACC[b], kappa, HC);
#pragma GCC unroll 16
        for (int i = 0; i < D; ++i) PB[b][i] = PB[b][i] + h * QB[b][i];
      }
    }
    for (int b = 0; b < NB; ++b) {
      for (int i = 0; i < D; ++i) {
        store(qb + i * NP + b * kLanes, QB[b][i]);
        store(pb + i * NP + b * kLanes, PB[b][i]);
      }
      for (int t = 0; t < kTerms; ++t) {
        double* row = tacc + t * NP + b * kLanes;
        Lanes sum;
        load(row, sum);
        store(row, sum + ACC[b][t]);
      }
    }
  }
};

}  // namespace adjoint_fast
}  // namespace symplid

#pragma GCC pop_options

namespace symplid {

namespace {

// Whether the processor has AVX2 and FMA, unless SYMPLID_KERNEL_ISA names "baseline" (as for
// the value kernel: to test the general path on a processor that would not take it).
bool fast_isa() {
#ifdef SYMPLID_X86
  const char* requested = std::getenv("SYMPLID_KERNEL_ISA");
  if (requested != nullptr && std::string(requested) == "baseline") return false;
  __builtin_cpu_init();
  return __builtin_cpu_supports("avx2") && __builtin_cpu_supports("fma");
#else
  return false;
#endif
}

}  // namespace

FastPropagation select_fast_propagation(const Settings& s) {
#ifdef SYMPLID_X86
  static const bool usable = fast_isa();
  if (s.has_mass || !s.composition || !usable) return {};
#define SYMPLID_TRY_FAST(D, ORDER)                                                  \
  if (adjoint_fast::FixedBasis<D, ORDER>::matches(s)) {                             \
    using Psi = adjoint_fast::FastPsi<D, ORDER, (4 * D + 1 + 3) / 4>;               \
    return {&Psi::forward, &Psi::reverse};                                          \
  }
  SYMPLID_TRY_FAST(1, 2) SYMPLID_TRY_FAST(1, 3) SYMPLID_TRY_FAST(1, 4) SYMPLID_TRY_FAST(1, 5)
  SYMPLID_TRY_FAST(2, 2) SYMPLID_TRY_FAST(2, 3) SYMPLID_TRY_FAST(2, 4) SYMPLID_TRY_FAST(2, 5)
  SYMPLID_TRY_FAST(3, 2) SYMPLID_TRY_FAST(3, 3)
#undef SYMPLID_TRY_FAST
#else
  (void)s;
#endif
  return {};
}

}  // namespace symplid
