// The compile-time basis of a polynomial potential (eq 13) in D coordinates up to degree ORDER:
// its monomials, the force's term program and the products that build the monomials, as
// constexpr tables. Shared by the value kernel (ukf_kernel_impl.h) and the adjoint's fast
// propagation (ukf_adjoint_fast.cc).
//
// Like ukf_kernel_impl.h this file is included inside an instruction set's namespace (and
// `#pragma GCC target` region) and includes nothing itself: Settings, Vec and the standard
// headers come from ukf_kernel.h.
//
// For d ≤ 2 and ℓ ≤ 5, and for d = 3 and ℓ ≤ 3, the force's term program is built at compile
// time, so the gradient is straight-line code with the lanes in registers (other bases use the
// runtime program, same numbers). The table is the library's basis order
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
    // The monomials of degree 1..ORDER−1 (the first kMono of exps), each the product of two
    // earlier ones (mono_a × mono_b, as balanced as the degrees allow; degree 1: coordinate
    // mono_a, mono_b = −1), and per term its derivative's monomial (−1: a constant).
    int mono_a[kCoef] = {};
    int mono_b[kCoef] = {};
    int term_mono[kMaxTerms] = {};
  };
  static constexpr int kMono = binomial(D + ORDER - 1, D) - 1;

  // Index of the monomial with exponents e in exps (degree ≥ 1), or −1.
  static constexpr int find(const Table& t, const int* e) {
    for (int c = 0; c < kCoef; ++c) {
      bool same = true;
      for (int i = 0; i < D; ++i) same = same && t.exps[c][i] == e[i];
      if (same) return c;
    }
    return -1;
  }

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
    for (int c = 0; c < kMono; ++c) {
      int degree = 0, half[3] = {0, 0, 0}, rest[3] = {0, 0, 0};
      for (int i = 0; i < D; ++i) degree += t.exps[c][i];
      if (degree == 1) {
        for (int i = 0; i < D; ++i) {
          if (t.exps[c][i] == 1) t.mono_a[c] = i;
        }
        t.mono_b[c] = -1;
        continue;
      }
      int left = degree / 2;  // the first half of the powers, coordinate by coordinate
      for (int i = 0; i < D; ++i) {
        half[i] = std::min(left, t.exps[c][i]);
        left -= half[i];
        rest[i] = t.exps[c][i] - half[i];
      }
      t.mono_a[c] = find(t, half);
      t.mono_b[c] = find(t, rest);
    }
    for (int k = 0; k < term; ++k) {
      int e[3] = {0, 0, 0}, degree = 0;
      for (int f = 0; f < t.num_factors[k]; ++f) {
        e[t.factor_coord[k][f]] = t.factor_power[k][f];
        degree += t.factor_power[k][f];
      }
      t.term_mono[k] = degree == 0 ? -1 : find(t, e);
    }
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
