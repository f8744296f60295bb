// The rest of a user model's compiled unit, included at the end of the unit that the library
// generates from the user's U(q; θ) (symplid/model/_user_kernel.py). The generated part
// defines the force policy (ukf_kernel_impl.h's PolynomialForce is the built-in one):
//
//   struct Force {
//     static constexpr int D;            // coordinates
//     static constexpr int kTerms;       // θ's parameters, read as coef(t)
//     static constexpr bool kTabled = false;
//     static constexpr bool kScalarLane = false;  // one θ's last sigma point in a vector
//     template <bool INIT, class T, class Coef>   // acc = ∂U/∂q(x) (INIT false only)
//     static void add(const T (&x)[D], const Coef& coef, T (&acc)[D]);
//     template <class T, class Coef>              // the adjoint's kick, for a vector v:
//     static void adjoint(const T (&x)[D], const Coef& coef, const T (&v)[D],
//                         T (&hv)[D], T* pv);     // hv = ∇²U v, pv_t = v · ∂∇U/∂θ_t
//   };
//
// and SYMPLID_USER_FORCE (its name), SYMPLID_USER_ISA (the instruction set it is compiled
// for, also set on the compiler's command line) and SYMPLID_MANY_REGISTERS. The unit is then
// the value kernel for that instruction set only (ukf_kernel_impl.h, the sizes of the force's
// dimension only), the adjoint (ukf_adjoint.cc, its kicks the force's) and the FFI handlers
// (ukf_kernel.cc): the filter and the propagators are the built-in kernel's, the force alone
// is the user's.

#ifndef SYMPLID_USER_FORCE
#error "define the force policy SYMPLID_USER_FORCE before including ukf_user.h"
#endif

#define SYMPLID_ISA_NS user
#include "ukf_kernel_impl.h"
#include "ukf_adjoint.cc"
#include "ukf_kernel.cc"
