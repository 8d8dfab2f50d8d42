// Delaunay tetrahedralisation and triangle-mesh self-intersections with CGAL's exact predicates,
// returned as numpy arrays. Python walks no CGAL objects: results are copied out in one pass.
//
// Every function checks its arrays (dtype, shape, finite coordinates, index bounds) and raises
// ValueError or TypeError naming the argument, then releases the GIL for the CGAL work.
#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>

#include "voro3d_checks.h"

#include <CGAL/Delaunay_triangulation_3.h>
#include <CGAL/Exact_predicates_exact_constructions_kernel.h>
#include <CGAL/Exact_predicates_inexact_constructions_kernel.h>
#include <CGAL/Triangulation_cell_base_with_info_3.h>
#include <CGAL/Triangulation_vertex_base_with_info_3.h>
#include <CGAL/box_intersection_d.h>
#include <CGAL/intersections.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <future>
#include <string>
#include <utility>
#include <vector>

namespace py = pybind11;

using voro3d::check_indices;
using voro3d::check_mask;
using voro3d::check_points;
using voro3d::Indices;
using voro3d::Points;
using voro3d::to_array;

using Kernel = CGAL::Exact_predicates_inexact_constructions_kernel;
using VertexBase = CGAL::Triangulation_vertex_base_with_info_3<std::int64_t, Kernel>;
using CellBase = CGAL::Triangulation_cell_base_with_info_3<std::int64_t, Kernel,
                                                         CGAL::Delaunay_triangulation_cell_base_3<Kernel>>;
using DataStructure = CGAL::Triangulation_data_structure_3<VertexBase, CellBase>;
using Delaunay = CGAL::Delaunay_triangulation_3<Kernel, DataStructure>;

// Returns the finite cells (m, 4), positively oriented, and the pairs of face-adjacent cells
// whose circumspheres coincide exactly (the opposite vertex lies on the sphere): those
// tetrahedra share one Voronoi vertex.
py::tuple delaunay_tetrahedra(const py::object& points_in) {
  Points points = check_points(points_in, "points", 4);
  const auto n = static_cast<std::size_t>(points.shape(0));
  auto p = points.unchecked<2>();
  std::vector<std::pair<Kernel::Point_3, std::int64_t>> input;
  input.reserve(n);
  for (std::size_t i = 0; i < n; ++i) {
    input.emplace_back(Kernel::Point_3(p(i, 0), p(i, 1), p(i, 2)), static_cast<std::int64_t>(i));
  }
  std::vector<std::int64_t> cells;
  std::vector<std::int64_t> cospherical;
  int dimension = 3;
  {
    py::gil_scoped_release release;
    Delaunay triangulation(input.begin(), input.end());
    dimension = triangulation.dimension();
    if (dimension == 3) {
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
  }
  if (dimension < 3) {
    static const char* flat[] = {"all coincide", "are collinear", "are coplanar"};
    throw py::value_error(std::string("points ") + flat[dimension < 0 ? 0 : dimension] + " (all " + std::to_string(n) +
                          " of them): no 3D tetrahedralisation exists");
  }
  return py::make_tuple(to_array(cells, 4), to_array(cospherical, 2));
}

// Circumcentres with exact constructions, rounded to double: for tetrahedra whose
// floating-point circumcentre is ill-conditioned.
py::array_t<double> exact_circumcenters(const py::object& points_in, const py::object& tets_in) {
  using Exact = CGAL::Exact_predicates_exact_constructions_kernel;
  Points points = check_points(points_in, "points", 0);
  Indices tets = check_indices(tets_in, "tets", 4, "m", points.shape(0), "points");
  auto p = points.unchecked<2>();
  auto t = tets.unchecked<2>();
  const auto m = tets.shape(0);
  py::array_t<double> result({m, static_cast<py::ssize_t>(3)});
  auto out = result.mutable_unchecked<2>();
  py::ssize_t flat = -1;
  {
    py::gil_scoped_release release;
    for (py::ssize_t c = 0; c < m; ++c) {
      Exact::Point_3 corner[4];
      for (int i = 0; i < 4; ++i) {
        const auto v = t(c, i);
        corner[i] = Exact::Point_3(p(v, 0), p(v, 1), p(v, 2));
      }
      if (CGAL::coplanar(corner[0], corner[1], corner[2], corner[3])) {
        flat = c;
        break;
      }
      const auto centre = CGAL::circumcenter(corner[0], corner[1], corner[2], corner[3]);
      // exact() first: a lazy number's to_double stops refining at a relative precision of
      // 1e-5 of its interval, which left thin-cell vertices 1e-11 off and their faces crossing.
      out(c, 0) = CGAL::to_double(CGAL::exact(centre.x()));
      out(c, 1) = CGAL::to_double(CGAL::exact(centre.y()));
      out(c, 2) = CGAL::to_double(CGAL::exact(centre.z()));
    }
  }
  if (flat >= 0) {
    throw py::value_error("tets row " + std::to_string(flat) +
                          " is flat (its four corners are coplanar, exactly), so it has no circumcentre");
  }
  return result;
}

namespace {
using Point = Kernel::Point_3;
using Segment = Kernel::Segment_3;
using Triangle = Kernel::Triangle_3;

// The point set of a mesh triangle: a triangle, or, when its corners are collinear, the segment
// between the two outermost of them, or one point. CGAL's Triangle_3 tests require a
// non-degenerate triangle.
struct Piece {
  int kind;  // 0 point (a), 1 segment (a, b), 2 triangle (a, b, c)
  Point a, b, c;
};

Piece piece_of(const Point& a, const Point& b, const Point& c) {
  if (!CGAL::collinear(a, b, c)) return {2, a, b, c};
  if (a == b && b == c) return {0, a, a, a};
  if (CGAL::collinear_are_ordered_along_line(a, b, c)) return {1, a, c, c};
  if (CGAL::collinear_are_ordered_along_line(b, a, c)) return {1, b, c, c};
  return {1, a, b, b};
}

// Whether the closed point sets meet (touching counts), decided with exact predicates only.
bool meet(const Piece& p, const Piece& q) {
  if (p.kind < q.kind) return meet(q, p);
  switch (3 * p.kind + q.kind) {
    case 8: return CGAL::do_intersect(Triangle(p.a, p.b, p.c), Triangle(q.a, q.b, q.c));
    case 7: return CGAL::do_intersect(Triangle(p.a, p.b, p.c), Segment(q.a, q.b));
    case 6: return Triangle(p.a, p.b, p.c).has_on(q.a);
    case 4: return CGAL::do_intersect(Segment(p.a, p.b), Segment(q.a, q.b));
    case 3: return Segment(p.a, p.b).has_on(q.a);
    default: return p.a == q.a;
  }
}

// Whether two non-degenerate triangles that share corners (`shared` of them, by position) meet
// beyond what they share, exactly. Sharing one corner v: they cross iff the edge of one opposite
// v meets the other (the segment along which they meet starts at v and ends on such an edge).
// Sharing an edge: only coplanar with both third corners on the same side (a fold flat on itself).
bool neighbours_cross(const Point (&p)[3], const Point (&q)[3], int shared) {
  auto corner_of = [](const Point (&x)[3], const Point (&y)[3], bool want_shared) {
    for (int k = 0; k < 3; ++k) {
      const bool in = x[k] == y[0] || x[k] == y[1] || x[k] == y[2];
      if (in == want_shared) return k;
    }
    return -1;
  };
  if (shared == 1) {
    const int vp = corner_of(p, q, true), vq = corner_of(q, p, true);
    if (vp < 0 || vq < 0) return false;
    const Segment opposite_p(p[(vp + 1) % 3], p[(vp + 2) % 3]);
    const Segment opposite_q(q[(vq + 1) % 3], q[(vq + 2) % 3]);
    return CGAL::do_intersect(Triangle(p[0], p[1], p[2]), opposite_q) ||
           CGAL::do_intersect(Triangle(q[0], q[1], q[2]), opposite_p);
  }
  if (shared == 2) {
    const int tp = corner_of(p, q, false), tq = corner_of(q, p, false);
    if (tp < 0 || tq < 0) return false;
    const Point& u = p[(tp + 1) % 3];
    const Point& w = p[(tp + 2) % 3];
    return CGAL::coplanar(u, w, p[tp], q[tq]) && CGAL::coplanar_orientation(u, w, p[tp], q[tq]) == CGAL::POSITIVE;
  }
  return false;
}

using Box = CGAL::Box_intersection_d::Box_with_info_d<double, 3, std::size_t>;
using Boxes = std::vector<Box>;

// Below this many triangles one thread does it all: a thread's start would not pay.
constexpr std::size_t kParallelBoxes = 2048;

// Box intersections to run: each box range against itself, and each pair of ranges against each
// other (the first range's boxes first in the callback).
struct BoxPart {
  std::vector<Boxes*> self;
  std::vector<std::pair<Boxes*, Boxes*>> between;
};

// The box pairs of a self-intersection test (or of changed boxes against all) in two parts of
// about equal work, for two threads. A box goes to the lower or the upper side of the plane
// x = m through the median of the boxes' lower x, by its lower x; two boxes on different sides
// meet only if the lower one reaches m, and few do (the plane crosses a surface along a curve).
// So part 0 is the lower side against itself and part 1 the upper side against itself and
// against the lower boxes that reach it: every meeting pair is in exactly one part, once.
struct BoxSplit {
  Boxes lower, upper, reaching;                         // all boxes, by side
  Boxes changed_lower, changed_upper, changed_reaching;  // changed boxes, by side
  BoxPart parts[2];

  BoxSplit(const Boxes& boxes, const Boxes* changed) {
    std::vector<double> low(boxes.size());
    for (std::size_t i = 0; i < boxes.size(); ++i) low[i] = boxes[i].min_coord(0);
    std::nth_element(low.begin(), low.begin() + low.size() / 2, low.end());
    const double m = low[low.size() / 2];
    auto divide = [m](const Boxes& in, Boxes& below, Boxes& above, Boxes& reach) {
      for (const auto& box : in) {
        (box.min_coord(0) < m ? below : above).push_back(box);
        if (box.min_coord(0) < m && box.max_coord(0) >= m) reach.push_back(box);
      }
    };
    divide(boxes, lower, upper, reaching);
    if (!changed) {
      parts[0].self = {&lower};
      parts[1].self = {&upper};
      parts[1].between = {{&reaching, &upper}};
      return;
    }
    divide(*changed, changed_lower, changed_upper, changed_reaching);
    parts[0].between = {{&changed_lower, &lower}};
    parts[1].between = {{&changed_upper, &upper}, {&changed_reaching, &upper}, {&changed_upper, &reaching}};
  }
};
}  // namespace

// Pairs (i < j) of triangles that cross, decided exactly: their closed point sets intersect, or,
// for neighbours sharing corners by index, they meet beyond those corners (neighbours_cross).
// Candidates are the pairs whose bounding boxes meet (CGAL's box intersection, Zomorodian and
// Edelsbrunner), so the cost follows the number of nearby pairs, not its square.
// With `changed`, a (t,) bool mask, only the pairs with at least one changed triangle are tested.
// With `parallel`, from kParallelBoxes triangles on, the work is split over two threads (see
// BoxSplit); the pairs are sorted, so the answer is the serial one.
py::array_t<std::int64_t> self_intersecting_pairs(const py::object& vertices_in, const py::object& triangles_in,
                                                  const py::object& changed_in, bool parallel) {
  Points vertices = check_points(vertices_in, "vertices", 0);
  Indices triangles = check_indices(triangles_in, "triangles", 3, "t", vertices.shape(0), "vertices");
  std::vector<char> changed;
  if (!changed_in.is_none()) {
    auto mask = check_mask(changed_in, "changed", triangles.shape(0)).unchecked<1>();
    changed.resize(static_cast<std::size_t>(triangles.shape(0)));
    for (py::ssize_t i = 0; i < triangles.shape(0); ++i) changed[i] = mask(i);
  }
  auto v = vertices.unchecked<2>();
  auto t = triangles.unchecked<2>();
  const auto f = static_cast<std::size_t>(triangles.shape(0));
  std::vector<std::int64_t> pairs;
  {
    py::gil_scoped_release release;
    std::vector<Point> points;
    points.reserve(static_cast<std::size_t>(v.shape(0)));
    for (py::ssize_t i = 0; i < v.shape(0); ++i) points.emplace_back(v(i, 0), v(i, 1), v(i, 2));
    std::vector<Piece> pieces;
    std::vector<Box> boxes;
    pieces.reserve(f);
    boxes.reserve(f);
    for (std::size_t i = 0; i < f; ++i) {
      const Point& a = points[t(i, 0)];
      const Point& b = points[t(i, 1)];
      const Point& c = points[t(i, 2)];
      pieces.push_back(piece_of(a, b, c));
      boxes.emplace_back(a.bbox() + b.bbox() + c.bbox(), i);  // doubles: the boxes are exact
    }
    auto shared_indices = [&](std::size_t i, std::size_t j) {
      int shared = 0;
      for (int k = 0; k < 3; ++k) {
        for (int l = 0; l < 3; ++l) shared += t(i, k) == t(j, l);
      }
      return shared;
    };
    // Neighbours (sharing corners by index) meet where they share them; they cross only beyond.
    auto crossing = [&](std::size_t i, std::size_t j) {
      if (shared_indices(i, j) == 0) return meet(pieces[i], pieces[j]);
      if (pieces[i].kind != 2 || pieces[j].kind != 2) return false;
      const Point p[3] = {points[t(i, 0)], points[t(i, 1)], points[t(i, 2)]};
      const Point q[3] = {points[t(j, 0)], points[t(j, 1)], points[t(j, 2)]};
      // Corners shared by position: a duplicated vertex (sheets touching) counts as shared.
      int shared = 0;
      for (const Point& x : p) shared += x == q[0] || x == q[1] || x == q[2];
      return neighbours_cross(p, q, shared);
    };
    // The pairs of one part of the work, into `found` (each thread has its own).
    auto search = [&](const BoxPart& part, std::vector<std::int64_t>& found) {
      auto test = [&](const Box& x, const Box& y) {
        const std::size_t i = std::min(x.info(), y.info());
        const std::size_t j = std::max(x.info(), y.info());
        if (crossing(i, j)) {
          found.push_back(static_cast<std::int64_t>(i));
          found.push_back(static_cast<std::int64_t>(j));
        }
      };
      // Closed boxes: boxes that only touch are candidates too.
      if (changed.empty()) {
        for (auto* self : part.self) CGAL::box_self_intersection_d(self->begin(), self->end(), test);
        for (const auto& [x, y] : part.between) CGAL::box_intersection_d(x->begin(), x->end(), y->begin(), y->end(), test);
        return;
      }
      // Changed boxes against all: a pair of two changed triangles comes once from each side and
      // is kept from the side of its smaller index.
      for (const auto& [x, y] : part.between) {
        CGAL::box_intersection_d(x->begin(), x->end(), y->begin(), y->end(), [&](const Box& a, const Box& b) {
          if (a.info() == b.info() || (changed[b.info()] && b.info() < a.info())) return;
          test(a, b);
        });
      }
    };
    std::vector<Box> changed_boxes;
    if (!changed.empty()) {
      for (const auto& box : boxes) {
        if (changed[box.info()]) changed_boxes.push_back(box);
      }
    }
    if (parallel && f >= kParallelBoxes) {
      BoxSplit split(boxes, changed.empty() ? nullptr : &changed_boxes);
      std::vector<std::int64_t> other;
      auto lower = std::async(std::launch::async, [&] { search(split.parts[0], other); });
      search(split.parts[1], pairs);
      lower.get();
      pairs.insert(pairs.end(), other.begin(), other.end());
    } else {
      BoxPart whole;
      if (changed.empty()) {
        whole.self.push_back(&boxes);
      } else {
        whole.between.emplace_back(&changed_boxes, &boxes);
      }
      search(whole, pairs);
    }
    // Sorted, so that the order depends neither on how the box intersection split its work nor
    // on the threads.
    std::vector<std::pair<std::int64_t, std::int64_t>> sorted(pairs.size() / 2);
    for (std::size_t k = 0; k < sorted.size(); ++k) sorted[k] = {pairs[2 * k], pairs[2 * k + 1]};
    std::sort(sorted.begin(), sorted.end());
    for (std::size_t k = 0; k < sorted.size(); ++k) {
      pairs[2 * k] = sorted[k].first;
      pairs[2 * k + 1] = sorted[k].second;
    }
  }
  return to_array(pairs, 2);
}

// src/voro3d_clean.cpp
void register_clean(py::module_& module);

PYBIND11_MODULE(_cgal, module) {
  module.doc() = "CGAL Delaunay tetrahedralisation, self-intersection test and surface cleaning for voro3d";
  register_clean(module);
  module.def("delaunay_tetrahedra", &delaunay_tetrahedra, py::arg("points"),
             "(tets (m, 4) int64 positively oriented, cospherical (p, 2) int64 pairs of cells "
             "sharing a circumsphere) of finite (n, 3) points, n >= 4, not all on one plane. "
             "Duplicate points keep the first index.");
  module.def("exact_circumcenters", &exact_circumcenters, py::arg("points"), py::arg("tets"),
             "Circumcentres (m, 3) of the (m, 4) tets indexing finite (n, 3) points, computed exactly, "
             "rounded to float64. Flat tets are a ValueError.");
  module.def("self_intersecting_pairs", &self_intersecting_pairs, py::arg("vertices"), py::arg("triangles"),
             py::arg("changed") = py::none(), py::arg("parallel") = true,
             "(p, 2) int64 sorted pairs i < j of the (t, 3) triangles over finite (n, 3) vertices that share "
             "no vertex index and intersect, touching included, decided with exact predicates; collinear "
             "triangles count as their segment. With changed, a (t,) bool mask, only the pairs holding a "
             "changed triangle. With parallel, large meshes are split over two threads (the same pairs).");
}
