// symplid's compiled likelihood kernel: the UKF log marginal likelihood (Theorem 1,
// eqs 10-12) of the state-space model of eq (7) with a polynomial potential (eq 13), a
// symplectic composition of leapfrog steps (eqs 5-6) or an explicit Runge-Kutta propagator
// over each observation gap (eq 14), and a linear observation operator.
//
// It is an XLA FFI handler ("symplid_ukf_loglik"), called from JAX through jax.ffi.ffi_call,
// with a second one ("symplid_ukf_loglik_grad") for the value and its gradient over θ by the
// adjoint of ukf_adjoint.cc.
// Static settings arrive as attributes, data as buffers. Under vmap (vmap_method
// "expand_dims") every buffer gains the same leading batch axes, of size 1 where that input
// is not batched; the kernel loops over the batch itself and, when the data are shared,
// propagates eight parameter vectors at once so that every vector lane is busy.
//
// The numerical kernel (ukf_kernel_impl.h) is compiled three times, each in its own
// translation unit so that the build runs them in parallel: for AVX-512
// (ukf_kernel_avx512.cc), for AVX2 with FMA (ukf_kernel_avx2.cc) and for the baseline x86-64,
// or whatever the target is elsewhere (ukf_kernel_baseline.cc). The best one the processor
// supports is chosen once at run time. Floating-point contraction is on (fused multiply-adds
// where the instruction set has them), so the variants agree with each other and with the JAX
// reference to rounding, not bit for bit.

#include <cstdlib>
#include <string>
#include <tuple>

#include "ukf_adjoint.h"
#include "ukf_kernel.h"
#include "xla/ffi/api/ffi.h"

namespace ffi = xla::ffi;

namespace symplid {

// The widest instruction set this processor supports, chosen once, or a narrower one named
// by the environment variable SYMPLID_KERNEL_ISA ("avx2" or "baseline": to test or time the
// variants that this processor would not choose; a wider or unknown name is ignored).
enum class Isa { kAvx512, kAvx2, kBaseline };

Isa select_isa() {
  const char* requested = std::getenv("SYMPLID_KERNEL_ISA");
  const std::string cap = requested != nullptr ? requested : "";
  if (cap == "baseline") return Isa::kBaseline;
#ifdef SYMPLID_X86
  __builtin_cpu_init();
  const bool avx2 = __builtin_cpu_supports("avx2") && __builtin_cpu_supports("fma");
  if (cap != "avx2" && avx2 && __builtin_cpu_supports("avx512f") &&
      __builtin_cpu_supports("avx512vl") && __builtin_cpu_supports("avx512dq")) {
    return Isa::kAvx512;
  }
  if (avx2) return Isa::kAvx2;
#endif
  return Isa::kBaseline;
}

// The instruction set this process runs with (the choice is made on the first call).
Isa isa() {
  static const Isa chosen = select_isa();
  return chosen;
}

EvaluateFn kernel() {
#ifdef SYMPLID_USER_FORCE
  return SYMPLID_ISA_NS::evaluate;  // a user's unit: compiled for one instruction set
#endif
#ifdef SYMPLID_X86
  if (isa() == Isa::kAvx512) return avx512::evaluate;
  if (isa() == Isa::kAvx2) return avx2::evaluate;
#endif
  return baseline::evaluate;
}

const char* kernel_isa() {
#ifdef SYMPLID_USER_ISA
  return SYMPLID_USER_ISA;
#endif
  switch (isa()) {
    case Isa::kAvx512:
      return "avx512";
    case Isa::kAvx2:
      return "avx2";
    default:
      return "baseline";
  }
}

namespace {

// A buffer seen through the batch axes that vmap added in front of its own `rank` axes.
struct Batched {
  const char* data;
  std::size_t item_bytes;       // bytes of one unbatched item
  std::vector<int64_t> stride;  // per batch axis, in items (0 where the axis has size 1)

  std::size_t offset(const std::vector<int64_t>& index) const {
    std::size_t items = 0;
    for (std::size_t a = 0; a < index.size(); ++a) items += index[a] * stride[a];
    return items * item_bytes;
  }
  bool shared() const {
    return std::all_of(stride.begin(), stride.end(), [](int64_t s) { return s == 0; });
  }
};

ffi::Error batched(const ffi::AnyBuffer& buffer, std::size_t rank,
                   const std::vector<int64_t>& batch, const char* name, Batched* out) {
  const auto dims = buffer.dimensions();
  if (dims.size() != batch.size() + rank) {
    return ffi::Error(ffi::ErrorCode::kInvalidArgument,
                      std::string("symplid kernel: wrong rank for ") + name);
  }
  std::size_t items = 1;
  for (std::size_t a = batch.size(); a < dims.size(); ++a) items *= dims[a];
  out->data = static_cast<const char*>(buffer.untyped_data());
  out->item_bytes = items * ffi::ByteWidth(buffer.element_type());
  out->stride.assign(batch.size(), 0);
  int64_t stride = 1;
  for (std::size_t a = batch.size(); a-- > 0;) {
    if (dims[a] != 1 && dims[a] != batch[a]) {
      return ffi::Error(ffi::ErrorCode::kInvalidArgument,
                        std::string("symplid kernel: batch axes do not match for ") + name);
    }
    out->stride[a] = dims[a] == 1 ? 0 : stride;
    stride *= dims[a];
  }
  return ffi::Error::Success();
}

// Reads the settings from the attributes and checks their sizes against each other.
ffi::Error read_settings(Settings& s, int64_t dim, int64_t order, ffi::Span<const int64_t> exps,
                         int64_t composition, ffi::Span<const double> comp_w,
                         ffi::Span<const double> rk_a, ffi::Span<const double> rk_b,
                         int64_t has_mass, ffi::Span<const double> inv_mass,
                         ffi::Span<const double> obs_matrix, ffi::Span<const double> wm,
                         ffi::Span<const double> wc, double scale, double jitter,
                         int64_t per_step, int64_t diagonal, int64_t max_steps, int64_t uniform) {
  s.d = static_cast<int>(dim);
  s.n = 2 * s.d;
  s.npts = 2 * s.n + 1;
  s.order = static_cast<int>(order);
  s.ncoef = static_cast<int>(exps.size() / std::max<int64_t>(dim, 1));
  s.dy = static_cast<int>(obs_matrix.size() / std::max(s.n, 1));
  s.exponents = exps.begin();
  s.composition = composition != 0;
  s.comp_w = comp_w.begin();
  s.ncomp = static_cast<int>(comp_w.size());
  s.rk_a = rk_a.begin();
  s.rk_b = rk_b.begin();
  s.stages = s.composition ? 0 : static_cast<int>(rk_b.size());
  s.has_mass = has_mass != 0;
  s.inv_mass = inv_mass.begin();
  s.obs_matrix = obs_matrix.begin();
  s.wm = wm.begin();
  s.wc = wc.begin();
  s.scale = scale;
  s.jitter = jitter;
  s.per_step = per_step != 0;
  s.diagonal = diagonal != 0;
  s.max_steps = static_cast<int>(max_steps);
  s.uniform = uniform != 0;
  s.nparams = s.ncoef + (s.diagonal ? s.n + s.dy : 2);
  const bool ok = s.d >= 1 && s.order >= 1 && exps.size() == std::size_t(s.ncoef) * s.d &&
                  obs_matrix.size() == std::size_t(s.dy) * s.n && s.dy >= 1 &&
                  wm.size() == std::size_t(s.npts) && wc.size() == std::size_t(s.npts) &&
                  (!s.has_mass || inv_mass.size() == std::size_t(s.d) * s.d) &&
                  (s.composition ? s.ncomp >= 1
                                 : rk_a.size() == std::size_t(s.stages) * s.stages);
  if (!ok) {
    return ffi::Error(ffi::ErrorCode::kInvalidArgument, "symplid kernel: inconsistent settings");
  }
  return ffi::Error::Success();
}

// Compiles the basis into the force's term program (Settings::term_*), in basis order.
// A user's unit (SYMPLID_USER_FORCE): term t is θ's parameter t, the force's own program
// reads them (no factors).
void build_terms(Settings& s, Workspace& w) {
  const int d = s.d, width = s.order + 1;
  w.term_start.assign(1, 0);
  w.term_coef_index.clear();
  w.term_mult.clear();
  w.factor_start.assign(1, 0);
  w.factor_rows.clear();
#ifdef SYMPLID_USER_FORCE
  for (int m = 0; m < s.ncoef; ++m) {
    w.term_coef_index.push_back(m);
    w.term_mult.push_back(1.0);
    w.factor_start.push_back(0);
  }
  w.term_start.push_back(s.ncoef);
  for (int j = 1; j < d; ++j) w.term_start.push_back(s.ncoef);
  (void)width;
#else
  for (int j = 0; j < d; ++j) {
    for (int m = 0; m < s.ncoef; ++m) {
      const int64_t* e = s.exponents + m * d;
      if (e[j] == 0) continue;
      w.term_coef_index.push_back(m);
      w.term_mult.push_back(static_cast<double>(e[j]));
      for (int i = 0; i < d; ++i) {
        const int64_t power = e[i] - (i == j ? 1 : 0);
        if (power > 0) w.factor_rows.push_back(i * width + static_cast<int>(power));
      }
      w.factor_start.push_back(static_cast<int>(w.factor_rows.size()));
    }
    w.term_start.push_back(static_cast<int>(w.term_coef_index.size()));
  }
#endif
  s.num_terms = static_cast<int>(w.term_coef_index.size());
  s.term_start = w.term_start.data();
  s.term_coef_index = w.term_coef_index.data();
  s.term_mult = w.term_mult.data();
  s.factor_start = w.factor_start.data();
  s.factor_rows = w.factor_rows.data();
}

// The batch of one call: the settings, the buffers seen through vmap's batch axes, and
// per batch element its member and data (a row-major walk of the batch multi-index).
struct Call {
  Settings s;
  std::vector<int64_t> batch;
  int64_t total = 1;
  int gaps = 0;
  bool shared_data = false;
  Batched th, m0, c0, dt, ns, y, mk;
  std::vector<int64_t> index;

  // The next batch element's member (its result at out) and, if `data`, its data.
  Member next(double* out, TrajectoryData* data) {
    Member m;
    m.theta = reinterpret_cast<const double*>(th.data + th.offset(index));
    m.x0 = reinterpret_cast<const double*>(m0.data + m0.offset(index));
    m.P0 = reinterpret_cast<const double*>(c0.data + c0.offset(index));
    m.out = out;
    if (data != nullptr) {
      data->num_gaps = gaps;
      data->step_size = reinterpret_cast<const double*>(dt.data + dt.offset(index));
      data->num_steps = reinterpret_cast<const int64_t*>(ns.data + ns.offset(index));
      data->ys = reinterpret_cast<const double*>(y.data + y.offset(index));
      data->masks = reinterpret_cast<const bool*>(mk.data + mk.offset(index));
    }
    for (std::size_t a = batch.size(); a-- > 0;) {  // row-major increment
      if (++index[a] < batch[a]) break;
      index[a] = 0;
    }
    return m;
  }
};

// The attributes of both handlers, in their order of binding.
#define SYMPLID_KERNEL_ATTRIBUTES                                                              \
  int64_t dim, int64_t order, ffi::Span<const int64_t> exponents, int64_t composition,        \
      ffi::Span<const double> comp_w, ffi::Span<const double> rk_a,                           \
      ffi::Span<const double> rk_b, int64_t has_mass, ffi::Span<const double> inv_mass,       \
      ffi::Span<const double> obs_matrix, ffi::Span<const double> wm,                         \
      ffi::Span<const double> wc, double scale, double jitter, int64_t per_step,              \
      int64_t diagonal, int64_t max_steps, int64_t uniform
#define SYMPLID_KERNEL_ATTRIBUTE_NAMES                                                         \
  dim, order, exponents, composition, comp_w, rk_a, rk_b, has_mass, inv_mass, obs_matrix, wm, \
      wc, scale, jitter, per_step, diagonal, max_steps, uniform

// Reads and checks the settings and the (batched) buffers; the batch is the shape of out.
ffi::Error prepare(Call& call, Workspace& work, const ffi::AnyBuffer& theta,
                   const ffi::AnyBuffer& x0, const ffi::AnyBuffer& P0,
                   const ffi::AnyBuffer& step_size, const ffi::AnyBuffer& num_steps,
                   const ffi::AnyBuffer& ys, const ffi::AnyBuffer& masks,
                   const ffi::AnyBuffer& out, SYMPLID_KERNEL_ATTRIBUTES) {
  Settings& s = call.s;
  if (auto err = read_settings(s, dim, order, exponents, composition, comp_w, rk_a, rk_b,
                               has_mass, inv_mass, obs_matrix, wm, wc, scale, jitter, per_step,
                               diagonal, max_steps, uniform);
      !err.success()) {
    return err;
  }
  for (int64_t e : exponents) {
    if (e < 0 || e > order) {
      return ffi::Error(ffi::ErrorCode::kInvalidArgument, "symplid kernel: bad exponents");
    }
  }
  build_terms(s, work);
  if (theta.element_type() != ffi::F64 || x0.element_type() != ffi::F64 ||
      P0.element_type() != ffi::F64 || step_size.element_type() != ffi::F64 ||
      num_steps.element_type() != ffi::S64 || ys.element_type() != ffi::F64 ||
      masks.element_type() != ffi::PRED || out.element_type() != ffi::F64) {
    return ffi::Error(ffi::ErrorCode::kInvalidArgument, "symplid kernel: wrong dtypes");
  }
  const auto out_dims = out.dimensions();
  call.batch.assign(out_dims.begin(), out_dims.end());
  for (auto [buf, rank, name, view] :
       {std::tuple{&theta, 1, "theta", &call.th}, std::tuple{&x0, 1, "x0", &call.m0},
        std::tuple{&P0, 2, "P0", &call.c0}, std::tuple{&step_size, 1, "step_size", &call.dt},
        std::tuple{&num_steps, 1, "num_steps", &call.ns}, std::tuple{&ys, 2, "ys", &call.y},
        std::tuple{&masks, 2, "masks", &call.mk}}) {
    if (auto err = batched(*buf, rank, call.batch, name, view); !err.success()) return err;
  }
  const auto gaps = step_size.dimensions().back();
  if (theta.dimensions().back() != s.nparams || x0.dimensions().back() != s.n ||
      ys.dimensions().back() != s.dy || num_steps.dimensions().back() != gaps ||
      ys.dimensions()[ys.dimensions().size() - 2] != gaps) {
    return ffi::Error(ffi::ErrorCode::kInvalidArgument, "symplid kernel: wrong shapes");
  }
  call.gaps = static_cast<int>(gaps);
  for (int64_t b : call.batch) call.total *= b;
  call.shared_data = call.dt.shared() && call.ns.shared() && call.y.shared() && call.mk.shared();
  call.index.assign(call.batch.size(), 0);
  return ffi::Error::Success();
}

}  // namespace

// The FFI handler: reads the settings and the (batched) buffers, then evaluates every batch
// element, in groups of kMaxGroup where the data are shared.
ffi::Error log_likelihood(ffi::AnyBuffer theta, ffi::AnyBuffer x0, ffi::AnyBuffer P0,
                          ffi::AnyBuffer step_size, ffi::AnyBuffer num_steps, ffi::AnyBuffer ys,
                          ffi::AnyBuffer masks, ffi::Result<ffi::AnyBuffer> out,
                          SYMPLID_KERNEL_ATTRIBUTES) {
  const EvaluateFn evaluate = kernel();
  thread_local Workspace work;
  Call call;
  if (auto err = prepare(call, work, theta, x0, P0, step_size, num_steps, ys, masks, *out,
                         SYMPLID_KERNEL_ATTRIBUTE_NAMES);
      !err.success()) {
    return err;
  }
  double* result = static_cast<double*>(out->untyped_data());
  for (int64_t start = 0; start < call.total;) {
    const int G = (call.shared_data && call.total - start >= kMaxGroup) ? kMaxGroup : 1;
    Member members[kMaxGroup];
    TrajectoryData data;
    for (int g = 0; g < G; ++g) members[g] = call.next(result + start + g, g == 0 ? &data : nullptr);
    evaluate(call.s, data, members, G, work);
    start += G;
  }
  return ffi::Error::Success();
}

// The gradient's FFI handler: per batch element log L (out) and ∂ log L/∂θ (grad, the
// batch then θ's entries), by the adjoint (ukf_adjoint.cc), one element at a time.
ffi::Error log_likelihood_gradient(ffi::AnyBuffer theta, ffi::AnyBuffer x0, ffi::AnyBuffer P0,
                                   ffi::AnyBuffer step_size, ffi::AnyBuffer num_steps,
                                   ffi::AnyBuffer ys, ffi::AnyBuffer masks,
                                   ffi::Result<ffi::AnyBuffer> out,
                                   ffi::Result<ffi::AnyBuffer> grad, SYMPLID_KERNEL_ATTRIBUTES) {
  thread_local Workspace work;
  thread_local AdjointWorkspace adjoint_work;
  Call call;
  if (auto err = prepare(call, work, theta, x0, P0, step_size, num_steps, ys, masks, *out,
                         SYMPLID_KERNEL_ATTRIBUTE_NAMES);
      !err.success()) {
    return err;
  }
  const int P = call.s.nparams;
  if (!adjoint_supports(call.s) || grad->element_type() != ffi::F64 ||
      grad->element_count() != static_cast<std::size_t>(call.total * P)) {
    return ffi::Error(ffi::ErrorCode::kInvalidArgument, "symplid kernel: bad gradient output");
  }
  double* result = static_cast<double*>(out->untyped_data());
  double* gradients = static_cast<double*>(grad->untyped_data());
  for (int64_t b = 0; b < call.total; ++b) {
    TrajectoryData data;
    const Member member = call.next(result + b, &data);
    adjoint_gradient(call.s, data, member, gradients + b * P, adjoint_work);
  }
  return ffi::Error::Success();
}

}  // namespace symplid

// The buffers and attributes of both handlers (the gradient's adds one result).
#define SYMPLID_BIND_BUFFERS                  \
  ffi::Ffi::Bind()                            \
      .Arg<ffi::AnyBuffer>() /* theta */      \
      .Arg<ffi::AnyBuffer>() /* x0 */         \
      .Arg<ffi::AnyBuffer>() /* P0 */         \
      .Arg<ffi::AnyBuffer>() /* step_size */  \
      .Arg<ffi::AnyBuffer>() /* num_steps */  \
      .Arg<ffi::AnyBuffer>() /* ys */         \
      .Arg<ffi::AnyBuffer>() /* masks */      \
      .Ret<ffi::AnyBuffer>() /* log L */
#define SYMPLID_BIND_ATTRIBUTES                              \
  .Attr<int64_t>("dim")                                      \
      .Attr<int64_t>("order")                                \
      .Attr<ffi::Span<const int64_t>>("exponents")           \
      .Attr<int64_t>("composition")                          \
      .Attr<ffi::Span<const double>>("comp_weights")         \
      .Attr<ffi::Span<const double>>("rk_a")                 \
      .Attr<ffi::Span<const double>>("rk_b")                 \
      .Attr<int64_t>("has_mass")                             \
      .Attr<ffi::Span<const double>>("inv_mass")             \
      .Attr<ffi::Span<const double>>("obs_matrix")           \
      .Attr<ffi::Span<const double>>("weights_mean")         \
      .Attr<ffi::Span<const double>>("weights_cov")          \
      .Attr<double>("scale")                                 \
      .Attr<double>("jitter")                                \
      .Attr<int64_t>("per_step")                             \
      .Attr<int64_t>("diagonal")                             \
      .Attr<int64_t>("max_steps")                            \
      .Attr<int64_t>("uniform")

XLA_FFI_DEFINE_HANDLER_SYMBOL(SymplidUkfLogLikelihood, symplid::log_likelihood,
                              SYMPLID_BIND_BUFFERS SYMPLID_BIND_ATTRIBUTES);
XLA_FFI_DEFINE_HANDLER_SYMBOL(SymplidUkfLogLikelihoodGradient, symplid::log_likelihood_gradient,
                              SYMPLID_BIND_BUFFERS.Ret<ffi::AnyBuffer>() /* ∂ log L/∂θ */
                                  SYMPLID_BIND_ATTRIBUTES);

// The instruction set the kernel runs with ("avx512", "avx2" or "baseline"), for reports.
extern "C" const char* symplid_kernel_isa() { return symplid::kernel_isa(); }
