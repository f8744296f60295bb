// The numerical kernel for AVX-512 (with AVX2 and FMA instructions available: the build's
// floating-point contraction fuses multiply-adds). Its own translation unit, so
// that the build compiles the instruction sets in parallel; compiled to nothing off x86.

#include "ukf_kernel.h"

#ifdef SYMPLID_X86
#pragma GCC push_options
#pragma GCC target("avx512f,avx512vl,avx512dq,avx2,fma")
#define SYMPLID_ISA_NS avx512
#define SYMPLID_MANY_REGISTERS 1
#include "ukf_kernel_impl.h"
#pragma GCC pop_options
#endif
