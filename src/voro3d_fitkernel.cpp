// The inner step of the VoroMesh fit (voro3d.fitting) on CPU: VoroLoss and its gradient for a
// batch of samples in one pass over their kNN candidates, on a few threads.
//
// The torch path (voro3d.loss.bisector_pairs + bisector_distance) stays the reference and the
// CUDA path; this one does the same arithmetic per sample without materialising (c, m)
// temporaries, which is where torch spent 90% of a step.
//
// Threads are std::threads started per call and joined, not OpenMP: libgomp (shared with torch,
// which loads it first) spins at barriers and between regions, and on a loaded 2-core machine
// that cost 20 ms of CPU per 4 ms call (30k samples); starting a thread costs tens of
// microseconds, and a joined thread waits without spinning.
//
// Every function checks its arrays (dtype, shape, finite coordinates, index bounds) and raises
// ValueError or TypeError naming the argument, and releases the GIL while it computes.
#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>

#include "voro3d_checks.h"
#include "voro3d_parallel.h"

#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstdint>
#include <limits>
#include <string>
#include <system_error>
#include <thread>
#include <utility>
#include <vector>

namespace py = pybind11;

namespace {

// Samples per unit of work: the loss is summed per block in sample order and the block sums in
// block order, so the loss does not depend on the thread count or on which thread ran a block.
constexpr std::int64_t kBlock = 1024;

// Gradient terms are summed in fixed point (units of 2^-40) in one int64 buffer per thread.
// Integer addition is associative, so the gradient is bitwise the same whatever the thread count
// and schedule (a float sum per thread would round differently with 1 or 2 threads). In the fit
// frame (diagonal 2) a term 2 d dd/dq is about a voxel or less, where 2^-40 is far below float32's
// resolution; a term is clamped to +-2^12, reached only when two generators lie within about
// 1e-6 of each other, so that 2^11 clamped terms on one generator still fit in an int64.
constexpr double kFixedScale = 1099511627776.0;  // 2^40
constexpr double kTermLimit = 4096.0;            // 2^12

// An ndarray as it is (no conversion: the kernels take float32 or float64 as given), else TypeError.
py::array numpy_array(const py::object& value, const char* name) {
  if (!py::isinstance<py::array>(value)) {
    throw py::type_error(std::string(name) + " must be a numpy array, got " +
                         py::str(py::type::of(value).attr("__name__")).cast<std::string>());
  }
  return py::reinterpret_borrow<py::array>(value);
}

using voro3d::check_columns;
using voro3d::shape_of;

std::string dtype_name(const py::array& array) { return py::str(array.dtype()).cast<std::string>(); }

struct Failure {
  std::int64_t row = -1;  // first bad row of the block, -1 when none
  std::int64_t index = 0;
  bool bad_index = false;
};

using voro3d::parallel_for;

// Point-major double copy of the generators, checked finite: one cache line per generator read
// instead of three strided ones.
template <typename Real>
std::vector<double> packed_sites(const py::array_t<Real>& generators_in) {
  auto generators = generators_in.template unchecked<2>();
  std::vector<double> sites(3 * generators.shape(0));
  for (py::ssize_t g = 0; g < generators.shape(0); ++g) {
    for (int axis = 0; axis < 3; ++axis) {
      const double value = generators(g, axis);
      if (!std::isfinite(value)) throw py::value_error("generators holds NaN or inf at row " + std::to_string(g));
      sites[3 * g + axis] = value;
    }
  }
  return sites;
}

// samples float32 or float64, generators the same.
void check_real_pair(const py::array& samples, const py::array& generators) {
  if (!py::isinstance<py::array_t<float>>(samples) && !py::isinstance<py::array_t<double>>(samples)) {
    throw py::type_error("samples must be float32 or float64, got dtype " + dtype_name(samples));
  }
  if (!samples.dtype().is(generators.dtype())) {
    throw py::type_error("generators must have the dtype of samples (" + dtype_name(samples) + "), got " +
                         dtype_name(generators));
  }
}

template <typename Real, typename Index>
double voroloss_impl(const py::array& samples_in, const py::array& generators_in, const py::array& candidates_in,
                     const py::object& grad_in, int threads, const std::uint8_t* sides) {
  auto samples = py::reinterpret_borrow<py::array_t<Real>>(samples_in).template unchecked<2>();
  auto candidates = py::reinterpret_borrow<py::array_t<Index>>(candidates_in).template unchecked<2>();
  const std::int64_t m = samples.shape(0);
  const std::int64_t n = generators_in.shape(0);
  const std::int64_t c = candidates.shape(1);
  const bool want_grad = !grad_in.is_none();
  py::array_t<Real> grad_array;
  if (want_grad) {
    py::array grad = numpy_array(grad_in, "grad");
    if (!py::isinstance<py::array_t<Real>>(grad)) {
      throw py::type_error("grad must have the dtype of generators (" + dtype_name(generators_in) + "), got " +
                           dtype_name(grad));
    }
    if (grad.ndim() != 2 || grad.shape(0) != n || grad.shape(1) != 3) {
      throw py::value_error("grad must have shape (" + std::to_string(n) + ", 3) like generators, got " +
                            shape_of(grad));
    }
    if (!grad.writeable()) throw py::value_error("grad must be writeable");
    grad_array = py::reinterpret_borrow<py::array_t<Real>>(grad);
  }

  const std::vector<double> sites = packed_sites(py::reinterpret_borrow<py::array_t<Real>>(generators_in));

  const std::int64_t blocks = (m + kBlock - 1) / kBlock;
  std::vector<double> block_loss(blocks, 0.0);
  std::vector<Failure> failures(blocks);
  std::vector<std::int64_t> fixed(want_grad ? static_cast<std::size_t>(threads) * 3 * n : 0, 0);
  auto loss_block = [&](int worker, std::int64_t block) {
    std::int64_t* mine = want_grad ? fixed.data() + static_cast<std::size_t>(worker) * 3 * n : nullptr;
    std::vector<double> squared(c);
    std::vector<std::int64_t> index(c);
    double sum = 0.0;
    for (std::int64_t s = block * kBlock; s < std::min(m, (block + 1) * kBlock); ++s) {
      const double x[3] = {samples(s, 0), samples(s, 1), samples(s, 2)};
      if (!(std::isfinite(x[0]) && std::isfinite(x[1]) && std::isfinite(x[2]))) {
        failures[block].row = s;
        return;
      }
      // The nearest candidate i (ties to the first), working relative to the sample.
      // Both searches keep their best in registers and update it by selection, not branches: the
      // order of random candidates defeats branch prediction (1.2 times faster).
      std::int64_t col_i = 0;
      double nearest = std::numeric_limits<double>::infinity();
      for (std::int64_t r = 0; r < c; ++r) {
        const auto g = static_cast<std::int64_t>(candidates(s, r));
        if (g < 0 || g >= n) {
          failures[block] = {s, g, true};
          return;
        }
        const double* q = &sites[3 * g];
        const double dx = q[0] - x[0], dy = q[1] - x[1], dz = q[2] - x[2];
        const double distance = dx * dx + dy * dy + dz * dz;
        index[r] = g;
        squared[r] = distance;
        const bool closer = distance < nearest;
        nearest = closer ? distance : nearest;
        col_i = closer ? r : col_i;
      }
      // The candidate j whose bisector with i is nearest: d^2 = (|x-q_j|^2 - |x-q_i|^2)^2 / (4 |q_j-q_i|^2),
      // ranked without the 4 and compared as cross products (no division); copies of q_i (i itself
      // included) have no bisector, nor, with sides, a candidate on i's side.
      const double* q_i = &sites[3 * index[col_i]];
      const std::uint8_t side_i = sides == nullptr ? 0 : sides[index[col_i]];
      std::int64_t col_j = -1;
      double best_gap2 = 1.0, best_edge = 0.0;  // the ratio +inf
      for (std::int64_t r = 0; r < c; ++r) {
        const double* q = &sites[3 * index[r]];
        const double ex = q[0] - q_i[0], ey = q[1] - q_i[1], ez = q[2] - q_i[2];
        const double edge = ex * ex + ey * ey + ez * ez;
        const double gap = squared[r] - nearest;
        const double gap2 = gap * gap;
        const bool across = sides == nullptr || sides[index[r]] != side_i;
        const bool better = (edge != 0.0) & across & (gap2 * best_edge < best_gap2 * edge);
        best_gap2 = better ? gap2 : best_gap2;
        best_edge = better ? edge : best_edge;
        col_j = better ? r : col_j;
      }
      if (col_j < 0) continue;  // every candidate is a copy of q_i (or on its side): no term, no gradient
      const double* q_j = &sites[3 * index[col_j]];
      const double e[3] = {q_j[0] - q_i[0], q_j[1] - q_i[1], q_j[2] - q_i[2]};
      const double length = std::sqrt(e[0] * e[0] + e[1] * e[1] + e[2] * e[2]);
      const double u[3] = {e[0] / length, e[1] / length, e[2] / length};
      const double from_i[3] = {x[0] - q_i[0], x[1] - q_i[1], x[2] - q_i[2]};
      const double d = length / 2 - (u[0] * from_i[0] + u[1] * from_i[1] + u[2] * from_i[2]);
      sum += d * d;
      if (mine == nullptr) continue;
      // dd/dq_i = (x - q_i + d u) / L and dd/dq_j = u - dd/dq_i, times 2 d for the square.
      std::int64_t* to_i = mine + 3 * index[col_i];
      std::int64_t* to_j = mine + 3 * index[col_j];
      for (int axis = 0; axis < 3; ++axis) {
        const double term_i = std::clamp(2 * d * (from_i[axis] + d * u[axis]) / length, -kTermLimit, kTermLimit);
        const double term_j = std::clamp(2 * d * u[axis] - term_i, -kTermLimit, kTermLimit);
        to_i[axis] += static_cast<std::int64_t>(term_i * kFixedScale);
        to_j[axis] += static_cast<std::int64_t>(term_j * kFixedScale);
      }
    }
    block_loss[block] = sum;
  };
  {
    py::gil_scoped_release release;
    parallel_for(threads, blocks, loss_block);
  }
  for (std::int64_t block = 0; block < blocks; ++block) {
    const Failure& failure = failures[block];
    if (failure.row < 0) continue;
    if (failure.bad_index) {
      throw py::value_error("candidates holds index " + std::to_string(failure.index) + " at row " +
                            std::to_string(failure.row) + ", outside [0, " + std::to_string(n) + ")");
    }
    throw py::value_error("samples holds NaN or inf at row " + std::to_string(failure.row));
  }
  double loss = 0.0;
  for (double sum : block_loss) loss += sum;
  if (want_grad) {
    auto grad = grad_array.template mutable_unchecked<2>();
    const double scale = 1.0 / (kFixedScale * static_cast<double>(m));
    // Few generators (1e4 at grid 64): one thread sums the per-thread buffers in well under a millisecond.
    for (std::int64_t g = 0; g < n; ++g) {
      for (int axis = 0; axis < 3; ++axis) {
        std::int64_t total = 0;
        for (int t = 0; t < threads; ++t) total += fixed[static_cast<std::size_t>(t) * 3 * n + 3 * g + axis];
        grad(g, axis) = static_cast<Real>(static_cast<double>(total) * scale);
      }
    }
  }
  return loss / static_cast<double>(m);
}

double voroloss(const py::object& samples_in, const py::object& generators_in, const py::object& candidates_in,
                const py::object& grad_in, int threads, const py::object& sides_in) {
  py::array samples = numpy_array(samples_in, "samples");
  py::array generators = numpy_array(generators_in, "generators");
  py::array candidates = numpy_array(candidates_in, "candidates");
  check_columns(samples, "samples", "(m, 3)", 3);
  check_columns(generators, "generators", "(n, 3)", 3);
  check_columns(candidates, "candidates", "(m, c) with c >= 2", -2);
  if (samples.shape(0) == 0) throw py::value_error("samples must hold at least 1 point, got 0");
  if (generators.shape(0) < 2) {
    throw py::value_error("generators must hold at least 2 points, got " + std::to_string(generators.shape(0)));
  }
  if (candidates.shape(0) != samples.shape(0)) {
    throw py::value_error("candidates must have one row per sample, shape (" + std::to_string(samples.shape(0)) +
                          ", c), got " + shape_of(candidates));
  }
  if (threads < 1) throw py::value_error("threads must be >= 1, got " + std::to_string(threads));
  check_real_pair(samples, generators);
  py::array_t<std::uint8_t, py::array::c_style | py::array::forcecast> sides_array;
  const std::uint8_t* sides = nullptr;
  if (!sides_in.is_none()) {
    sides_array = py::array_t<std::uint8_t, py::array::c_style | py::array::forcecast>::ensure(sides_in);
    if (!sides_array || sides_array.ndim() != 1 || sides_array.shape(0) != generators.shape(0)) {
      throw py::value_error("sides must be an (n,) array of 0/1 labels, one per generator (n = " +
                            std::to_string(generators.shape(0)) + ")");
    }
    sides = sides_array.data();
  }
  const bool f32 = py::isinstance<py::array_t<float>>(samples);
  const bool i32 = py::isinstance<py::array_t<std::int32_t>>(candidates);
  const bool i64 = py::isinstance<py::array_t<std::int64_t>>(candidates);
  if (!i32 && !i64) {
    throw py::type_error("candidates must be an int32 or int64 array of indices, got dtype " + dtype_name(candidates));
  }
  if (f32) {
    return i32 ? voroloss_impl<float, std::int32_t>(samples, generators, candidates, grad_in, threads, sides)
               : voroloss_impl<float, std::int64_t>(samples, generators, candidates, grad_in, threads, sides);
  }
  return i32 ? voroloss_impl<double, std::int32_t>(samples, generators, candidates, grad_in, threads, sides)
             : voroloss_impl<double, std::int64_t>(samples, generators, candidates, grad_in, threads, sides);
}

// Generators bucketed in a uniform grid of cubic cells (CSR: cell -> generator indices).
struct CellGrid {
  double origin[3];
  double cell;
  std::int64_t dims[3];
  std::vector<std::int64_t> start;  // cells + 1 offsets into members
  std::vector<std::int64_t> members;

  std::int64_t coordinate(double value, int axis) const {
    const double scaled = std::floor((value - origin[axis]) / cell);
    return static_cast<std::int64_t>(std::clamp(scaled, 0.0, static_cast<double>(dims[axis] - 1)));
  }
};

// At most 64 cells per generator (a fit's band of generators has at most 14-50 at grids 32-128) and 2^24
// cells (128 MB of offsets): a finer request is coarsened, which only costs speed, while empty
// cells would cost a search ring after ring of nothing.
constexpr double kCellsPerGenerator = 64.0;
constexpr double kMaxCells = 16777216.0;

// anchor: when finite, the cells' corners lie on anchor + j * cell on every axis (j integer), so
// that samples sorted by the same cells (the fit's search order) meet each cell in one run.
CellGrid bucket(const std::vector<double>& sites, double cell, double anchor) {
  const std::int64_t n = static_cast<std::int64_t>(sites.size() / 3);
  CellGrid grid;
  double top[3];
  for (int axis = 0; axis < 3; ++axis) {
    grid.origin[axis] = top[axis] = sites[axis];
    for (std::int64_t g = 1; g < n; ++g) {
      grid.origin[axis] = std::min(grid.origin[axis], sites[3 * g + axis]);
      top[axis] = std::max(top[axis], sites[3 * g + axis]);
    }
  }
  auto cells_for = [&](double size) {
    double cells = 1.0;
    for (int axis = 0; axis < 3; ++axis) cells *= std::floor((top[axis] - grid.origin[axis]) / size) + 1.0;
    return cells;
  };
  while (cells_for(cell) > std::min(kMaxCells, kCellsPerGenerator * n)) cell *= 1.25;
  grid.cell = cell;
  if (std::isfinite(anchor)) {
    for (int axis = 0; axis < 3; ++axis) {
      const double lowest = grid.origin[axis];
      grid.origin[axis] = anchor + std::floor((lowest - anchor) / cell) * cell;
      if (grid.origin[axis] > lowest) grid.origin[axis] -= cell;  // rounding: every site at or above it
    }
  }
  for (int axis = 0; axis < 3; ++axis) {
    grid.dims[axis] = static_cast<std::int64_t>(std::floor((top[axis] - grid.origin[axis]) / cell)) + 1;
  }
  std::vector<std::int64_t> of(n);
  grid.start.assign(grid.dims[0] * grid.dims[1] * grid.dims[2] + 1, 0);
  for (std::int64_t g = 0; g < n; ++g) {
    of[g] = (grid.coordinate(sites[3 * g], 0) * grid.dims[1] + grid.coordinate(sites[3 * g + 1], 1)) * grid.dims[2] +
            grid.coordinate(sites[3 * g + 2], 2);
    ++grid.start[of[g] + 1];
  }
  for (std::size_t c = 1; c < grid.start.size(); ++c) grid.start[c] += grid.start[c - 1];
  grid.members.resize(n);
  std::vector<std::int64_t> fill(grid.start.begin(), grid.start.end() - 1);
  for (std::int64_t g = 0; g < n; ++g) grid.members[fill[of[g]]++] = g;  // increasing index within a cell
  return grid;
}

template <typename Real>
py::array_t<std::int32_t> nearest_impl(const py::array& samples_in, const py::array& generators_in, std::int64_t k,
                                       double cell, double anchor, int threads, py::array_t<std::int32_t> result,
                                       const std::int64_t* rows) {
  auto samples = py::reinterpret_borrow<py::array_t<Real>>(samples_in).template unchecked<2>();
  const std::int64_t m = samples.shape(0);
  const std::vector<double> sites = packed_sites(py::reinterpret_borrow<py::array_t<Real>>(generators_in));
  std::int32_t* out = result.mutable_data();
  std::vector<std::int64_t> bad(std::max<std::int64_t>(1, (m + kBlock - 1) / kBlock), -1);
  {
    py::gil_scoped_release release;
    const CellGrid grid = bucket(sites, cell, anchor);
    // Distance from x to the nearest face of the cell box [lo, hi] that is not on the grid's
    // border: no generator outside the box is nearer. +inf when the box is the whole grid.
    auto reach = [&](const double* x, const std::int64_t* lo, const std::int64_t* hi) {
      double nearest = std::numeric_limits<double>::infinity();
      for (int axis = 0; axis < 3; ++axis) {
        if (lo[axis] > 0) nearest = std::min(nearest, x[axis] - (grid.origin[axis] + lo[axis] * grid.cell));
        if (hi[axis] < grid.dims[axis] - 1) {
          nearest = std::min(nearest, grid.origin[axis] + (hi[axis] + 1) * grid.cell - x[axis]);
        }
      }
      return std::max(0.0, nearest);
    };
    auto search_block = [&](int, std::int64_t block) {
      // The k best so far as (squared distance, index), sorted: ties go to the lower index, so
      // the answer does not depend on the order in which generators are visited.
      std::vector<std::pair<double, std::int64_t>> best;
      best.reserve(k + 1);
      auto offer = [&](double squared, std::int64_t g) {
        const std::pair<double, std::int64_t> entry{squared, g};
        if (static_cast<std::int64_t>(best.size()) == k && !(entry < best.back())) return;
        // Insertion from the back: k is small, and most entries that get here go near the end.
        if (static_cast<std::int64_t>(best.size()) < k) best.push_back(entry);
        std::size_t slot = best.size() - 1;
        for (; slot > 0 && entry < best[slot - 1]; --slot) best[slot] = best[slot - 1];
        best[slot] = entry;
      };
      auto box_members = [&](const std::int64_t* lo, const std::int64_t* hi, auto&& visit) {
        for (std::int64_t a = lo[0]; a <= hi[0]; ++a) {
          for (std::int64_t b = lo[1]; b <= hi[1]; ++b) {
            const std::int64_t row = (a * grid.dims[1] + b) * grid.dims[2];
            for (std::int64_t e = grid.start[row + lo[2]]; e < grid.start[row + hi[2] + 1]; ++e) visit(grid.members[e]);
          }
        }
      };
      // Consecutive samples in one cell (the fit passes them sorted by voxel) share the generators
      // of the box of kLocalRings rings around it, copied once coordinate-major so that the
      // distance loop vectorises; a sample whose k-th nearest lies beyond the box searches again.
      constexpr std::int64_t kLocalRings = 2;
      std::int64_t local_centre[3] = {-1, -1, -1}, local_lo[3] = {0, 0, 0}, local_hi[3] = {0, 0, 0};
      std::vector<double> local_x, local_y, local_z, local_squared;
      std::vector<std::int64_t> local_index, previous;  // the last sample's k best, all in the box
      std::vector<std::uint32_t> local_kept;
      for (std::int64_t s = block * kBlock; s < std::min(m, (block + 1) * kBlock); ++s) {
        const double x[3] = {samples(s, 0), samples(s, 1), samples(s, 2)};
        if (!(std::isfinite(x[0]) && std::isfinite(x[1]) && std::isfinite(x[2]))) {
          bad[block] = s;
          return;
        }
        std::int64_t centre[3];
        for (int axis = 0; axis < 3; ++axis) centre[axis] = grid.coordinate(x[axis], axis);
        if (!std::equal(centre, centre + 3, local_centre)) {
          std::copy(centre, centre + 3, local_centre);
          for (int axis = 0; axis < 3; ++axis) {
            local_lo[axis] = std::max<std::int64_t>(0, centre[axis] - kLocalRings);
            local_hi[axis] = std::min(grid.dims[axis] - 1, centre[axis] + kLocalRings);
          }
          local_x.clear(), local_y.clear(), local_z.clear(), local_index.clear();
          box_members(local_lo, local_hi, [&](std::int64_t g) {
            local_x.push_back(sites[3 * g]), local_y.push_back(sites[3 * g + 1]), local_z.push_back(sites[3 * g + 2]);
            local_index.push_back(g);
          });
          local_squared.resize(local_index.size());
          local_kept.resize(local_index.size());
          previous.clear();
        }
        // The last sample's k best are box members, so the farthest of them from x bounds x's k-th
        // nearest in the box: members beyond it cannot enter (the same computed distances, so exact).
        double bound = std::numeric_limits<double>::infinity();
        if (static_cast<std::int64_t>(previous.size()) == k) {
          bound = 0.0;
          for (std::int64_t g : previous) {
            const double dx = sites[3 * g] - x[0], dy = sites[3 * g + 1] - x[1], dz = sites[3 * g + 2] - x[2];
            bound = std::max(bound, dx * dx + dy * dy + dz * dz);
          }
          bound *= 1.0 + 1e-12;  // in case the compiler contracts one of the two sums differently
        }
        best.clear();
        const std::size_t count = local_index.size();
        for (std::size_t e = 0; e < count; ++e) {
          const double dx = local_x[e] - x[0], dy = local_y[e] - x[1], dz = local_z[e] - x[2];
          local_squared[e] = dx * dx + dy * dy + dz * dz;
        }
        // Branch-free compaction first: which members pass is close to random, the branch is not.
        const double* squared = local_squared.data();
        std::uint32_t* kept = local_kept.data();
        std::size_t n_kept = 0;
        for (std::size_t e = 0; e < count; ++e) {
          kept[n_kept] = static_cast<std::uint32_t>(e);
          n_kept += squared[e] <= bound;
        }
        for (std::size_t i = 0; i < n_kept; ++i) offer(squared[kept[i]], local_index[kept[i]]);
        previous.clear();
        if (static_cast<std::int64_t>(best.size()) == k) {
          for (const auto& entry : best) previous.push_back(entry.second);
        }
        const double local_reach = reach(x, local_lo, local_hi);
        const bool done = static_cast<std::int64_t>(best.size()) == k && best.back().first <= local_reach * local_reach;
        // Rings of cells around the sample's, each adding the cells of the next shell, until no
        // unseen generator can be nearer than the k-th best. The box holds every cell of the first
        // kLocalRings rings, and best its k nearest there (members past the bound cannot be among
        // them), so the rings go on from the next one.
        for (std::int64_t ring = kLocalRings + 1; !done; ++ring) {
          std::int64_t lo[3], hi[3];
          for (int axis = 0; axis < 3; ++axis) {
            lo[axis] = std::max<std::int64_t>(0, centre[axis] - ring);
            hi[axis] = std::min(grid.dims[axis] - 1, centre[axis] + ring);
          }
          for (std::int64_t a = lo[0]; a <= hi[0]; ++a) {
            for (std::int64_t b = lo[1]; b <= hi[1]; ++b) {
              // Inside the shell only the two end cells of a row are new.
              const bool whole_row = std::abs(a - centre[0]) == ring || std::abs(b - centre[1]) == ring;
              for (std::int64_t c = lo[2]; c <= hi[2]; ++c) {
                if (!whole_row && std::abs(c - centre[2]) != ring) continue;
                const std::int64_t id = (a * grid.dims[1] + b) * grid.dims[2] + c;
                for (std::int64_t e = grid.start[id]; e < grid.start[id + 1]; ++e) {
                  const std::int64_t g = grid.members[e];
                  const double dx = sites[3 * g] - x[0], dy = sites[3 * g + 1] - x[1], dz = sites[3 * g + 2] - x[2];
                  offer(dx * dx + dy * dy + dz * dz, g);
                }
              }
            }
          }
          const double ring_reach = reach(x, lo, hi);
          if (ring_reach == std::numeric_limits<double>::infinity()) break;  // the whole grid searched
          if (static_cast<std::int64_t>(best.size()) == k && best.back().first <= ring_reach * ring_reach) break;
        }
        const std::int64_t row = rows == nullptr ? s : rows[s];
        for (std::int64_t r = 0; r < k; ++r) out[row * k + r] = static_cast<std::int32_t>(best[r].second);
      }
    };
    parallel_for(threads, (m + kBlock - 1) / kBlock, search_block);
  }
  for (std::int64_t row : bad) {
    if (row >= 0) throw py::value_error("samples holds NaN or inf at row " + std::to_string(row));
  }
  return result;
}

py::array_t<std::int32_t> nearest_generators(const py::object& samples_in, const py::object& generators_in,
                                             std::int64_t k, double cell, const py::object& anchor_in, int threads,
                                             const py::object& out_in, const py::object& rows_in) {
  py::array samples = numpy_array(samples_in, "samples");
  py::array generators = numpy_array(generators_in, "generators");
  check_columns(samples, "samples", "(m, 3)", 3);
  check_columns(generators, "generators", "(n, 3)", 3);
  const std::int64_t m = samples.shape(0);
  const std::int64_t n = generators.shape(0);
  if (k < 1 || k > n || k > std::numeric_limits<std::int32_t>::max()) {
    throw py::value_error("k must be in [1, " + std::to_string(n) + "] (the number of generators), got " +
                          std::to_string(k));
  }
  if (n > std::numeric_limits<std::int32_t>::max()) throw py::value_error("generators must number under 2^31");
  if (!(std::isfinite(cell) && cell > 0)) throw py::value_error("cell must be a finite number > 0, got " + std::to_string(cell));
  if (threads < 1) throw py::value_error("threads must be >= 1, got " + std::to_string(threads));
  const double anchor = anchor_in.is_none() ? std::numeric_limits<double>::quiet_NaN() : anchor_in.cast<double>();
  if (!anchor_in.is_none() && !std::isfinite(anchor)) throw py::value_error("anchor must be finite, got " + std::to_string(anchor));
  check_real_pair(samples, generators);
  // The answer goes to rows[s] of out when given (the fit's candidates, in the samples' own order,
  // while the search runs in spatial order): no gather of the whole answer afterwards.
  if (out_in.is_none() != rows_in.is_none()) throw py::value_error("out and rows must be given together");
  py::array_t<std::int32_t> result;
  std::vector<std::int64_t> rows;
  if (out_in.is_none()) {
    result = py::array_t<std::int32_t>({m, k});
  } else {
    py::array out = numpy_array(out_in, "out");
    if (!py::isinstance<py::array_t<std::int32_t>>(out)) throw py::type_error("out must be int32, got dtype " + dtype_name(out));
    if (out.ndim() != 2 || out.shape(1) != k) {
      throw py::value_error("out must have shape (rows, " + std::to_string(k) + "), got " + shape_of(out));
    }
    if (!out.writeable() || !(out.flags() & py::array::c_style)) throw py::value_error("out must be writeable and C-contiguous");
    result = py::reinterpret_borrow<py::array_t<std::int32_t>>(out);
    py::array row_array = numpy_array(rows_in, "rows");
    if (row_array.ndim() != 1 || row_array.shape(0) != m) {
      throw py::value_error("rows must have shape (" + std::to_string(m) + ",) like samples, got " + shape_of(row_array));
    }
    auto given = py::array_t<std::int64_t, py::array::forcecast>(row_array);
    rows.assign(given.data(), given.data() + m);
    // Distinct rows: two samples written to one row would race between threads.
    std::vector<char> taken(static_cast<std::size_t>(out.shape(0)), 0);
    for (std::int64_t row : rows) {
      if (row < 0 || row >= out.shape(0)) {
        throw py::value_error("rows holds " + std::to_string(row) + ", outside [0, " + std::to_string(out.shape(0)) + ")");
      }
      if (taken[row]) throw py::value_error("rows holds " + std::to_string(row) + " twice; rows must be distinct");
      taken[row] = 1;
    }
  }
  const std::int64_t* row_data = rows.empty() ? nullptr : rows.data();
  return py::isinstance<py::array_t<float>>(samples)
             ? nearest_impl<float>(samples, generators, k, cell, anchor, threads, result, row_data)
             : nearest_impl<double>(samples, generators, k, cell, anchor, threads, result, row_data);
}

}  // namespace

void register_winding(py::module_& module);  // voro3d_winding.cpp
void register_filter(py::module_& module);   // voro3d_filter.cpp
void register_imls(py::module_& module);     // voro3d_imls.cpp

PYBIND11_MODULE(_fitkernel, module) {
  module.doc() = "The VoroMesh fit's inner step on CPU: VoroLoss and its gradient in one threaded pass; point winding numbers; bilateral normal filtering; the IMLS field.";
  register_winding(module);
  register_filter(module);
  register_imls(module);
  module.def("voroloss", &voroloss, py::arg("samples"), py::arg("generators"), py::arg("candidates"),
             py::arg("grad") = py::none(), py::arg("threads") = 1, py::arg("sides") = py::none(),
             R"doc(VoroLoss of samples over their candidate generators, and optionally its gradient.

For each sample ``x`` the nearest candidate ``q_i`` and the candidate ``q_j`` whose bisector plane
with ``q_i`` is nearest are found; the loss is the mean over samples of the squared distance from
``x`` to that plane, as :func:`voro3d.loss.voroloss` with ``candidates``. Arithmetic is in float64.

Parameters
----------
samples : (m, 3) float32 or float64 array, any strides
generators : (n, 3) array of the same dtype, n >= 2
candidates : (m, c) int32 or int64 array, c >= 2
    Generator indices to search per sample, in [0, n).
grad : (n, 3) writeable array of the generators' dtype, optional
    Overwritten with the gradient of the loss in the generators. Terms are summed in fixed point,
    so it is bitwise the same for any ``threads``; a term is clamped to +-4096 (two generators
    within about 1e-6 of each other in the fit frame).
threads : int
    Threads to use, >= 1.
sides : (n,) bool or uint8 array, optional
    Each generator's label: ``q_j`` is then sought among the candidates on the other side of ``q_i``
    only (the loss of the surface between inside and outside cells); a sample with none adds nothing.

Returns
-------
float
    The loss.

Raises
------
ValueError
    Bad shapes, NaN or inf, candidate indices outside [0, n), threads < 1, read-only grad, sides
    not one label per generator.
TypeError
    Not arrays, or wrong dtypes.
)doc");
  module.def("nearest_generators", &nearest_generators, py::arg("samples"), py::arg("generators"), py::arg("k"),
             py::kw_only(), py::arg("cell"), py::arg("anchor") = py::none(), py::arg("threads") = 1, py::arg("out") = py::none(),
             py::arg("rows") = py::none(),
             R"doc(Indices of the k generators nearest to each sample, nearest first (exact, ties to the lower index).

The generators are bucketed in a grid of cubic cells of side ``cell`` (coarsened if that would
make over 64 cells per generator or 2^24 in all), and each sample searches rings of cells around its own until no unseen
generator can be nearer than its k-th. The fit passes its voxel size, about one generator a cell.

Parameters
----------
samples : (m, 3) float32 or float64 array, any strides
generators : (n, 3) array of the same dtype
k : int
    In [1, n].
cell : float
    Side of the bucket cells, > 0; only the speed depends on it.
anchor : float, optional
    Cells aligned to ``anchor + j * cell`` on every axis (j integer) instead of starting at the
    generators' lowest coordinates. Samples passed in the order of these same cells meet each
    cell in one run: the search is about twice as fast as when the cells straddle the order's
    (a fit's generators have moved since the first search). Only the speed depends on it.
threads : int
    Threads to use, >= 1.
out : (r, k) int32 writeable C-contiguous array, optional
rows : (m,) int array, optional
    Given together: the answer for sample ``s`` is written to ``out[rows[s]]`` (other rows are
    left as they are) and ``out`` is returned. Rows must be distinct.

Returns
-------
(m, k) int32 array, or ``out``

Raises
------
ValueError
    Bad shapes, NaN or inf, k outside [1, n], cell <= 0, anchor not finite, threads < 1, rows outside ``out`` or
    repeated, ``out`` without ``rows`` or the other way round.
TypeError
    Not arrays, or wrong dtypes.
)doc");
}
