// Fused CPU kernel for the multi-resolution hash encoding (Instant-NGP, Mueller et al. 2022, Sec. 3).
//
// Same semantics as Nerfstudio's torch fallback (``HashEncoding.pytorch_fwd``) and the torch path in
// ``nerfify_ns/runtime/hashgrid.py``:
//
//   corner  = floor(p * scaling_l) + (bx, by, bz),            b in {0, 1}
//   row     = ((x * 1) ^ (y * 2654435761) ^ (z * 805459861)) mod T + l * T
//   out[n, l * F + f] = sum_c w_c * table[row_c, f],           w_c = prod_axis (b ? t : 1 - t)
//
// with t = p * scaling_l - floor(p * scaling_l). T is a power of two, so only the low log2(T) bits of
// the hash matter and the products are done in wrapping uint32 arithmetic.
//
// The backward pass recomputes rows and weights instead of saving [L, N, 8] tensors. The table
// gradient is a scatter-add; two race-free schedules are provided:
//   * by level: each task owns whole levels, i.e. disjoint slices of the table (no atomics, no copies);
//   * by point: each task owns a contiguous range of points and its own zeroed copy of the table
//     gradient, reduced at the end (better balanced when there are few levels per thread).
// ``backward`` picks one with a simple cost model unless a schedule is forced (for benchmarks).

#include <torch/extension.h>

#include <ATen/Parallel.h>

#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstdint>
#include <vector>

#if defined(__SSE__) || defined(__x86_64__)
#include <xmmintrin.h>
#define NERFIFY_HAVE_MXCSR 1
#endif

namespace {

constexpr uint32_t kPrimeY = 2654435761u;
constexpr uint32_t kPrimeZ = 805459861u;
constexpr int64_t kChunk = 512;  // points handled level by level together (keeps their rows in cache)

// Rows and per-axis weights of the 8 corners of one point at one level.
// Corner c = 4 * bx + 2 * by + bz, as in the torch path.
template <typename scalar_t>
struct Cell {
  uint32_t row[8];
  scalar_t w[3][2];  // w[axis][b]: (1 - t, t)
};

template <typename scalar_t>
inline void locate(const scalar_t* p, scalar_t scaling, uint32_t mask, uint32_t offset, Cell<scalar_t>& cell) {
  uint32_t h[3][2];
  const uint32_t primes[3] = {1u, kPrimeY, kPrimeZ};
  for (int a = 0; a < 3; ++a) {
    const scalar_t v = p[a] * scaling;
    const scalar_t fl = std::floor(v);
    const scalar_t t = v - fl;
    cell.w[a][0] = scalar_t(1) - t;
    cell.w[a][1] = t;
    const uint32_t lo = static_cast<uint32_t>(static_cast<int32_t>(fl)) * primes[a];
    h[a][0] = lo;
    h[a][1] = lo + primes[a];
  }
  for (int bx = 0; bx < 2; ++bx)
    for (int by = 0; by < 2; ++by) {
      const uint32_t hxy = h[0][bx] ^ h[1][by];
      cell.row[4 * bx + 2 * by + 0] = ((hxy ^ h[2][0]) & mask) + offset;
      cell.row[4 * bx + 2 * by + 1] = ((hxy ^ h[2][1]) & mask) + offset;
    }
}

template <typename scalar_t>
inline void corner_weights(const Cell<scalar_t>& cell, scalar_t w[8]) {
  for (int bx = 0; bx < 2; ++bx)
    for (int by = 0; by < 2; ++by) {
      const scalar_t wxy = cell.w[0][bx] * cell.w[1][by];
      w[4 * bx + 2 * by + 0] = wxy * cell.w[2][0];
      w[4 * bx + 2 * by + 1] = wxy * cell.w[2][1];
    }
}

// Calls body(i, cell) for points [c0, c1) at one level, locating each point kPrefetch points ahead
// and prefetching its rows (from `a` and, if not null, `b`), so the random row accesses overlap.
constexpr int kPrefetch = 16;

template <typename scalar_t, typename Body>
inline void for_each_cell(const scalar_t* pos, scalar_t s, uint32_t mask, uint32_t offset, int64_t c0, int64_t c1,
                          const scalar_t* a, const scalar_t* b, int64_t F, Body&& body) {
  Cell<scalar_t> ring[kPrefetch];
  auto fetch = [&](int64_t i, Cell<scalar_t>& cell) {
    locate(pos + 3 * i, s, mask, offset, cell);
    for (int c = 0; c < 8; ++c) {
      __builtin_prefetch(a + static_cast<int64_t>(cell.row[c]) * F, 1, 3);
      if (b != nullptr) __builtin_prefetch(b + static_cast<int64_t>(cell.row[c]) * F, 0, 3);
    }
  };
  const int64_t head = std::min<int64_t>(c1, c0 + kPrefetch);
  for (int64_t i = c0; i < head; ++i) fetch(i, ring[(i - c0) % kPrefetch]);
  for (int64_t i = c0; i < c1; ++i) {
    Cell<scalar_t>& slot = ring[(i - c0) % kPrefetch];
    const Cell<scalar_t> cell = slot;
    if (i + kPrefetch < c1) fetch(i + kPrefetch, slot);
    body(i, cell);
  }
}

// d(out)/d(p) of one level contracted with the output gradient, given d[c] = <f_c, g_l>.
// Along an axis the corner weight's derivative is +-1 times the other two axes' weights.
template <typename scalar_t>
inline void add_position_grad(const Cell<scalar_t>& cell, const scalar_t d[8], scalar_t scaling, scalar_t* gp) {
  const scalar_t(&w)[3][2] = cell.w;
  const scalar_t gx = ((d[4] - d[0]) * w[2][0] + (d[5] - d[1]) * w[2][1]) * w[1][0] +
                      ((d[6] - d[2]) * w[2][0] + (d[7] - d[3]) * w[2][1]) * w[1][1];
  const scalar_t gy = ((d[2] - d[0]) * w[2][0] + (d[3] - d[1]) * w[2][1]) * w[0][0] +
                      ((d[6] - d[4]) * w[2][0] + (d[7] - d[5]) * w[2][1]) * w[0][1];
  const scalar_t gz = ((d[1] - d[0]) * w[1][0] + (d[3] - d[2]) * w[1][1]) * w[0][0] +
                      ((d[5] - d[4]) * w[1][0] + (d[7] - d[6]) * w[1][1]) * w[0][1];
  gp[0] += gx * scaling;
  gp[1] += gy * scaling;
  gp[2] += gz * scaling;
}

// FT > 0: feature count known at compile time (unrolled); FT == 0: runtime count F.
template <typename scalar_t, int FT>
void forward_impl(const scalar_t* pos, const scalar_t* table, const scalar_t* scalings, scalar_t* out, int64_t n,
                  int64_t levels, int64_t table_size, int64_t features) {
  const int64_t F = FT > 0 ? FT : features;
  const uint32_t mask = static_cast<uint32_t>(table_size - 1);
  const int64_t stride = levels * F;
  at::parallel_for(0, n, kChunk, [&](int64_t begin, int64_t end) {
    for (int64_t c0 = begin; c0 < end; c0 += kChunk) {
      const int64_t c1 = std::min(end, c0 + kChunk);
      for (int64_t l = 0; l < levels; ++l) {
        const scalar_t s = scalings[l];
        const uint32_t offset = static_cast<uint32_t>(l * table_size);
        for_each_cell(pos, s, mask, offset, c0, c1, table, static_cast<const scalar_t*>(nullptr), F,
                      [&](int64_t i, const Cell<scalar_t>& cell) {
          scalar_t w[8];
          corner_weights(cell, w);
          scalar_t* o = out + i * stride + l * F;
          if constexpr (FT > 0) {
            scalar_t acc[FT > 0 ? FT : 1];
            for (int f = 0; f < FT; ++f) acc[f] = 0;
            for (int c = 0; c < 8; ++c) {
              const scalar_t* r = table + static_cast<int64_t>(cell.row[c]) * FT;
              for (int f = 0; f < FT; ++f) acc[f] += w[c] * r[f];
            }
            for (int f = 0; f < FT; ++f) o[f] = acc[f];
          } else {
            for (int64_t f = 0; f < F; ++f) o[f] = 0;
            for (int c = 0; c < 8; ++c) {
              const scalar_t* r = table + static_cast<int64_t>(cell.row[c]) * F;
              for (int64_t f = 0; f < F; ++f) o[f] += w[c] * r[f];
            }
          }
        });
      }
    }
  });
}

// Backward for points [p0, p1) and levels in `level_list`: scatter into gt (may be null), add into gp
// (may be null; rows indexed by point).
template <typename scalar_t, int FT>
inline void backward_range(const scalar_t* pos, const scalar_t* table, const scalar_t* scalings, const scalar_t* gout,
                           scalar_t* gt, scalar_t* gp, int64_t p0, int64_t p1, const int64_t* level_list,
                           int64_t n_levels_here, int64_t levels, int64_t table_size, int64_t features) {
  const int64_t F = FT > 0 ? FT : features;
  const uint32_t mask = static_cast<uint32_t>(table_size - 1);
  const int64_t stride = levels * F;
  for (int64_t c0 = p0; c0 < p1; c0 += kChunk) {
    const int64_t c1 = std::min(p1, c0 + kChunk);
    for (int64_t k = 0; k < n_levels_here; ++k) {
      const int64_t l = level_list[k];
      const scalar_t s = scalings[l];
      const uint32_t offset = static_cast<uint32_t>(l * table_size);
      for_each_cell(pos, s, mask, offset, c0, c1, gt != nullptr ? static_cast<const scalar_t*>(gt) : table,
                    gt != nullptr && gp != nullptr ? table : static_cast<const scalar_t*>(nullptr), F,
                    [&](int64_t i, const Cell<scalar_t>& cell) {
        const scalar_t* g = gout + i * stride + l * F;
        if (gt != nullptr) {
          scalar_t w[8];
          corner_weights(cell, w);
          for (int c = 0; c < 8; ++c) {
            scalar_t* r = gt + static_cast<int64_t>(cell.row[c]) * F;
            for (int64_t f = 0; f < F; ++f) r[f] += w[c] * g[f];
          }
        }
        if (gp != nullptr) {
          scalar_t d[8];
          for (int c = 0; c < 8; ++c) {
            const scalar_t* r = table + static_cast<int64_t>(cell.row[c]) * F;
            scalar_t acc = 0;
            for (int64_t f = 0; f < F; ++f) acc += r[f] * g[f];
            d[c] = acc;
          }
          add_position_grad(cell, d, s, gp + 3 * i);
        }
      });
    }
  }
}

enum Schedule : int64_t { kAuto = 0, kByLevel = 1, kByPoint = 2 };

template <typename scalar_t, int FT>
void backward_impl(const scalar_t* pos, const scalar_t* table, const scalar_t* scalings, const scalar_t* gout,
                   scalar_t* gt, scalar_t* gp, int64_t n, int64_t levels, int64_t table_size, int64_t features,
                   int64_t schedule) {
  const int64_t threads = std::max<int64_t>(1, at::get_num_threads());
  std::vector<int64_t> all_levels(levels);
  for (int64_t l = 0; l < levels; ++l) all_levels[l] = l;

  if (gt == nullptr) {  // position gradient only: every task owns its points
    at::parallel_for(0, n, kChunk, [&](int64_t b, int64_t e) {
      backward_range<scalar_t, FT>(pos, table, scalings, gout, nullptr, gp, b, e, all_levels.data(), levels, levels,
                                   table_size, features);
    });
    return;
  }
  const int64_t table_elems = levels * table_size * features;
  if (schedule == kAuto) {
    // By level is free of copies but only balances when each thread gets several levels; by point
    // pays for zeroing and reducing one table-gradient copy per extra thread.
    const int64_t by_level_tasks = std::min(threads, levels);
    const double imbalance = static_cast<double>((levels + by_level_tasks - 1) / by_level_tasks) * threads / levels;
    const double by_level_cost = imbalance * static_cast<double>(n) * levels * 8;
    const double by_point_cost = static_cast<double>(n) * levels * 8 + 2.0 * table_elems * (threads - 1);
    schedule = (threads > 1 && by_point_cost < by_level_cost) ? kByPoint : kByLevel;
  }
  if (threads == 1 || n == 0) {
    backward_range<scalar_t, FT>(pos, table, scalings, gout, gt, gp, 0, n, all_levels.data(), levels, levels,
                                 table_size, features);
    return;
  }
  if (schedule == kByLevel) {
    // Task t owns levels t, t + tasks, ... (interleaved: coarse levels are cheaper than fine ones).
    const int64_t tasks = std::min(threads, levels);
    std::vector<std::vector<int64_t>> owned(tasks);
    for (int64_t l = 0; l < levels; ++l) owned[l % tasks].push_back(l);
    std::vector<at::Tensor> partial_gp;  // per-task position gradients (task 0 writes gp directly)
    if (gp != nullptr)
      for (int64_t t = 1; t < tasks; ++t) partial_gp.push_back(at::zeros({n, 3}, c10::CppTypeToScalarType<scalar_t>::value));
    at::parallel_for(0, tasks, 1, [&](int64_t b, int64_t e) {
      for (int64_t t = b; t < e; ++t) {
        scalar_t* my_gp = gp == nullptr ? nullptr : (t == 0 ? gp : partial_gp[t - 1].data_ptr<scalar_t>());
        backward_range<scalar_t, FT>(pos, table, scalings, gout, gt, my_gp, 0, n, owned[t].data(),
                                     static_cast<int64_t>(owned[t].size()), levels, table_size, features);
      }
    });
    if (gp != nullptr)
      for (auto& part : partial_gp) {
        const scalar_t* src = part.data_ptr<scalar_t>();
        at::parallel_for(0, 3 * n, 1 << 14, [&](int64_t b, int64_t e) {
          for (int64_t j = b; j < e; ++j) gp[j] += src[j];
        });
      }
    return;
  }
  // By point: task 0 scatters into gt, task t > 0 into its own zeroed copy, reduced afterwards.
  const int64_t tasks = threads;
  std::vector<at::Tensor> partial_gt;
  for (int64_t t = 1; t < tasks; ++t)
    partial_gt.push_back(at::empty({table_elems}, c10::CppTypeToScalarType<scalar_t>::value));
  at::parallel_for(0, tasks, 1, [&](int64_t b, int64_t e) {
    for (int64_t t = b; t < e; ++t) {
      scalar_t* my_gt = t == 0 ? gt : partial_gt[t - 1].data_ptr<scalar_t>();
      if (t > 0) std::fill(my_gt, my_gt + table_elems, scalar_t(0));
      const int64_t p0 = n * t / tasks, p1 = n * (t + 1) / tasks;
      backward_range<scalar_t, FT>(pos, table, scalings, gout, my_gt, gp, p0, p1, all_levels.data(), levels, levels,
                                   table_size, features);
    }
  });
  at::parallel_for(0, table_elems, 1 << 14, [&](int64_t b, int64_t e) {
    for (const auto& part : partial_gt) {
      const scalar_t* src = part.data_ptr<scalar_t>();
      for (int64_t j = b; j < e; ++j) gt[j] += src[j];
    }
  });
}

void check_inputs(const at::Tensor& positions, const at::Tensor& table, const at::Tensor& scalings, int64_t table_size) {
  TORCH_CHECK(positions.device().is_cpu() && table.device().is_cpu() && scalings.device().is_cpu(),
              "hashgrid_cpu: tensors must be on the CPU");
  TORCH_CHECK(positions.dim() == 2 && positions.size(1) == 3, "hashgrid_cpu: positions must be [N, 3]");
  TORCH_CHECK(table.dim() == 2, "hashgrid_cpu: table must be [L * T, F]");
  TORCH_CHECK(scalings.dim() == 1, "hashgrid_cpu: scalings must be [L]");
  TORCH_CHECK(table_size > 0 && (table_size & (table_size - 1)) == 0 && table_size <= (int64_t(1) << 31),
              "hashgrid_cpu: table size must be a power of two <= 2^31");
  TORCH_CHECK(table.size(0) == scalings.size(0) * table_size, "hashgrid_cpu: table has ", table.size(0),
              " rows, expected levels * T = ", scalings.size(0) * table_size);
  TORCH_CHECK(table.size(0) <= (int64_t(1) << 32), "hashgrid_cpu: table too large for 32-bit rows");
  TORCH_CHECK(positions.scalar_type() == table.scalar_type() && scalings.scalar_type() == table.scalar_type(),
              "hashgrid_cpu: positions, table and scalings must share one dtype");
}

#define HASHGRID_DISPATCH_FEATURES(F, ...)              \
  switch (F) {                                          \
    case 1: { constexpr int FT = 1; __VA_ARGS__; break; } \
    case 2: { constexpr int FT = 2; __VA_ARGS__; break; } \
    case 4: { constexpr int FT = 4; __VA_ARGS__; break; } \
    case 8: { constexpr int FT = 8; __VA_ARGS__; break; } \
    default: { constexpr int FT = 0; __VA_ARGS__; break; } \
  }

}  // namespace

// out[N, L * F]; need_pos_grad is accepted for API symmetry (backward recomputes everything it needs).
at::Tensor hashgrid_forward(const at::Tensor& positions_in, const at::Tensor& table_in, const at::Tensor& scalings_in,
                            int64_t table_size, bool need_pos_grad) {
  (void)need_pos_grad;
  check_inputs(positions_in, table_in, scalings_in, table_size);
  const at::Tensor positions = positions_in.contiguous();
  const at::Tensor table = table_in.contiguous();
  const at::Tensor scalings = scalings_in.contiguous();
  const int64_t n = positions.size(0), levels = scalings.size(0), features = table.size(1);
  at::Tensor out = at::empty({n, levels * features}, positions.options());
  if (n == 0 || levels == 0 || features == 0) return out;
  AT_DISPATCH_FLOATING_TYPES(positions.scalar_type(), "hashgrid_forward", [&] {
    HASHGRID_DISPATCH_FEATURES(features, forward_impl<scalar_t, FT>(
        positions.data_ptr<scalar_t>(), table.data_ptr<scalar_t>(), scalings.data_ptr<scalar_t>(),
        out.data_ptr<scalar_t>(), n, levels, table_size, features));
  });
  return out;
}

// (grad_table [L * T, F] or empty, grad_positions [N, 3] or empty).
// schedule: 0 auto, 1 by level, 2 by point (table-gradient parallelisation; for benchmarks).
std::tuple<at::Tensor, at::Tensor> hashgrid_backward(const at::Tensor& grad_out_in, const at::Tensor& positions_in,
                                                     const at::Tensor& table_in, const at::Tensor& scalings_in,
                                                     int64_t table_size, bool need_table_grad, bool need_pos_grad,
                                                     int64_t schedule) {
  check_inputs(positions_in, table_in, scalings_in, table_size);
  const at::Tensor positions = positions_in.contiguous();
  const at::Tensor table = table_in.contiguous();
  const at::Tensor scalings = scalings_in.contiguous();
  const int64_t n = positions.size(0), levels = scalings.size(0), features = table.size(1);
  TORCH_CHECK(grad_out_in.device().is_cpu() && grad_out_in.dim() == 2 && grad_out_in.size(0) == n &&
                  grad_out_in.size(1) == levels * features,
              "hashgrid_cpu: grad_out must be [N, L * F] on the CPU");
  TORCH_CHECK(schedule >= 0 && schedule <= 2, "hashgrid_cpu: schedule must be 0, 1 or 2");
  const at::Tensor grad_out = grad_out_in.to(positions.scalar_type()).contiguous();
  at::Tensor grad_table = need_table_grad ? at::zeros_like(table) : at::empty({0}, table.options());
  at::Tensor grad_pos = need_pos_grad ? at::zeros({n, 3}, positions.options()) : at::empty({0}, positions.options());
  if (n == 0 || levels == 0 || features == 0 || (!need_table_grad && !need_pos_grad)) return {grad_table, grad_pos};
  AT_DISPATCH_FLOATING_TYPES(positions.scalar_type(), "hashgrid_backward", [&] {
    HASHGRID_DISPATCH_FEATURES(features, backward_impl<scalar_t, FT>(
        positions.data_ptr<scalar_t>(), table.data_ptr<scalar_t>(), scalings.data_ptr<scalar_t>(),
        grad_out.data_ptr<scalar_t>(), need_table_grad ? grad_table.data_ptr<scalar_t>() : nullptr,
        need_pos_grad ? grad_pos.data_ptr<scalar_t>() : nullptr, n, levels, table_size, features, schedule));
  });
  return {grad_table, grad_pos};
}

// Sets (or clears) flush-to-zero and denormals-are-zero in the calling thread and in every thread of
// ATen's intra-op pool. torch.set_flush_denormal changes only the calling thread, and the pool's threads
// do not inherit it, so without this half of a two-thread elementwise op still runs at denormal speed.
// Returns the number of threads whose MXCSR was set (0 where the CPU has no MXCSR).
int64_t set_flush_denormal_all_threads(bool on) {
#ifdef NERFIFY_HAVE_MXCSR
  constexpr unsigned kFtzDaz = 0x8040u;  // FTZ (bit 15) | DAZ (bit 6)
  auto apply = [on]() { _mm_setcsr(on ? (_mm_getcsr() | kFtzDaz) : (_mm_getcsr() & ~kFtzDaz)); };
  apply();
  std::atomic<int64_t> count{0};
  const int64_t threads = at::get_num_threads();
  at::parallel_for(0, threads, 1, [&](int64_t begin, int64_t end) {
    apply();
    count += end - begin > 0 ? 1 : 0;
  });
  return std::max<int64_t>(count.load(), 1);
#else
  (void)on;
  return 0;
#endif
}

PYBIND11_MODULE(TORCH_EXTENSION_NAME, m) {
  m.doc() = "nerfify multi-resolution hash encoding, fused CPU kernel";
  m.attr("ABI_VERSION") = 1;
  m.def("forward", &hashgrid_forward, "hash-grid encode: (positions [N,3], table [L*T,F], scalings [L], T, "
        "need_pos_grad) -> [N, L*F]", py::arg("positions"), py::arg("table"), py::arg("scalings"),
        py::arg("table_size"), py::arg("need_pos_grad") = false);
  m.def("backward", &hashgrid_backward, "hash-grid backward -> (grad_table or empty, grad_positions or empty)",
        py::arg("grad_out"), py::arg("positions"), py::arg("table"), py::arg("scalings"), py::arg("table_size"),
        py::arg("need_table_grad") = true, py::arg("need_pos_grad") = true, py::arg("schedule") = 0);
  m.def("set_flush_denormal_all_threads", &set_flush_denormal_all_threads,
        "FTZ/DAZ on or off in the calling thread and every intra-op pool thread -> threads set",
        py::arg("on") = true);
}
