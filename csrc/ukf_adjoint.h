// The gradient over θ of the UKF log marginal likelihood (Theorem 1, eqs 10-12) as an adjoint:
// a forward sweep that computes the value and records what the reverse sweep needs, then one
// reverse sweep over the gaps (ukf_adjoint.cc). Scalar double code over one θ, compiled once
// (it is not part of the per-instruction-set kernels), for the symplectic compositions with
// Σ added once per gap; other models keep the JAX tier's gradient.

#ifndef SYMPLID_UKF_ADJOINT_H_
#define SYMPLID_UKF_ADJOINT_H_

#include <cstddef>
#include <vector>

#include "ukf_kernel.h"

namespace symplid {

// The force's and its Jacobian's program for the adjoint, built from the basis.
struct ForceProgram {
  // Monomials of degree 1..order−1, each the product of an earlier one (or 1) and a coordinate.
  std::vector<int> mono_parent;  // −1: the coordinate alone
  std::vector<int> mono_coord;
  // ∂U/∂q_j = Σ_t c_m(t) mult_t mono_t (mono −1: the constant 1).
  std::vector<int> term_j, term_m, term_mono;
  std::vector<double> term_mult;
  // ∂²U/∂q_i∂q_j (i ≤ j) = Σ_h c_m(h) mult_h mono_h.
  std::vector<int> hess_i, hess_j, hess_m, hess_mono;
  std::vector<double> hess_mult;
};

// Ψ over one gap for every sigma point (d rows of NP lanes) with the positions at every force
// evaluation recorded in qs, and its adjoint, for a basis fixed at compile time
// (ukf_adjoint_fast.cc); tc holds c_m e_mj per force term, tacc the coefficients' adjoint per
// term and lane.
using FastForwardFn = void (*)(const Settings&, double dt, int steps, int NP, double* q,
                               double* p, double* qs, const double* tc);
using FastReverseFn = void (*)(const Settings&, double dt, int steps, int NP, const double* qs,
                               double* qb, double* pb, const double* tc, double* tacc);
struct FastPropagation {
  FastForwardFn forward = nullptr;
  FastReverseFn reverse = nullptr;
};

// The fast propagation for these settings, or nullptrs (then the general one, same numbers to
// rounding): a composition without a mass matrix, a basis of the value kernel's fast path, on
// a processor with AVX2 and FMA.
FastPropagation select_fast_propagation(const Settings& s);

// Reused buffers (one per thread): the tape of the forward sweep and the reverse's arrays.
struct AdjointWorkspace {
  std::vector<double> tape;
  std::vector<std::size_t> gap_offset;
  std::vector<double> scratch;
  ForceProgram program;
  std::vector<int64_t> program_exponents;  // the basis the program was built for
  int program_dim = 0;
  FastPropagation fast;
  std::vector<int> steps;  // per gap
};

// Whether adjoint_gradient carries these settings (a composition of leapfrog steps, Σ once
// per gap); the caller (symplid/model/_kernel.py) routes other models to the JAX tier's gradient.
bool adjoint_supports(const Settings& s);

// log L at the member's θ into *member.out and ∂ log L/∂θ (s.nparams entries) into grad,
// with the JAX tier's conventions off the support (see ukf_adjoint.cc).
void adjoint_gradient(const Settings& s, const TrajectoryData& data, const Member& member,
                      double* grad, AdjointWorkspace& work);

}  // namespace symplid

#endif  // SYMPLID_UKF_ADJOINT_H_
