// The types shared by symplid's compiled likelihood kernel (ukf_kernel.cc, the FFI handler)
// and its numerical kernel, compiled once per instruction set in its own translation unit
// (ukf_kernel_avx512.cc, ukf_kernel_avx2.cc, ukf_kernel_baseline.cc, each including
// ukf_kernel_impl.h inside a `#pragma GCC target` region). This header is included before
// any such region, so that everything it defines (and the standard library's inline code)
// is compiled for the baseline instruction set only.

#ifndef SYMPLID_UKF_KERNEL_H_
#define SYMPLID_UKF_KERNEL_H_

#include <algorithm>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <limits>
#include <type_traits>
#include <utility>
#include <vector>

#if defined(__GNUC__) && (defined(__x86_64__) || defined(__i386__))
#define SYMPLID_X86 1
#endif

// Forces inlining of the small functions of the hot loops (the substep and the force), so
// that a block of sigma points stays in registers for a whole gap.
#define SYMPLID_INLINE inline __attribute__((always_inline))

namespace symplid {

// Largest number of parameter vectors propagated together.
constexpr int kMaxGroup = 8;

// The model's static settings (views into the call's attributes).
struct Settings {
  int d = 0;       // coordinates q (the state has n = 2d components)
  int n = 0;       // state dimension
  int dy = 0;      // observed components
  int npts = 0;    // sigma points, 2n + 1
  int order = 0;   // highest total degree of U
  int ncoef = 0;   // coefficients of U
  int nparams = 0; // entries of θ
  const int64_t* exponents = nullptr;  // ncoef x d, the monomial basis
  bool composition = true;             // leapfrog composition (else Runge-Kutta)
  const double* comp_w = nullptr;      // leapfrog sub-step weights
  int ncomp = 0;
  const double* rk_a = nullptr;  // stages x stages Butcher matrix
  const double* rk_b = nullptr;  // stages weights
  int stages = 0;
  bool has_mass = false;
  const double* inv_mass = nullptr;    // d x d, M⁻¹
  const double* obs_matrix = nullptr;  // dy x n, H
  const double* wm = nullptr;          // npts mean weights
  const double* wc = nullptr;          // npts covariance weights
  double scale = 0.0;                  // sqrt(n + λ)
  double jitter = 0.0;
  bool per_step = false;  // Σ after every substep (else once per gap)
  bool diagonal = false;  // one variance per component (else one each)
  int max_steps = 0;
  bool uniform = false;  // every gap has max_steps substeps
  // The force as a program of terms (c_m e_mj) Π x_i^power, for j = 0..d-1 in turn.
  int num_terms = 0;
  const int* term_start = nullptr;      // d + 1: terms of component j are [start[j], start[j+1])
  const int* term_coef_index = nullptr; // per term: m
  const double* term_mult = nullptr;    // per term: e_mj
  const int* factor_start = nullptr;    // num_terms + 1
  const int* factor_rows = nullptr;     // per factor: i * (order + 1) + power
};

// Eight lanes of doubles: one AVX-512 register, two AVX2 or four SSE2 registers.
typedef double Vec __attribute__((vector_size(8 * sizeof(double))));

// Reused buffers (one per thread): lane arrays and the members' small matrices.
struct Workspace {
  // At least `count` vectors, aligned to a whole vector.
  Vec* lanes(std::size_t count) {
    lane_storage.resize((count + 1) * kVecDoubles);
    const auto address = reinterpret_cast<std::uintptr_t>(lane_storage.data());
    const std::size_t skip = (sizeof(Vec) - address % sizeof(Vec)) % sizeof(Vec);
    return reinterpret_cast<Vec*>(lane_storage.data() + skip / sizeof(double));
  }
  static constexpr std::size_t kVecDoubles = sizeof(Vec) / sizeof(double);
  std::vector<double> lane_storage;
  std::vector<int> term_start, term_coef_index, factor_start, factor_rows;
  std::vector<double> term_mult;
};

// One trajectory's observations and gap structure.
struct TrajectoryData {
  int num_gaps = 0;
  const double* step_size = nullptr;  // per gap
  const int64_t* num_steps = nullptr; // per gap
  const double* ys = nullptr;         // num_gaps x dy
  const bool* masks = nullptr;        // num_gaps x dy
};

// One evaluation: θ, the initial state's mean and covariance, where the result goes.
struct Member {
  const double* theta = nullptr;
  const double* x0 = nullptr;
  const double* P0 = nullptr;
  double* out = nullptr;
};


// One evaluation of a group of members (the entry point of each instruction set's kernel).
using EvaluateFn = void (*)(const Settings&, const TrajectoryData&, const Member*, int,
                            Workspace&);

#ifdef SYMPLID_X86
namespace avx512 {
void evaluate(const Settings& s, const TrajectoryData& data, const Member* members, int G,
              Workspace& work);
}  // namespace avx512
namespace avx2 {
void evaluate(const Settings& s, const TrajectoryData& data, const Member* members, int G,
              Workspace& work);
}  // namespace avx2
#endif
namespace baseline {
void evaluate(const Settings& s, const TrajectoryData& data, const Member* members, int G,
              Workspace& work);
}  // namespace baseline

}  // namespace symplid

#endif  // SYMPLID_UKF_KERNEL_H_
