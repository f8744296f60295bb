// The dense algebra of the adjoint (ukf_adjoint.cc): Cholesky factorisation and triangular
// solves, the Cholesky factorisation in reverse, one gap's record on the tape, and the update
// of eqs (11)-(12) forward and in reverse (the formulas are in ukf_adjoint.cc's header).
// Sizes are template arguments where common (0: at run time), so that the small loops unroll.
//
// Included by ukf_adjoint.cc inside its anonymous namespace; it includes nothing itself.

// The sizes and the settings one evaluation uses.
struct Dims {
  int d, n, dy, npts, NP, nc;
};

// Lower Cholesky factor of the symmetric n x n matrix a (lower triangle read) into l (upper
// triangle zero); NaN where a is not positive definite.
template <int FN>
SYMPLID_INLINE void cholesky(const double* a, double* l, int rn) {
  const int n = FN > 0 ? FN : rn;
  for (int i = 0; i < n * n; ++i) l[i] = 0.0;
  for (int j = 0; j < n; ++j) {
    double diag = a[j * n + j];
    for (int k = 0; k < j; ++k) diag -= l[j * n + k] * l[j * n + k];
    const double root = std::sqrt(diag);
    l[j * n + j] = root;
    for (int i = j + 1; i < n; ++i) {
      double sum = a[i * n + j];
      for (int k = 0; k < j; ++k) sum -= l[i * n + k] * l[j * n + k];
      l[i * n + j] = sum / root;
    }
  }
}

// x = L⁻ᵀ b for the lower factor L (n x n) and b with `cols` columns (n x cols), in place.
template <int FN, int FC>
SYMPLID_INLINE void solve_upper_transposed(const double* l, double* b, int rn, int rc) {
  const int n = FN > 0 ? FN : rn, cols = FC > 0 ? FC : rc;
  for (int c = 0; c < cols; ++c) {
    for (int i = n - 1; i >= 0; --i) {
      double sum = b[i * cols + c];
      for (int k = i + 1; k < n; ++k) sum -= l[k * n + i] * b[k * cols + c];
      b[i * cols + c] = sum / l[i * n + i];
    }
  }
}

// x = L⁻¹ b in place (forward substitution), b n x cols.
template <int FN, int FC>
SYMPLID_INLINE void solve_lower(const double* l, double* b, int rn, int rc) {
  const int n = FN > 0 ? FN : rn, cols = FC > 0 ? FC : rc;
  for (int c = 0; c < cols; ++c) {
    for (int i = 0; i < n; ++i) {
      double sum = b[i * cols + c];
      for (int k = 0; k < i; ++k) sum -= l[i * n + k] * b[k * cols + c];
      b[i * cols + c] = sum / l[i * n + i];
    }
  }
}

// The adjoint of P = L Lᵀ: P̄ (symmetric) from L̄ (lower; its upper triangle is ignored).
template <int FN>
void cholesky_reverse(const double* l, const double* lbar, double* pbar, double* tmp, int rn) {
  const int n = FN > 0 ? FN : rn;
  double* g = tmp;  // M = Lᵀ L̄, then G = ½(Φ(M) + Φ(M)ᵀ)
  for (int i = 0; i < n; ++i) {
    for (int j = 0; j <= i; ++j) {
      double sum = 0.0;
      for (int k = i; k < n; ++k) sum += l[k * n + i] * lbar[k * n + j];  // (Lᵀ L̄)_ij, L̄ lower
      g[i * n + j] = 0.5 * sum;  // G_ij = ½ M_ij below and on the diagonal, mirrored
      g[j * n + i] = 0.5 * sum;
    }
  }
  solve_upper_transposed<FN, FN>(l, g, n, n);  // Z = L⁻ᵀ G
  for (int i = 0; i < n; ++i) {        // Zᵀ
    for (int j = 0; j < n; ++j) pbar[i * n + j] = g[j * n + i];
  }
  solve_upper_transposed<FN, FN>(l, pbar, n, n);  // L⁻ᵀ Zᵀ = P̄ᵀ = P̄
  for (int i = 0; i < n; ++i) {
    for (int j = 0; j < i; ++j) {
      const double v = 0.5 * (pbar[i * n + j] + pbar[j * n + i]);
      pbar[i * n + j] = v;
      pbar[j * n + i] = v;
    }
  }
}

// One gap's record on the tape (pointers into it) and its size.
struct GapRecord {
  double* qs;     // (S + 1) x d x NP: positions at every force evaluation
  double* pend;   // d x NP: final momenta
  double* mpred;  // n: predicted mean m⁻
  double* lpost;  // n x n: filtered factor L⁺
  double* sinv;   // o x o: S⁻¹ of the observed components
  double* gain;   // n x o: K = C S⁻¹
  double* a;      // o: S⁻¹ v
  int* obs;       // o observed components, then o itself at obs[dy]
  static std::size_t size(const Dims& z, int steps, int ncomp) {
    const std::size_t S = static_cast<std::size_t>(steps) * ncomp;
    return (S + 2) * z.d * z.NP + z.n + z.n * z.n + z.dy * z.dy + z.n * z.dy + z.dy +
           (z.dy + 1 + 1) / 2 + 1;
  }
  GapRecord(double* at, const Dims& z, int steps, int ncomp) {
    const std::size_t S = static_cast<std::size_t>(steps) * ncomp;
    qs = at;
    pend = qs + (S + 1) * z.d * z.NP;
    mpred = pend + z.d * z.NP;
    lpost = mpred + z.n;
    sinv = lpost + z.n * z.n;
    gain = sinv + z.dy * z.dy;
    a = gain + z.n * z.dy;
    obs = reinterpret_cast<int*>(a + z.dy);
  }
  int observed(const Dims& z) const { return obs[z.dy]; }
};

// The update (eqs 11-12) in the forward sweep: from m⁻ (mean) and P⁻ (cov) to m⁺ (mean) and
// L⁺ (rec.lpost); returns the log-likelihood term.
// NN, O: n and the number of observed components at compile time (0: at run time).
template <int NN, int O>
double update_forward(const Settings& s, const Dims& z, const double* y, const double* obs_var,
                      double* mean, const double* cov, GapRecord& rec, double* tmp) {
  const int n = NN > 0 ? NN : z.n, o = O > 0 ? O : rec.observed(z);
  const double* H = s.obs_matrix;
  double* C = tmp;             // n x o
  double* S = C + n * o;       // o x o
  double* LS = S + o * o;      // o x o
  double* v = LS + o * o;      // o
  double* P = v + o;           // n x n
  for (int i = 0; i < n; ++i) {
    for (int r = 0; r < o; ++r) {
      double sum = 0.0;
      for (int k = 0; k < n; ++k) sum += cov[i * n + k] * H[rec.obs[r] * n + k];
      C[i * o + r] = sum;
    }
  }
  for (int r = 0; r < o; ++r) {
    for (int c = 0; c < o; ++c) {
      double sum = 0.0;
      for (int k = 0; k < n; ++k) sum += H[rec.obs[r] * n + k] * C[k * o + c];
      S[r * o + c] = sum;
    }
  }
  for (int r = 0; r < o; ++r) {
    for (int c = 0; c < r; ++c) {
      const double sym = 0.5 * (S[r * o + c] + S[c * o + r]);
      S[r * o + c] = sym;
      S[c * o + r] = sym;
    }
    S[r * o + r] += obs_var[rec.obs[r]];
  }
  cholesky<O>(S, LS, o);
  double logdet = 0.0;
  for (int r = 0; r < o; ++r) logdet += std::log(LS[r * o + r]);
  for (int r = 0; r < o; ++r) {  // S⁻¹ = L_S⁻ᵀ L_S⁻¹
    for (int c = 0; c < o; ++c) rec.sinv[r * o + c] = r == c ? 1.0 : 0.0;
  }
  solve_lower<O, O>(LS, rec.sinv, o, o);
  solve_upper_transposed<O, O>(LS, rec.sinv, o, o);
  for (int r = 0; r < o; ++r) {
    double sum = 0.0;
    for (int k = 0; k < n; ++k) sum += H[rec.obs[r] * n + k] * mean[k];
    v[r] = y[rec.obs[r]] - sum;
  }
  double quad = 0.0;
  for (int r = 0; r < o; ++r) {
    double sum = 0.0;
    for (int c = 0; c < o; ++c) sum += rec.sinv[r * o + c] * v[c];
    rec.a[r] = sum;
    quad += v[r] * sum;
  }
  for (int i = 0; i < n; ++i) {
    for (int r = 0; r < o; ++r) {
      double sum = 0.0;
      for (int c = 0; c < o; ++c) sum += C[i * o + c] * rec.sinv[c * o + r];
      rec.gain[i * o + r] = sum;
    }
    double shift = 0.0;
    for (int r = 0; r < o; ++r) shift += C[i * o + r] * rec.a[r];
    rec.mpred[i] = mean[i];
    mean[i] += shift;
  }
  for (int i = 0; i < n; ++i) {
    for (int j = 0; j <= i; ++j) {
      double sum = 0.0;
      for (int r = 0; r < o; ++r) sum += rec.gain[i * o + r] * C[j * o + r];
      P[i * n + j] = cov[i * n + j] - sum;
    }
  }
  cholesky<NN>(P, rec.lpost, n);
  return (-0.5 * quad - logdet) - 0.5 * o * kLog2Pi;
}

// The adjoint of update_forward: from m̄⁺ (mbar) and P̄⁺ (pbar, symmetric) to m̄⁻ (mbar) and
// P̄⁻ (pbar), adding Γ̄ per observed component to obs_bar.
template <int NN, int O>
void update_reverse(const Settings& s, const Dims& z, const GapRecord& rec, double* mbar,
                    double* pbar, double* obs_bar, double* tmp) {
  const int n = NN > 0 ? NN : z.n, o = O > 0 ? O : rec.observed(z);
  const double* H = s.obs_matrix;
  const double* K = rec.gain;
  double* b = tmp;           // o: Kᵀ m̄⁺
  double* vbar = b + o;      // o
  double* Sbar = vbar + o;   // o x o
  double* PK = Sbar + o * o; // n x o: P̄⁺ K
  double* Cbar = PK + n * o; // n x o
  double* M = Cbar + n * o;  // n x n: C̄ H_O
  for (int r = 0; r < o; ++r) {
    double sum = 0.0;
    for (int i = 0; i < n; ++i) sum += K[i * o + r] * mbar[i];
    b[r] = sum;
    vbar[r] = sum - rec.a[r];
  }
  for (int i = 0; i < n; ++i) {
    for (int r = 0; r < o; ++r) {
      double sum = 0.0;
      for (int k = 0; k < n; ++k) sum += pbar[i * n + k] * K[k * o + r];
      PK[i * o + r] = sum;
      Cbar[i * o + r] = mbar[i] * rec.a[r] - 2.0 * sum;
    }
  }
  for (int r = 0; r < o; ++r) {
    for (int c = 0; c < o; ++c) {
      double sum = 0.0;
      for (int i = 0; i < n; ++i) sum += K[i * o + r] * PK[i * o + c];
      Sbar[r * o + c] = 0.5 * (rec.a[r] * rec.a[c] - rec.sinv[r * o + c]) -
                        0.5 * (b[r] * rec.a[c] + rec.a[r] * b[c]) + sum;
    }
  }
  for (int r = 0; r < o; ++r) obs_bar[rec.obs[r]] += Sbar[r * o + r];
  for (int i = 0; i < n; ++i) {  // m̄⁻ = m̄⁺ − H_Oᵀ v̄
    double sum = 0.0;
    for (int r = 0; r < o; ++r) sum += H[rec.obs[r] * n + i] * vbar[r];
    mbar[i] -= sum;
  }
  for (int i = 0; i < n; ++i) {  // C̄ H_O
    for (int j = 0; j < n; ++j) {
      double sum = 0.0;
      for (int r = 0; r < o; ++r) sum += Cbar[i * o + r] * H[rec.obs[r] * n + j];
      M[i * n + j] = sum;
    }
  }
  for (int i = 0; i < n; ++i) {  // P̄⁻ = P̄⁺ + H_Oᵀ S̄ H_O + sym(C̄ H_O)
    for (int j = 0; j < n; ++j) {
      double sum = 0.0;
      for (int r = 0; r < o; ++r) {
        const double* hr = H + rec.obs[r] * n;
        double inner = 0.0;
        for (int c = 0; c < o; ++c) inner += Sbar[r * o + c] * H[rec.obs[c] * n + j];
        sum += hr[i] * inner;
      }
      pbar[i * n + j] += sum + 0.5 * (M[i * n + j] + M[j * n + i]);
    }
  }
}

// The update's forward and reverse with the observed count at compile time where all of
// DY components are observed.
template <int NN, int DY>
double update_forward(const Settings& s, const Dims& z, const double* y, const bool* mask,
                      const double* obs_var, double* mean, const double* cov, GapRecord& rec,
                      double* tmp) {
  int o = 0;
  for (int r = 0; r < z.dy; ++r) {
    if (mask[r]) rec.obs[o++] = r;
  }
  rec.obs[z.dy] = o;
  if (DY > 0 && o == DY) return update_forward<NN, DY>(s, z, y, obs_var, mean, cov, rec, tmp);
  return update_forward<NN, 0>(s, z, y, obs_var, mean, cov, rec, tmp);
}
template <int NN, int DY>
void update_reverse_for(const Settings& s, const Dims& z, const GapRecord& rec, double* mbar,
                        double* pbar, double* obs_bar, double* tmp) {
  if (DY > 0 && rec.observed(z) == DY) {
    return update_reverse<NN, DY>(s, z, rec, mbar, pbar, obs_bar, tmp);
  }
  update_reverse<NN, 0>(s, z, rec, mbar, pbar, obs_bar, tmp);
}
