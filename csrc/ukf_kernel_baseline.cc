// The numerical kernel for the compiler's default target (x86-64's SSE2, or whatever the
// platform is): the fallback that every processor runs. Its own translation unit, so that the
// build compiles the instruction sets in parallel.

#include "ukf_kernel.h"

#define SYMPLID_ISA_NS baseline
#define SYMPLID_MANY_REGISTERS 0
#include "ukf_kernel_impl.h"
