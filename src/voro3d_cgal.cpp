// Delaunay tetrahedralisation with CGAL's exact predicates, returned as numpy arrays.
// Python walks no CGAL objects: the cells are copied out in one pass.
#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>

#include <CGAL/Delaunay_triangulation_3.h>
#include <CGAL/Exact_predicates_exact_constructions_kernel.h>
#include <CGAL/Exact_predicates_inexact_constructions_kernel.h>
#include <CGAL/Triangulation_cell_base_with_info_3.h>
#include <CGAL/Triangulation_vertex_base_with_info_3.h>

#include <cstdint>
#include <stdexcept>
#include <utility>
#include <vector>

namespace py = pybind11;

namespace {
py::array_t<std::int64_t> to_array(const std::vector<std::int64_t>& values, py::ssize_t width) {
  py::array_t<std::int64_t> result({static_cast<py::ssize_t>(values.size()) / width, width});
  std::copy(values.begin(), values.end(), result.mutable_data());
  return result;
}
}  // namespace

using Kernel = CGAL::Exact_predicates_inexact_constructions_kernel;
using VertexBase = CGAL::Triangulation_vertex_base_with_info_3<std::int64_t, Kernel>;
using CellBase = CGAL::Triangulation_cell_base_with_info_3<std::int64_t, Kernel,
                                                         CGAL::Delaunay_triangulation_cell_base_3<Kernel>>;
using DataStructure = CGAL::Triangulation_data_structure_3<VertexBase, CellBase>;
using Delaunay = CGAL::Delaunay_triangulation_3<Kernel, DataStructure>;

// Returns the finite cells (m, 4), positively oriented, and the pairs of face-adjacent cells
// whose circumspheres coincide exactly (the opposite vertex lies on the sphere): those
// tetrahedra share one Voronoi vertex.
py::tuple delaunay_tetrahedra(py::array_t<double, py::array::c_style | py::array::forcecast> points) {
  if (points.ndim() != 2 || points.shape(1) != 3) {
    throw std::invalid_argument("points must have shape (n, 3)");
  }
  const auto n = static_cast<std::size_t>(points.shape(0));
  auto p = points.unchecked<2>();
  std::vector<std::pair<Kernel::Point_3, std::int64_t>> input;
  input.reserve(n);
  for (std::size_t i = 0; i < n; ++i) {
    input.emplace_back(Kernel::Point_3(p(i, 0), p(i, 1), p(i, 2)), static_cast<std::int64_t>(i));
  }
  std::vector<std::int64_t> cells;
  std::vector<std::int64_t> cospherical;
  {
    py::gil_scoped_release release;
    Delaunay triangulation(input.begin(), input.end());
    if (triangulation.dimension() < 3) {
      throw std::invalid_argument("points are coplanar: no 3D tetrahedralisation exists");
    }
    cells.reserve(4 * triangulation.number_of_finite_cells());
    std::int64_t index = 0;
    // CGAL stores every cell positively oriented.
    for (auto cell : triangulation.finite_cell_handles()) {
      cell->info() = index++;
      for (int i = 0; i < 4; ++i) cells.push_back(cell->vertex(i)->info());
    }
    for (auto cell : triangulation.finite_cell_handles()) {
      for (int i = 0; i < 4; ++i) {
        auto other = cell->neighbor(i);
        if (triangulation.is_infinite(other) || other->info() < cell->info()) continue;
        const auto& opposite = other->vertex(other->index(cell))->point();
        // perturb = false: the exact answer, ON_BOUNDARY for co-spherical points.
        if (triangulation.side_of_sphere(cell, opposite, false) == CGAL::ON_BOUNDARY) {
          cospherical.push_back(cell->info());
          cospherical.push_back(other->info());
        }
      }
    }
  }
  return py::make_tuple(to_array(cells, 4), to_array(cospherical, 2));
}

// Circumcentres with exact constructions, rounded to double: for slivers, whose
// floating-point circumcentre is ill-conditioned.
py::array_t<double> exact_circumcenters(
    py::array_t<double, py::array::c_style | py::array::forcecast> points,
    py::array_t<std::int64_t, py::array::c_style | py::array::forcecast> tets) {
  using Exact = CGAL::Exact_predicates_exact_constructions_kernel;
  auto p = points.unchecked<2>();
  auto t = tets.unchecked<2>();
  const auto m = tets.shape(0);
  py::array_t<double> result({m, static_cast<py::ssize_t>(3)});
  auto out = result.mutable_unchecked<2>();
  for (py::ssize_t c = 0; c < m; ++c) {
    Exact::Point_3 corner[4];
    for (int i = 0; i < 4; ++i) {
      const auto v = t(c, i);
      corner[i] = Exact::Point_3(p(v, 0), p(v, 1), p(v, 2));
    }
    const auto centre = CGAL::circumcenter(corner[0], corner[1], corner[2], corner[3]);
    out(c, 0) = CGAL::to_double(centre.x());
    out(c, 1) = CGAL::to_double(centre.y());
    out(c, 2) = CGAL::to_double(centre.z());
  }
  return result;
}

PYBIND11_MODULE(_cgal, module) {
  module.doc() = "CGAL Delaunay tetrahedralisation for voro3d";
  module.def("delaunay_tetrahedra", &delaunay_tetrahedra, py::arg("points"),
             "(tets (m, 4) int64 positively oriented, cospherical (p, 2) int64 pairs of cells "
             "sharing a circumsphere). Duplicate points keep the first index.");
  module.def("exact_circumcenters", &exact_circumcenters, py::arg("points"), py::arg("tets"),
             "Circumcentres (m, 3) computed exactly, rounded to float64.");
}
