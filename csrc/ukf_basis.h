// The compile-time basis of a polynomial potential (eq 13) in D coordinates up to degree ORDER:
// its monomials, the force's term program, the products that build the monomials and the
// force as a Horner program (horner_add), as constexpr tables. Shared by the value kernel
// (ukf_kernel_impl.h) and the adjoint's fast propagation (ukf_adjoint_fast.cc).
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

  // The force's components as multivariate Horner schemes, for the fast propagation: per
  // component j a straight-line program whose op o writes register o. Splitting the terms by
  // one coordinate at a time, P = x_v P1 + P0 with P1 = (the terms holding x_v) / x_v, split
  // again by x_v, and P0 = the others, split by the next coordinates; so each term's
  // coefficient enters once and the dependent chain is (degree + D − 1) multiply-adds long,
  // where products of powers followed by a sum over the terms take about twice as long. The
  // component's initial value (a momentum, so that a kick is one program) is added where the
  // constant term sits. The reference's polynomial, associated differently: equal to rounding.
  enum HornerKind { kHornerConst, kHornerInit, kHornerFma, kHornerMul };
  struct HornerOp {
    int kind = kHornerConst;
    int var = 0;   // x_var (kHornerFma, kHornerMul)
    int a = 0;     // x_var r_a (+ r_b)
    int b = 0;
    int term = -1; // the coefficient (kHornerConst, kHornerInit; −1: the initial value alone)
  };
  static constexpr int kMaxOps = 2 * (kCoef + 1);
  struct Horner {
    HornerOp ops[D][kMaxOps] = {};
    int count[D] = {};
  };
  // A set of a component's terms with the powers not yet taken out; term −1 is the initial
  // value (all powers zero).
  struct TermSet {
    int n = 0;
    int term[kCoef + 1] = {};
    int e[kCoef + 1][3] = {};
  };

  // Appends the program of Σ_s coefficient x^e from coordinate v on; returns its register.
  static constexpr int emit(Horner& h, int j, const TermSet& set, int v) {
    if (v == D) {  // all powers taken out: one term at most, and perhaps the initial value
      HornerOp op{};
      for (int k = 0; k < set.n; ++k) {
        if (set.term[k] < 0) op.kind = kHornerInit;
        else op.term = set.term[k];
      }
      h.ops[j][h.count[j]] = op;
      return h.count[j]++;
    }
    TermSet with{}, without{};
    for (int k = 0; k < set.n; ++k) {
      TermSet& to = set.e[k][v] > 0 ? with : without;
      to.term[to.n] = set.term[k];
      for (int i = 0; i < D; ++i) to.e[to.n][i] = set.e[k][i] - (i == v && set.e[k][v] > 0);
      ++to.n;
    }
    if (with.n == 0) return emit(h, j, without, v + 1);
    const int a = emit(h, j, with, v);
    HornerOp op{};
    op.var = v;
    op.a = a;
    if (without.n == 0) {
      op.kind = kHornerMul;
    } else {
      op.kind = kHornerFma;
      op.b = emit(h, j, without, v + 1);
    }
    h.ops[j][h.count[j]] = op;
    return h.count[j]++;
  }

  static constexpr Horner horner() {
    Horner h{};
    for (int j = 0; j < D; ++j) {
      TermSet all{};
      for (int t = kTable.start[j]; t < kTable.start[j + 1]; ++t) {
        all.term[all.n] = t;
        for (int f = 0; f < kTable.num_factors[t]; ++f) {
          all.e[all.n][kTable.factor_coord[t][f]] = kTable.factor_power[t][f];
        }
        ++all.n;
      }
      all.term[all.n++] = -1;  // the initial value
      emit(h, j, all, 0);
    }
    return h;
  }
  static constexpr Horner kHorner = horner();

  // acc_j + Σ_t coef(t) x^(e_t) over component j's terms, into acc (the force with acc = 0
  // and coef(t) = c_m e_mj; a kick p − k ∂U/∂q with acc = p and coef(t) = −k c_m e_mj).
  // INIT false: acc's values are not read (a force from zero, without adding zeros).
  template <bool INIT, class T, class Coef>
  SYMPLID_INLINE static void horner_add(const T (&x)[D], const Coef& coef, T (&acc)[D]) {
#pragma GCC unroll 16
    for (int j = 0; j < D; ++j) {
      T r[kMaxOps];
#pragma GCC unroll 256
      for (int o = 0; o < kHorner.count[j]; ++o) {
        const HornerOp& op = kHorner.ops[j][o];
        if (op.kind == kHornerConst) {
          r[o] = coef(op.term);
        } else if (op.kind == kHornerInit) {
          if (INIT) {
            r[o] = op.term < 0 ? acc[j] : acc[j] + coef(op.term);
          } else {
            r[o] = op.term < 0 ? T{} : coef(op.term);
          }
        } else if (op.kind == kHornerFma) {
          r[o] = x[op.var] * r[op.a] + r[op.b];
        } else {
          r[o] = x[op.var] * r[op.a];
        }
      }
      acc[j] = r[kHorner.count[j] - 1];
    }
  }

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
