// The functions a user's force (a generated unit, see ukf_user.h) calls, for one lane
// (double) and for a vector of eight (Vec), lane by lane with the C library's functions. With
// SYMPLID_USER_MVEC (x86-64 with glibc's vector math library, libmvec) the vector forms of
// exp, log, sin, cos, tan, their hyperbolic and inverse forms call its eight-, four- or
// two-lane variants instead (accurate to a few units in the last place, like the scalar
// ones). sqrt and the powers are exact or correctly rounded either way.

#ifndef SYMPLID_UKF_USER_MATH_H_
#define SYMPLID_UKF_USER_MATH_H_

#include <cmath>

#include "ukf_kernel.h"

namespace symplid {
namespace user_math {

// x^N for an integer N ≥ 1 by repeated squaring (the same products in every lane type).
template <int N, class T>
SYMPLID_INLINE T pown(const T& x) {
  if constexpr (N == 1) {
    return x;
  } else if constexpr (N % 2 == 0) {
    const T h = pown<N / 2>(x);
    return h * h;
  } else {
    return pown<N - 1>(x) * x;
  }
}

SYMPLID_INLINE double sqrt(double x) { return std::sqrt(x); }
SYMPLID_INLINE Vec sqrt(const Vec& x) {
  Vec r;
#pragma GCC unroll 8
  for (int w = 0; w < 8; ++w) r[w] = std::sqrt(x[w]);
  return r;
}
SYMPLID_INLINE double abs(double x) { return std::fabs(x); }
SYMPLID_INLINE Vec abs(const Vec& x) {
  Vec r;
#pragma GCC unroll 8
  for (int w = 0; w < 8; ++w) r[w] = std::fabs(x[w]);
  return r;
}
// sign(x) (0 at 0), the derivative of abs.
SYMPLID_INLINE double sign(double x) { return x > 0.0 ? 1.0 : (x < 0.0 ? -1.0 : 0.0); }
SYMPLID_INLINE Vec sign(const Vec& x) {
  Vec r;
#pragma GCC unroll 8
  for (int w = 0; w < 8; ++w) r[w] = x[w] > 0.0 ? 1.0 : (x[w] < 0.0 ? -1.0 : 0.0);
  return r;
}

#if defined(SYMPLID_USER_MVEC) && defined(__x86_64__)
#if defined(__AVX512F__)
#define SYMPLID_MVEC_WIDTH 8
#define SYMPLID_MVEC_NAME(f) _ZGVeN8v_##f
#define SYMPLID_MVEC_NAME2(f) _ZGVeN8vv_##f
#elif defined(__AVX2__)
#define SYMPLID_MVEC_WIDTH 4
#define SYMPLID_MVEC_NAME(f) _ZGVdN4v_##f
#define SYMPLID_MVEC_NAME2(f) _ZGVdN4vv_##f
#else
#define SYMPLID_MVEC_WIDTH 2
#define SYMPLID_MVEC_NAME(f) _ZGVbN2v_##f
#define SYMPLID_MVEC_NAME2(f) _ZGVbN2vv_##f
#endif
typedef double MvecLanes __attribute__((vector_size(SYMPLID_MVEC_WIDTH * sizeof(double))));
#define SYMPLID_MVEC_LIST(X) \
  X(exp) X(log) X(sin) X(cos) X(tan) X(sinh) X(cosh) X(tanh) X(asin) X(acos) X(atan)
#define SYMPLID_MVEC_DECLARE(f) extern "C" MvecLanes SYMPLID_MVEC_NAME(f)(MvecLanes);
SYMPLID_MVEC_LIST(SYMPLID_MVEC_DECLARE)
extern "C" MvecLanes SYMPLID_MVEC_NAME2(atan2)(MvecLanes, MvecLanes);
#undef SYMPLID_MVEC_DECLARE
#define SYMPLID_VEC_FUNCTION(f)                                             \
  SYMPLID_INLINE double f(double x) { return std::f(x); }                   \
  SYMPLID_INLINE Vec f(const Vec& x) {                                      \
    Vec r;                                                                  \
    for (int w = 0; w < 8; w += SYMPLID_MVEC_WIDTH) {                       \
      MvecLanes a, b;                                                       \
      __builtin_memcpy(&a, reinterpret_cast<const double*>(&x) + w, sizeof a); \
      b = SYMPLID_MVEC_NAME(f)(a);                                          \
      __builtin_memcpy(reinterpret_cast<double*>(&r) + w, &b, sizeof b);    \
    }                                                                       \
    return r;                                                               \
  }
SYMPLID_MVEC_LIST(SYMPLID_VEC_FUNCTION)
#undef SYMPLID_VEC_FUNCTION
SYMPLID_INLINE double atan2(double y, double x) { return std::atan2(y, x); }
SYMPLID_INLINE Vec atan2(const Vec& y, const Vec& x) {
  Vec r;
  for (int w = 0; w < 8; w += SYMPLID_MVEC_WIDTH) {
    MvecLanes a, b, c;
    __builtin_memcpy(&a, reinterpret_cast<const double*>(&y) + w, sizeof a);
    __builtin_memcpy(&b, reinterpret_cast<const double*>(&x) + w, sizeof b);
    c = SYMPLID_MVEC_NAME2(atan2)(a, b);
    __builtin_memcpy(reinterpret_cast<double*>(&r) + w, &c, sizeof c);
  }
  return r;
}
#else
#define SYMPLID_VEC_FUNCTION(f)                              \
  SYMPLID_INLINE double f(double x) { return std::f(x); }    \
  SYMPLID_INLINE Vec f(const Vec& x) {                       \
    Vec r;                                                   \
    for (int w = 0; w < 8; ++w) r[w] = std::f(x[w]);         \
    return r;                                                \
  }
SYMPLID_VEC_FUNCTION(exp) SYMPLID_VEC_FUNCTION(log) SYMPLID_VEC_FUNCTION(sin)
SYMPLID_VEC_FUNCTION(cos) SYMPLID_VEC_FUNCTION(tan) SYMPLID_VEC_FUNCTION(sinh)
SYMPLID_VEC_FUNCTION(cosh) SYMPLID_VEC_FUNCTION(tanh) SYMPLID_VEC_FUNCTION(asin)
SYMPLID_VEC_FUNCTION(acos) SYMPLID_VEC_FUNCTION(atan)
#undef SYMPLID_VEC_FUNCTION
SYMPLID_INLINE double atan2(double y, double x) { return std::atan2(y, x); }
SYMPLID_INLINE Vec atan2(const Vec& y, const Vec& x) {
  Vec r;
  for (int w = 0; w < 8; ++w) r[w] = std::atan2(y[w], x[w]);
  return r;
}
#endif

// x^y for a real y (lane by lane: exp(y log x) loses digits for large |y log x|).
SYMPLID_INLINE double pow(double x, double y) { return std::pow(x, y); }
SYMPLID_INLINE Vec pow(const Vec& x, double y) {
  Vec r;
  for (int w = 0; w < 8; ++w) r[w] = std::pow(x[w], y);
  return r;
}

}  // namespace user_math
}  // namespace symplid

#endif  // SYMPLID_UKF_USER_MATH_H_
