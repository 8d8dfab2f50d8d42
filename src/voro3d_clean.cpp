// Cleaning of a closed, oriented, manifold triangle surface (a VoroMesh), in passes of: nearly
// coincident vertices merged, short edges collapsed as CGAL's Surface_mesh_simplification does, then
// edges flipped where that raises the smallest angle. Frozen vertices are never moved, merged or
// flipped around. Self-intersections are tested by the caller (voro3d/cleaning.py), which freezes
// the input vertices behind crossing triangles and has the changes, logged by clean_surface, made
// again without them by replay_clean.
//
// Distance bound. Every face F carries a bound E(F) (0 at the start) such that every point of F is
// within E(F) of the input surface and every point of the input that F stands for is within E(F)
// of F. A collapse or flip replaces a disk of faces by another disk with the same boundary, and
// each new face gets a bound from one of two arguments:
// - Graph: when some direction n (the mean normal of the old disk) makes both disks graphs (every
//   triangle facing n, each interior vertex's angles summing to one turn), the two height functions
//   differ by a piecewise-linear function on the overlay of the two projected triangulations, whose
//   largest value (the gap) is at an overlay vertex: a vertex of either disk or a crossing of their
//   edges. Points of a new face are within the gap (along n) of points of the old faces whose
//   projections overlap it, and the other way round: E = gap + the largest of those faces' E.
// - Displacement: a face that keeps two corners and whose third moves by s has every point within s
//   of the same barycentric point of the old face: E = E(old) + s; the two faces a collapse removes
//   map onto the new edges to their third corners.
// A change whose new bounds exceed max_distance, or that takes the volume change of all changes so
// far beyond max_volume_change, is not made.
//
// Why not CGAL's Polyhedral_envelope (the exact envelope test that Polyhedral_envelope_filter
// uses): measured on fandisk at 32^3 (11k triangles), its triangle test takes 107 us a call and
// cleaning 2.9 s, over the fit's own 2.4 s; these bounds cost a few microseconds a change. The
// displacement bound alone counts sliding along the surface as distance: it kept 83-90% of the faces.
#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>

#include "voro3d_checks.h"

#include <CGAL/Exact_predicates_inexact_constructions_kernel.h>
#include <CGAL/Surface_mesh.h>
#include <CGAL/Surface_mesh_simplification/Policies/Edge_collapse/Edge_profile.h>
#include <CGAL/Surface_mesh_simplification/Policies/Edge_collapse/LindstromTurk_placement.h>
#include <CGAL/boost/graph/helpers.h>
#include <CGAL/boost/graph/Euler_operations.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <deque>
#include <functional>
#include <memory>
#include <queue>
#include <stdexcept>
#include <string>
#include <tuple>
#include <utility>
#include <vector>

namespace py = pybind11;

namespace {
using Kernel = CGAL::Exact_predicates_inexact_constructions_kernel;
using Point = Kernel::Point_3;
using Vector = Kernel::Vector_3;
using Mesh = CGAL::Surface_mesh<Point>;
using Vertex = Mesh::Vertex_index;
using Face = Mesh::Face_index;
using FaceBound = Mesh::Property_map<Face, double>;
using Triangle = std::array<int, 3>;
namespace SMS = CGAL::Surface_mesh_simplification;

// A disk replaced by another with the same boundary, in local vertex indices, with the vertices
// and edges inside each disk (not on the boundary); graph_gap fills the projected coordinates x, y
// and the heights z. Reused from change to change, so that testing one allocates nothing.
struct Patch {
  std::vector<Point> points;
  std::vector<Triangle> before, after;
  std::vector<int> inner_before, inner_after;
  std::vector<std::pair<int, int>> edges_before, edges_after;
  std::vector<double> x, y, z;

  void clear() {
    points.clear();
    before.clear();
    after.clear();
    inner_before.clear();
    inner_after.clear();
    edges_before.clear();
    edges_after.clear();
  }

  // The edges of `triangles` at an interior vertex: all interior, each listed once (its two
  // triangles run it in opposite directions, one of them from the smaller index).
  static void edges_at(const std::vector<Triangle>& triangles, const std::vector<int>& inner,
                       std::vector<std::pair<int, int>>& edges) {
    auto is_inner = [&](int v) {  // one or two of them: compared with each, not searched
      bool found = false;
      for (const int w : inner) found |= v == w;
      return found;
    };
    for (const auto& t : triangles) {
      for (int k = 0; k < 3; ++k) {
        const int a = t[k], b = t[(k + 1) % 3];
        if (a < b && (is_inner(a) || is_inner(b))) edges.emplace_back(a, b);
      }
    }
  }
};

// The largest gap between the two disks of `patch` along the mean normal of `before`, or -1 when
// that direction does not make both of them graphs (see the top of the file).
double graph_gap(Patch& patch) {
  Vector normal = CGAL::NULL_VECTOR;
  for (const auto& t : patch.before) {
    normal = normal + CGAL::cross_product(patch.points[t[1]] - patch.points[t[0]], patch.points[t[2]] - patch.points[t[0]]);
  }
  const double length = std::sqrt(normal.squared_length());
  if (!(length > 0)) return -1;
  normal = normal / length;
  const Vector helper = std::abs(normal.x()) < 0.9 ? Vector(1, 0, 0) : Vector(0, 1, 0);
  Vector e1 = CGAL::cross_product(normal, helper);
  e1 = e1 / std::sqrt(e1.squared_length());
  const Vector e2 = CGAL::cross_product(normal, e1);
  const std::size_t n = patch.points.size();
  std::vector<double>&x = patch.x, &y = patch.y, &z = patch.z;
  x.resize(n);
  y.resize(n);
  z.resize(n);
  for (std::size_t i = 0; i < n; ++i) {
    const Vector d = patch.points[i] - patch.points[0];
    x[i] = d * e1;
    y[i] = d * e2;
    z[i] = d * normal;
  }
  // Seen along the normal, every triangle must face it (its normal within 89.9 degrees).
  for (const auto* triangles : {&patch.before, &patch.after}) {
    for (const auto& t : *triangles) {
      const Vector c = CGAL::cross_product(patch.points[t[1]] - patch.points[t[0]], patch.points[t[2]] - patch.points[t[0]]);
      const double area = std::sqrt(c.squared_length());
      if (!(area > 0) || c * normal < 1e-3 * area) return -1;
    }
  }
  // The projected height at (u, v) of a disk: the triangle holding it, else NaN.
  auto height = [&](const std::vector<Triangle>& triangles, double u, double v) {
    double best = -1e300, value = NAN;
    for (const auto& t : triangles) {
      const double ax = x[t[0]], ay = y[t[0]];
      const double det = (x[t[1]] - ax) * (y[t[2]] - ay) - (x[t[2]] - ax) * (y[t[1]] - ay);
      const double l1 = ((u - ax) * (y[t[2]] - ay) - (x[t[2]] - ax) * (v - ay)) / det;
      const double l2 = ((x[t[1]] - ax) * (v - ay) - (u - ax) * (y[t[1]] - ay)) / det;
      const double l0 = 1 - l1 - l2;
      const double inside = std::min({l0, l1, l2});
      // Selected without a branch, as the crossings below.
      const bool better = inside > best;
      const double here = l0 * z[t[0]] + l1 * z[t[1]] + l2 * z[t[2]];
      best = better ? inside : best;
      value = better ? here : value;
    }
    return best >= -1e-9 ? value : NAN;
  };
  const auto& edges_before = patch.edges_before;
  const auto& edges_after = patch.edges_after;
  const auto& inner_before = patch.inner_before;
  const auto& inner_after = patch.inner_after;
  // One turn around each interior vertex: a graph, not a disk wrapped twice around it. Every
  // triangle faces the normal, so each turns by less than half a turn around its corner, and the
  // turns add up to whole ones: counted in pseudo-angles (a quarter turn is 1, monotone in the
  // angle; no atan2), the sum is 4 per turn.
  auto pseudo_angle = [](double dx, double dy) {
    const double p = dx / (std::abs(dx) + std::abs(dy));  // 1 -> -1 as the angle goes 0 -> pi
    return dy >= 0 ? 1 - p : 3 + p;
  };
  for (const auto* side : {&patch.before, &patch.after}) {
    const auto& inner = side == &patch.before ? inner_before : inner_after;
    for (int w : inner) {
      double turn = 0;
      for (const auto& t : *side) {
        for (int k = 0; k < 3; ++k) {
          if (t[k] != w) continue;
          const int a = t[(k + 1) % 3], b = t[(k + 2) % 3];
          const double step = pseudo_angle(x[b] - x[w], y[b] - y[w]) - pseudo_angle(x[a] - x[w], y[a] - y[w]);
          turn += step < 0 ? step + 4 : step;
        }
      }
      if (turn > 6) return -1;
    }
  }
  double gap = 0;
  for (int w : inner_before) {
    const double h = height(patch.after, x[w], y[w]);
    if (std::isnan(h)) return -1;
    gap = std::max(gap, std::abs(h - z[w]));
  }
  for (int w : inner_after) {
    const double h = height(patch.before, x[w], y[w]);
    if (std::isnan(h)) return -1;
    gap = std::max(gap, std::abs(h - z[w]));
  }
  // Every pair of edges is computed and its gap kept where they cross, without a branch: which
  // pairs cross is unpredictable, and the mispredicted branches took more time than the divisions
  // (half of this function's, 80 pairs a collapse).
  for (const auto& [a, b] : edges_before) {
    const double rx = x[b] - x[a], ry = y[b] - y[a];
    for (const auto& [c, d] : edges_after) {
      const double sx = x[d] - x[c], sy = y[d] - y[c];
      const double den = rx * sy - ry * sx;
      const double s = ((x[c] - x[a]) * sy - (y[c] - y[a]) * sx) / den;
      const double t = ((x[c] - x[a]) * ry - (y[c] - y[a]) * rx) / den;
      const bool crossing = (a != c) & (a != d) & (b != c) & (b != d) & (den != 0) &
                            !((s < 0) | (s > 1) | (t < 0) | (t > 1));
      const double here[2] = {0.0, std::abs((z[a] + s * (z[b] - z[a])) - (z[c] + t * (z[d] - z[c])))};
      gap = std::max(gap, here[crossing]);
    }
  }
  return gap;
}

// Whether the projections of two triangles of `patch` overlap (touching counts): no edge of either
// separates them.
bool overlap(const Patch& patch, const Triangle& p, const Triangle& q) {
  const auto& x = patch.x;
  const auto& y = patch.y;
  // Every edge tested, without a branch: whether one separates is unpredictable.
  auto separates = [&](const Triangle& a, const Triangle& b) {
    bool found = false;
    for (int k = 0; k < 3; ++k) {
      const int i = a[k], j = a[(k + 1) % 3], o = a[(k + 2) % 3];
      auto side = [&](int w) { return (x[j] - x[i]) * (y[w] - y[i]) - (y[j] - y[i]) * (x[w] - x[i]); };
      const double own = side(o);
      found |= (own != 0) & (side(b[0]) * own < 0) & (side(b[1]) * own < 0) & (side(b[2]) * own < 0);
    }
    return found;
  };
  return !(separates(p, q) | separates(q, p));
}

// A set of indices emptied in constant time: i is in it while stamp[i] is the current stamp (the
// stamps are cleared only when the counter wraps round).
struct Marks {
  std::vector<std::uint32_t> stamp;
  std::uint32_t current = 0;

  void resize(std::size_t n) { stamp.assign(n, 0); }
  void clear() {
    if (++current == 0) {
      std::fill(stamp.begin(), stamp.end(), 0);
      current = 1;
    }
  }
  bool has(std::size_t i) const { return stamp[i] == current; }
  void add(std::size_t i) { stamp[i] = current; }
};

// Union-find over input vertex indices: parent[v] is the vertex v was merged into.
struct Merges {
  std::vector<std::int64_t> parent;

  std::int64_t find(std::int64_t v) {
    while (parent[v] != v) {
      parent[v] = parent[parent[v]];
      v = parent[v];
    }
    return v;
  }
};

// One change of a cleaning run, enough to make it again on the same input (replay_clean).
struct Operation {
  enum Kind : std::uint8_t { kPass, kCollapse, kFlip } kind;
  std::uint32_t a = 0, b = 0;  // collapse: the vertex merged away and the one kept; flip: the edge, a -> b
  Point placement;             // collapse: where the kept vertex goes
  std::uint32_t first = 0, last = 0;  // the new bounds of its faces: CleanLog::bounds[first:last]
  double volume = 0;
};

// The changes of one clean_surface call, in order, and what replaying them needs.
struct CleanLog {
  std::size_t n_vertices = 0, n_triangles = 0;
  double max_distance = 0, max_volume_change = 0;  // per pass
  double flip_margin = 0;
  std::vector<Operation> operations;
  std::vector<std::pair<std::uint32_t, double>> bounds;  // (face, bound)
  // The surface the call was given, built, and its arrays: replay_clean copies the mesh when it is
  // given the same arrays instead of building it again (a tenth of its time at 64^3).
  std::shared_ptr<const Mesh> input;
  std::vector<double> input_points;
  std::vector<std::int64_t> input_triangles;

  void add(Operation::Kind kind, std::uint32_t a, std::uint32_t b, const Point& placement,
           const std::vector<std::pair<Face, double>>& face_bounds, double volume) {
    Operation operation{kind, a, b, placement, static_cast<std::uint32_t>(bounds.size()), 0, volume};
    for (const auto& [face, bound] : face_bounds) bounds.emplace_back(face.idx(), bound);
    operation.last = static_cast<std::uint32_t>(bounds.size());
    operations.push_back(operation);
  }
};

// What the collapse filter and visitor share: frozen vertices, face bounds, the last accepted bound.
struct State {
  const std::vector<char>* frozen;
  FaceBound bound;
  double max_distance;
  double max_volume_change;
  double volume_change = 0;  // signed, of the changes made so far
  // The last accepted collapse: the new bound of each face it keeps, its volume change.
  std::vector<std::pair<Face, double>> accepted;
  double accepted_volume = 0;
  Merges merges;
  CleanLog* log = nullptr;
  // Workspace of bound_collapse (the patch: of bound_flip too).
  Patch patch;
  // A vertex's local index is local_index[v] while v is in `local`, and a face was seen while it
  // is in `seen`: searching the patch's lists instead mispredicted where each search ended, a
  // third of the mispredicted branches of a clean.
  Marks local, seen;
  std::vector<int> local_index;
  std::vector<Face> kept;
  std::vector<double> old_bound, shifted;
  std::vector<int> by_bound;
  std::vector<std::pair<int, double>> removed;  // third vertex and bound of the two faces on the edge

  // Workspace of satisfies_link_condition: the neighbours of one end of the edge.
  Marks marked;

  bool volume_allows(double change) const { return std::abs(volume_change + change) <= max_volume_change; }

  // Makes the last accepted change's bounds and volume change those of the surface.
  void apply_accepted() {
    for (const auto& [face, face_bound] : accepted) bound[face] = face_bound;
    volume_change += accepted_volume;
  }

  // Records a collapse just made (gone merged into kept at placement): merges, bounds, volume, log.
  void commit_collapse(Vertex gone, Vertex kept, const Point& placement) {
    merges.parent[gone.idx()] = kept.idx();
    apply_accepted();
    log->add(Operation::kCollapse, gone.idx(), kept.idx(), placement, accepted, accepted_volume);
  }
};

// The new bound of each face that collapsing v0-v1 to `placement` keeps, into state->accepted;
// false when a vertex is frozen or a bound would exceed max_distance (see the top of the file).
bool bound_collapse(const Mesh& mesh, State* state, Vertex v0, Vertex v1, const Point& placement) {
  if ((*state->frozen)[v0.idx()] || (*state->frozen)[v1.idx()]) return false;
  Patch& patch = state->patch;
  auto& kept = state->kept;
  auto& old_bound = state->old_bound;
  auto& shifted = state->shifted;
  auto& removed = state->removed;
  patch.clear();
  kept.clear();
  old_bound.clear();
  shifted.clear();
  removed.clear();
  state->local.clear();
  state->seen.clear();
  auto index = [&](Vertex v) {
    if (state->local.has(v.idx())) return state->local_index[v.idx()];
    state->local.add(v.idx());
    state->local_index[v.idx()] = static_cast<int>(patch.points.size());
    patch.points.push_back(mesh.point(v));
    return static_cast<int>(patch.points.size() - 1);
  };
  const int i0 = index(v0), i1 = index(v1);
  const int ip = static_cast<int>(patch.points.size());
  patch.points.push_back(placement);
  const double shift[2] = {std::sqrt(CGAL::squared_distance(mesh.point(v0), placement)),
                           std::sqrt(CGAL::squared_distance(mesh.point(v1), placement))};
  double volume = 0;  // of the old faces seen from the placement; the new ones all hold it
  for (const Vertex centre : {v0, v1}) {
    for (const auto h : mesh.halfedges_around_target(mesh.halfedge(centre))) {
      const Face f = mesh.face(h);
      if (state->seen.has(f.idx())) continue;
      state->seen.add(f.idx());
      old_bound.push_back(state->bound[f]);
      Triangle t;
      int k = 0, moved = 0;
      for (const Vertex v : mesh.vertices_around_face(mesh.halfedge(f))) {
        t[k] = index(v);
        moved += t[k] == i0 || t[k] == i1;
        ++k;
      }
      patch.before.push_back(t);
      const Vector a = patch.points[t[0]] - placement, b = patch.points[t[1]] - placement,
                   c = patch.points[t[2]] - placement;
      volume -= CGAL::determinant(a, b, c) / 6;
      if (moved == 2) {  // one of the two faces on the edge, removed
        for (int c : t) {
          if (c != i0 && c != i1) removed.emplace_back(c, state->bound[f]);
        }
        continue;
      }
      for (int& c : t) {
        // Each point of the new face is within the shift of the same barycentric point of the old.
        if (c == i0 || c == i1) shifted.push_back(state->bound[f] + shift[c == i1]);
        c = (c == i0 || c == i1) ? ip : c;
      }
      kept.push_back(f);
      patch.after.push_back(t);
    }
  }
  if (!state->volume_allows(volume)) return false;
  patch.inner_before = {i0, i1};
  patch.inner_after = {ip};
  Patch::edges_at(patch.before, patch.inner_before, patch.edges_before);
  Patch::edges_at(patch.after, patch.inner_after, patch.edges_after);
  const double gap = graph_gap(patch);
  state->accepted.clear();
  state->accepted_volume = volume;
  auto& by_bound = state->by_bound;  // the old faces of nonzero bound, largest bound first
  by_bound.clear();
  if (gap >= 0) {
    for (std::size_t j = 0; j < patch.before.size(); ++j) {
      if (old_bound[j] > 0) by_bound.push_back(static_cast<int>(j));
    }
    std::sort(by_bound.begin(), by_bound.end(), [&](int a, int b) { return old_bound[a] > old_bound[b]; });
  }
  for (std::size_t i = 0; i < kept.size(); ++i) {
    double bound = shifted[i];
    // A removed face maps onto the new edge from the placement to its third vertex.
    for (const auto& [c, old] : removed) {
      const auto& t = patch.after[i];
      if (t[0] == c || t[1] == c || t[2] == c) bound = std::max(bound, old + std::max(shift[0], shift[1]));
    }
    if (gap >= 0) {
      // Points of the new face are within the gap of old faces whose projections overlap its own:
      // the first of them in `by_bound` has the largest bound.
      double worst = 0;
      for (const int j : by_bound) {
        if (overlap(patch, patch.after[i], patch.before[j])) {
          worst = old_bound[j];
          break;
        }
      }
      bound = std::min(bound, gap + worst);
    }
    if (bound > state->max_distance) return false;
    state->accepted.emplace_back(kept[i], bound);
  }
  return true;
}

// Whether collapsing the edge of `h` to `placement` turns a face it keeps by 90 degrees or more.
bool turns_a_face(const Mesh& mesh, Mesh::Halfedge_index h, const Point& placement) {
  for (const Vertex moved : {mesh.source(h), mesh.target(h)}) {
    for (const auto around : mesh.halfedges_around_target(mesh.halfedge(moved))) {
      const Face f = mesh.face(around);
      if (f == mesh.face(h) || f == mesh.face(mesh.opposite(h))) continue;
      // The face's normal before and after, from one walk around it.
      std::array<Point, 3> p, q;
      int k = 0;
      for (const Vertex v : mesh.vertices_around_face(mesh.halfedge(f))) {
        p[k] = mesh.point(v);
        q[k] = v == moved ? placement : p[k];
        ++k;
      }
      if (CGAL::cross_product(p[1] - p[0], p[2] - p[0]) * CGAL::cross_product(q[1] - q[0], q[2] - q[0]) <= 0) return true;
    }
  }
  return false;
}

// CGAL::Euler::does_satisfy_link_condition on a closed surface: the ends of the edge have no common
// neighbour but the two opposite corners, the edge is not on a tetrahedron and its two triangles are
// not glued back to back. The neighbours of one end are marked instead of walking around each
// neighbour of the other (the same answer, without the walks' cache misses).
bool satisfies_link_condition(const Mesh& mesh, Mesh::Halfedge_index v0_v1, State& state) {
  const auto v1_v0 = mesh.opposite(v0_v1);
  const Vertex v0 = mesh.source(v0_v1), v1 = mesh.target(v0_v1);
  const Vertex vL = mesh.target(mesh.next(v0_v1)), vR = mesh.target(mesh.next(v1_v0));
  state.marked.clear();
  for (const auto h : mesh.halfedges_around_target(mesh.halfedge(v1))) state.marked.add(mesh.source(h).idx());
  for (const auto h : mesh.halfedges_around_target(mesh.halfedge(v0))) {
    const Vertex k = mesh.source(h);
    if (k != v1 && k != vL && k != vR && state.marked.has(k.idx())) return false;
  }
  if (CGAL::is_tetrahedron(v0_v1, mesh)) return false;
  return !(mesh.next(v0_v1) == mesh.opposite(mesh.prev(v1_v0)) && mesh.prev(v0_v1) == mesh.opposite(mesh.next(v1_v0)));
}

// Merges the ends of edges shorter than `length` at their midpoint, shortest first, under the rules
// of the collapses (link condition, bound_collapse, no face normal turned by 90 degrees or more).
// Written here rather than left to edge_collapse, whose geometric test refuses any collapse next to a
// face 10^4 times smaller than its neighbour: around clusters of three or more nearly coincident
// Voronoi vertices it left 1200 of 1415 edges under 0.001 voxel (fandisk 32^3) uncollapsed.
std::size_t merge_close_vertices(Mesh& mesh, State& state, double length) {
  using Item = std::pair<double, Mesh::Edge_index>;
  std::priority_queue<Item, std::vector<Item>, std::greater<Item>> queue;
  auto squared_length = [&](Mesh::Edge_index e) {
    return CGAL::squared_distance(mesh.point(mesh.vertex(e, 0)), mesh.point(mesh.vertex(e, 1)));
  };
  const double limit = length * length;
  for (const auto e : mesh.edges()) {
    const double l = squared_length(e);
    if (l < limit) queue.emplace(l, e);
  }
  std::size_t merges = 0;
  while (!queue.empty()) {
    const auto [l, e] = queue.top();
    queue.pop();
    if (mesh.is_removed(e) || squared_length(e) != l) continue;
    const auto h = mesh.halfedge(e);
    const Vertex gone = mesh.source(h), kept = mesh.target(h);
    if (!satisfies_link_condition(mesh, h, state)) continue;
    const Point middle = CGAL::midpoint(mesh.point(gone), mesh.point(kept));
    if (turns_a_face(mesh, h, middle) || !bound_collapse(mesh, &state, gone, kept, middle)) continue;
    CGAL::Euler::collapse_edge(e, mesh);
    mesh.point(kept) = middle;
    state.commit_collapse(gone, kept, middle);
    ++merges;
    for (const auto around : mesh.halfedges_around_target(mesh.halfedge(kept))) {
      const auto edge = mesh.edge(around);
      const double length_now = squared_length(edge);
      if (length_now < limit) queue.emplace(length_now, edge);
    }
  }
  return merges;
}

using Profile = SMS::Edge_profile<Mesh>;
using EdgeFlags = Mesh::Property_map<Mesh::Edge_index, bool>;

// CGAL's topological test of a collapse (is_collapse_topologically_valid in
// Surface_mesh_simplification/internal/Edge_collapse.h), on a closed surface: the link condition
// (satisfies_link_condition), and not both ends on constrained edges.
bool keeps_topology(const Mesh& mesh, const Profile& profile, const EdgeFlags& constrained, State& state) {
  if (!satisfies_link_condition(mesh, profile.v0_v1(), state)) return false;
  auto on_constrained = [&](Vertex v) {
    for (const auto h : mesh.halfedges_around_target(mesh.halfedge(v))) {
      if (constrained[mesh.edge(h)]) return true;
    }
    return false;
  };
  return !(on_constrained(profile.v0()) && on_constrained(profile.v1()));
}

// CGAL's are_shared_triangles_valid: triangles p0 p1 p2 and p0 p2 p3 neither 10^4 times apart in
// size nor folded onto each other (within one degree).
bool shared_triangles_valid(const Point& p0, const Point& p1, const Point& p2, const Point& p3) {
  const Vector n012 = CGAL::cross_product(p1 - p0, p2 - p0), n023 = CGAL::cross_product(p2 - p0, p3 - p0);
  const double l012 = n012 * n012, l023 = n023 * n023;
  if (!(std::max(l012, l023) < 1e8 * std::min(l012, l023))) return false;
  const double l0123 = n012 * n023;
  const double cos_squared = CGAL::square(std::cos(1.0 * CGAL_PI / 180.0));
  return CGAL::is_positive(l0123) || l0123 * l0123 <= cos_squared * (l012 * l023);
}

// CGAL's geometric test of a collapse to `placement` (is_collapse_geometrically_valid): the new
// triangles around the link, and each with its neighbour outside the link, pass
// shared_triangles_valid.
bool keeps_geometry(const Mesh& mesh, const Profile& profile, const Point& placement) {
  auto connection = [&](Vertex a, Vertex b) {
    for (const auto h : CGAL::halfedges_around_source(a, mesh)) {
      if (mesh.target(h) == b) return h;
    }
    return Mesh::null_halfedge();
  };
  auto third_outside = [&](Mesh::Halfedge_index e) {
    if (e == Mesh::null_halfedge()) return Mesh::null_vertex();
    for (const auto side : {e, mesh.opposite(e)}) {
      const Vertex ra = mesh.target(mesh.next(side)), rb = mesh.source(mesh.prev(side));
      if (ra == rb && ra != profile.v0() && ra != profile.v1()) return ra;
    }
    return Mesh::null_vertex();
  };
  const auto& link = profile.link();
  const std::size_t n = link.size();
  if (n == 0) return true;
  // The connection of one step along the link is the next step's first: each is looked up once.
  const auto first = connection(link[n - 1], link[0]);
  auto e12 = first;
  for (std::size_t i = 0; i < n; ++i) {
    const Vertex k1 = link[(i + n - 1) % n], k2 = link[i], k3 = link[(i + 1) % n];
    const auto next = i + 1 < n ? connection(k2, k3) : first;
    const auto e23 = k3 != k1 ? next : Mesh::null_halfedge();
    if (e12 != Mesh::null_halfedge() && e23 != Mesh::null_halfedge() &&
        !shared_triangles_valid(placement, mesh.point(k1), mesh.point(k2), mesh.point(k3))) {
      return false;
    }
    const Vertex k4 = third_outside(e12);
    if (k4 != Mesh::null_vertex() && !shared_triangles_valid(mesh.point(k1), mesh.point(k4), mesh.point(k2), placement)) {
      return false;
    }
    const Vertex k5 = third_outside(e23);
    if (k5 != Mesh::null_vertex() && !shared_triangles_valid(mesh.point(k2), mesh.point(k5), mesh.point(k3), placement)) {
      return false;
    }
    e12 = next;
  }
  return true;
}

// CGAL's Bounded_normal_change_filter: no face the collapse keeps turned by 90 degrees or more.
bool keeps_normals(const Mesh& mesh, const Profile& profile, const Point& placement) {
  const auto& triangles = profile.triangles();
  if (triangles.size() <= 2) return true;
  // The faces on the edge come first; in the others, v1 is the vertex that moves.
  for (std::size_t i = std::size_t(profile.left_face_exists()) + std::size_t(profile.right_face_exists());
       i < triangles.size(); ++i) {
    const Point &p = mesh.point(triangles[i].v0), &q = mesh.point(triangles[i].v1), &r = mesh.point(triangles[i].v2);
    if (!CGAL::is_positive(CGAL::cross_product(p - q, r - q) * CGAL::cross_product(p - placement, r - placement))) {
      return false;
    }
  }
  return true;
}

// Lindstrom-Turk placement (volume and shape kept, so sharp edges stay sharp) when it lies within
// one edge length of the edge's midpoint; else the midpoint. On the tiny near-degenerate faces of a
// VoroMesh, Lindstrom-Turk finds no placement or one far away (measured on fandisk 32^3: 1200 of
// 1415 edges under 0.001 voxel were left uncollapsed).
Point near_edge_placement(const Profile& profile) {
  const Point middle = CGAL::midpoint(profile.p0(), profile.p1());
  const auto placement = SMS::LindstromTurk_placement<Mesh>()(profile);
  if (placement && CGAL::squared_distance(*placement, middle) <= CGAL::squared_distance(profile.p0(), profile.p1())) {
    return *placement;
  }
  return middle;
}

// Collapses edges no longer than `length`, shortest first, as CGAL's edge_collapse does with
// Edge_length_cost, Edge_length_stop_predicate, near_edge_placement and its own tests (keeps_topology,
// keeps_geometry, keeps_normals), then bound_collapse; `constrained` edges are left. After each
// collapse the edges at the kept vertex, and the taken ones around its neighbours, are queued again,
// as edge_collapse updates them: the result is the same as edge_collapse's (identical on the dev
// meshes). Written out because edge_collapse builds a profile and a placement for every edge around
// those neighbours, short or long, whenever it collapses one; here only short edges are queued, and
// only an edge taken from the queue gets a profile: the clean takes a third less time at 64^3.
std::size_t collapse_short_edges(Mesh& mesh, State& state, double length, const EdgeFlags& constrained) {
  using Item = std::tuple<double, std::uint32_t, std::uint32_t>;  // squared length, edge, its stamp
  std::priority_queue<Item, std::vector<Item>, std::greater<Item>> queue;
  std::vector<std::uint32_t> stamp(mesh.num_edges(), 0);  // an item is current while its stamp is
  std::vector<char> pending(mesh.num_edges(), 0);          // a current item is in the queue
  const double limit = length * length;
  auto push = [&](Mesh::Edge_index e) {
    if (constrained[e]) return;
    const double l = CGAL::squared_distance(mesh.point(mesh.vertex(e, 0)), mesh.point(mesh.vertex(e, 1)));
    pending[e.idx()] = l <= limit;
    ++stamp[e.idx()];
    if (l <= limit) queue.emplace(l, static_cast<std::uint32_t>(e.idx()), stamp[e.idx()]);
  };
  for (const auto e : mesh.edges()) push(e);
  const Kernel traits;
  std::size_t collapses = 0;
  while (!queue.empty()) {
    const auto [l, index, item_stamp] = queue.top();
    queue.pop();
    const Mesh::Edge_index e(index);
    if (item_stamp != stamp[index] || mesh.is_removed(e)) continue;
    pending[index] = 0;  // taken: queued again only by a collapse nearby
    const Profile profile(mesh.halfedge(e), mesh, traits, get(CGAL::vertex_index, mesh), mesh.points(),
                          get(CGAL::halfedge_index, mesh), false);
    if (!keeps_topology(mesh, profile, constrained, state)) continue;
    const Point placement = near_edge_placement(profile);
    if (!keeps_geometry(mesh, profile, placement) || !keeps_normals(mesh, profile, placement) ||
        !bound_collapse(mesh, &state, profile.v0(), profile.v1(), placement)) {
      continue;
    }
    const Vertex kept = CGAL::Euler::collapse_edge(e, mesh, constrained);
    mesh.point(kept) = placement;
    const Vertex gone = kept == profile.v0() ? profile.v1() : profile.v0();
    state.commit_collapse(gone, kept, placement);
    ++collapses;
    // The edges at the kept vertex changed length; the others around its neighbours are queued
    // again if they were taken (a pending one would be queued again where it is).
    for (const auto h : mesh.halfedges_around_target(mesh.halfedge(kept))) {
      push(mesh.edge(h));
      for (const auto around : mesh.halfedges_around_target(mesh.halfedge(mesh.source(h)))) {
        if (!pending[mesh.edge(around).idx()]) push(mesh.edge(around));
      }
    }
  }
  return collapses;
}

// The cosine of the smallest angle of a triangle (1 when two corners coincide).
double smallest_angle_cosine(const Point& a, const Point& b, const Point& c) {
  const double ab = CGAL::squared_distance(a, b), bc = CGAL::squared_distance(b, c), ca = CGAL::squared_distance(c, a);
  // The smallest angle faces the shortest side; its cosine by the law of cosines.
  double opposite = ab, s1 = bc, s2 = ca;
  if (bc < opposite) opposite = bc, s1 = ab, s2 = ca;
  if (ca < opposite) opposite = ca, s1 = ab, s2 = bc;
  if (!(s1 > 0 && s2 > 0)) return 1;
  return std::clamp((s1 + s2 - opposite) / (2 * std::sqrt(s1 * s2)), -1.0, 1.0);
}

// Whether flipping the edge of `h` raises the smallest angle of its two triangles by more than
// `margin` radians with the new pair within max_distance and the volume budget (see the top of the
// file); its new faces' bound and the volume change into `bound` and `volume`.
bool bound_flip(const Mesh& mesh, State& state, Mesh::Halfedge_index h, double margin, double& bound,
                double& volume) {
  const auto o = mesh.opposite(h);
  const Vertex s = mesh.source(h), t = mesh.target(h);
  const Vertex a = mesh.target(mesh.next(h)), b = mesh.target(mesh.next(o));
  if ((*state.frozen)[s.idx()] || (*state.frozen)[t.idx()] || a == b) return false;
  const Point &ps = mesh.point(s), &pt = mesh.point(t), &pa = mesh.point(a), &pb = mesh.point(b);
  // The smallest angle of a pair is that of the largest cosine; an angle that does not grow is
  // told without acos.
  const double old_cosine = std::max(smallest_angle_cosine(ps, pt, pa), smallest_angle_cosine(pt, ps, pb));
  const double new_cosine = std::max(smallest_angle_cosine(pa, ps, pb), smallest_angle_cosine(pb, pt, pa));
  if (!(new_cosine < old_cosine && std::acos(new_cosine) > std::acos(old_cosine) + margin)) return false;
  if (mesh.halfedge(a, b) != Mesh::null_halfedge()) return false;
  // In the workspace of bound_collapse: a Patch of its own would allocate ten arrays a flip.
  Patch& patch = state.patch;
  patch.points.assign({ps, pt, pa, pb});
  patch.before.assign({{0, 1, 2}, {1, 0, 3}});
  patch.after.assign({{2, 0, 3}, {3, 1, 2}});
  patch.inner_before.clear();
  patch.inner_after.clear();
  patch.edges_before.assign({{0, 1}});
  patch.edges_after.assign({{2, 3}});
  const double gap = graph_gap(patch);
  bound = gap + std::max(state.bound[mesh.face(h)], state.bound[mesh.face(o)]);
  volume = CGAL::determinant(pb - ps, pt - ps, pa - ps) / 6;  // the old faces both hold s
  return gap >= 0 && bound <= state.max_distance && state.volume_allows(volume);
}

// Flips edges where the two triangles' smallest angle grows by more than `margin` radians and the
// new pair stays within max_distance (see the top of the file). Returns the number of flips.
std::size_t flip_edges(Mesh& mesh, State& state, double margin) {
  std::deque<Mesh::Edge_index> queue(mesh.edges().begin(), mesh.edges().end());
  auto queued = mesh.add_property_map<Mesh::Edge_index, bool>("e:voro3d_queued", true).first;
  std::size_t flips = 0;
  const std::size_t budget = 10 * mesh.number_of_edges();
  while (!queue.empty() && flips < budget) {
    const auto e = queue.front();
    queue.pop_front();
    queued[e] = false;
    const auto h = mesh.halfedge(e), o = mesh.opposite(h);
    const Vertex s = mesh.source(h), t = mesh.target(h);
    double bound = 0, volume = 0;
    if (!bound_flip(mesh, state, h, margin, bound, volume)) continue;
    state.volume_change += volume;
    CGAL::Euler::flip_edge(h, mesh);
    state.bound[mesh.face(h)] = state.bound[mesh.face(o)] = bound;
    state.log->add(Operation::kFlip, s.idx(), t.idx(), Point(), {{mesh.face(h), bound}, {mesh.face(o), bound}}, volume);
    ++flips;
    for (const auto side : {h, o}) {
      for (const auto k : {mesh.next(side), mesh.prev(side)}) {
        const auto edge = mesh.edge(k);
        if (!queued[edge]) {
          queued[edge] = true;
          queue.push_back(edge);
        }
      }
    }
  }
  mesh.remove_property_map(queued);
  return flips;
}
// Makes the changes of `log` again, in order. A vertex is touched when it is frozen or a change left
// out or made anew holds it: such a change moves no other vertex, and every face it changes (or, left
// out, leaves as it was) holds one of its touched vertices. So a change none of whose vertices
// touches a touched one (a collapse: its ends and their neighbours; a flip: its four corners) sees
// the very faces, positions and bounds it saw the first time: it is made with the bounds it had.
// The others are checked again as the first run checks them (frozen vertices, the link condition,
// turned faces, distance and volume bounds) and made with fresh bounds where they pass; either way
// their vertices count as touched from then on. (Touching the neighbours too, as this did before,
// spread the checks over half the collapses of abc_00000009 at 64^3 for 2-11 crossing pairs.)
void replay(Mesh& mesh, State& state, const CleanLog& log, std::size_t& collapses, std::size_t& flips) {
  std::vector<char> touched(state.frozen->begin(), state.frozen->end());
  std::vector<std::uint32_t> alias(touched.size());  // the first run's vertex index -> this run's
  for (std::size_t i = 0; i < alias.size(); ++i) alias[i] = static_cast<std::uint32_t>(i);
  auto star_untouched = [&](Vertex v) {
    if (touched[v.idx()]) return false;
    for (const auto h : mesh.halfedges_around_target(mesh.halfedge(v))) {
      if (touched[mesh.source(h).idx()]) return false;
    }
    return true;
  };
  // An untouched change takes the bounds and volume it was logged with.
  auto reuse_logged = [&](const Operation& operation) {
    for (std::uint32_t i = operation.first; i < operation.last; ++i) {
      state.bound[Face(log.bounds[i].first)] = log.bounds[i].second;
    }
    state.volume_change += operation.volume;
  };
  for (const auto& operation : log.operations) {
    if (operation.kind == Operation::kPass) {
      for (const auto face : mesh.faces()) state.bound[face] = 0;
      state.volume_change = 0;
      continue;
    }
    const Vertex a(alias[operation.a]), b(alias[operation.b]);
    if (mesh.is_removed(a) || mesh.is_removed(b)) continue;
    const auto h = mesh.halfedge(a, b);
    if (h == Mesh::null_halfedge()) continue;
    if (operation.kind == Operation::kCollapse) {
      const bool same = star_untouched(a) && star_untouched(b);
      if (same ? !state.volume_allows(operation.volume)
               : !satisfies_link_condition(mesh, mesh.halfedge(mesh.edge(h)), state) ||
                     turns_a_face(mesh, h, operation.placement) ||
                     !bound_collapse(mesh, &state, a, b, operation.placement)) {
        touched[a.idx()] = touched[b.idx()] = 1;
        continue;
      }
      const Vertex kept = CGAL::Euler::collapse_edge(mesh.edge(h), mesh);
      mesh.point(kept) = operation.placement;
      alias[operation.b] = kept.idx();
      state.merges.parent[(kept == a ? b : a).idx()] = kept.idx();
      ++collapses;
      if (same) {
        reuse_logged(operation);
      } else {
        state.apply_accepted();
        touched[kept.idx()] = 1;
      }
      continue;
    }
    const auto o = mesh.opposite(h);
    const Vertex c = mesh.target(mesh.next(h)), d = mesh.target(mesh.next(o));
    const bool same = !touched[a.idx()] && !touched[b.idx()] && !touched[c.idx()] && !touched[d.idx()];
    double bound = 0, volume = 0;
    if (same ? !state.volume_allows(operation.volume) || mesh.halfedge(c, d) != Mesh::null_halfedge()
             : !bound_flip(mesh, state, h, log.flip_margin, bound, volume)) {
      for (const Vertex v : {a, b, c, d}) touched[v.idx()] = 1;
      continue;
    }
    CGAL::Euler::flip_edge(h, mesh);
    ++flips;
    if (same) {
      reuse_logged(operation);
    } else {
      state.bound[mesh.face(h)] = state.bound[mesh.face(o)] = bound;
      state.volume_change += volume;
      for (const Vertex v : {a, b, c, d}) touched[v.idx()] = 1;
    }
  }
}

Mesh mesh_of(const voro3d::Points& vertices, const voro3d::Indices& triangles) {
  auto v = vertices.unchecked<2>();
  auto t = triangles.unchecked<2>();
  if (triangles.shape(0) < 4) {
    throw py::value_error("triangles must hold at least 4 rows for a closed surface, got " +
                          std::to_string(triangles.shape(0)));
  }
  Mesh mesh;
  // Room for every element first: the property arrays then grow without copies (a closed surface
  // of t triangles has 3t/2 edges).
  mesh.reserve(static_cast<Mesh::size_type>(v.shape(0)), static_cast<Mesh::size_type>(3 * t.shape(0) / 2),
               static_cast<Mesh::size_type>(t.shape(0)));
  for (py::ssize_t i = 0; i < v.shape(0); ++i) mesh.add_vertex(Point(v(i, 0), v(i, 1), v(i, 2)));
  for (py::ssize_t i = 0; i < t.shape(0); ++i) {
    if (mesh.add_face(Vertex(t(i, 0)), Vertex(t(i, 1)), Vertex(t(i, 2))) == Mesh::null_face()) {
      throw py::value_error("triangles row " + std::to_string(i) +
                            " makes the surface non-manifold, degenerate or inconsistently oriented");
    }
  }
  for (const auto h : mesh.halfedges()) {
    if (mesh.is_border(h)) {
      throw py::value_error("triangles do not form a closed surface: edge (" + std::to_string(mesh.source(h).idx()) +
                            ", " + std::to_string(mesh.target(h).idx()) + ") has one triangle");
    }
  }
  return mesh;
}

// (vertices, triangles, label) of the cleaned mesh, as clean_surface returns them.
py::tuple arrays_of(const Mesh& mesh, State& state, std::size_t n) {
  std::vector<double> points;
  std::vector<std::int64_t> triangles, label(n, -1);
  {
    py::gil_scoped_release release;
    std::vector<std::int64_t> index(n, -1);
    for (const auto vertex : mesh.vertices()) {
      if (mesh.is_isolated(vertex)) continue;
      index[vertex.idx()] = static_cast<std::int64_t>(points.size() / 3);
      const Point& p = mesh.point(vertex);
      points.insert(points.end(), {p.x(), p.y(), p.z()});
    }
    for (const auto face : mesh.faces()) {
      for (const auto vertex : mesh.vertices_around_face(mesh.halfedge(face))) triangles.push_back(index[vertex.idx()]);
    }
    for (std::size_t i = 0; i < n; ++i) label[i] = index[state.merges.find(static_cast<std::int64_t>(i))];
  }
  py::array_t<double> result_points({static_cast<py::ssize_t>(points.size() / 3), static_cast<py::ssize_t>(3)});
  std::copy(points.begin(), points.end(), result_points.mutable_data());
  py::array_t<std::int64_t> result_label(static_cast<py::ssize_t>(n));
  std::copy(label.begin(), label.end(), result_label.mutable_data());
  return py::make_tuple(result_points, voro3d::to_array(triangles, 3), result_label);
}

State state_of(Mesh& mesh, const std::vector<char>& frozen, double max_distance, double max_volume_change) {
  State state{&frozen, mesh.add_property_map<Face, double>("f:voro3d_bound", 0.0).first, max_distance,
              max_volume_change};
  state.merges.parent.resize(frozen.size());
  state.marked.resize(frozen.size());
  state.local.resize(frozen.size());
  state.local_index.assign(frozen.size(), 0);
  state.seen.resize(mesh.num_faces());
  for (std::size_t i = 0; i < frozen.size(); ++i) state.merges.parent[i] = static_cast<std::int64_t>(i);
  return state;
}

std::vector<char> frozen_of(const py::object& frozen_in, py::ssize_t n) {
  auto f = voro3d::check_mask(frozen_in, "frozen", n).unchecked<1>();
  std::vector<char> frozen(static_cast<std::size_t>(n));
  for (py::ssize_t i = 0; i < n; ++i) frozen[i] = f(i);
  return frozen;
}
}  // namespace

// Cleans a closed manifold triangle surface; see the docstring at the binding below.
py::tuple clean_surface(const py::object& vertices_in, const py::object& triangles_in, const py::object& frozen_in,
                        double merge_length, double collapse_length, double max_distance, double max_volume_change,
                        double flip_margin, int passes) {
  const voro3d::Points vertices = voro3d::check_points(vertices_in, "vertices", 3);
  const py::ssize_t n = vertices.shape(0);
  const voro3d::Indices triangles = voro3d::check_indices(triangles_in, "triangles", 3, "t", n, "vertices");
  const std::vector<char> frozen = frozen_of(frozen_in, n);
  for (const auto& [name, value] : {std::pair<const char*, double>{"merge_length", merge_length},
                                    {"collapse_length", collapse_length}, {"max_distance", max_distance},
                                    {"max_volume_change", max_volume_change}, {"flip_margin", flip_margin}}) {
    if (!(std::isfinite(value) && value >= 0)) {
      throw py::value_error(std::string(name) + " must be finite and >= 0, got " + std::to_string(value));
    }
  }
  if (passes < 1) throw py::value_error("passes must be >= 1, got " + std::to_string(passes));
  Mesh mesh = mesh_of(vertices, triangles);

  auto log = std::make_shared<CleanLog>();
  log->n_vertices = static_cast<std::size_t>(n);
  log->n_triangles = static_cast<std::size_t>(triangles.shape(0));
  log->input = std::make_shared<const Mesh>(mesh);
  log->input_points.assign(vertices.data(), vertices.data() + vertices.size());
  log->input_triangles.assign(triangles.data(), triangles.data() + triangles.size());
  // The bounds restart at zero each pass, against that pass's input: the Hausdorff distance obeys
  // the triangle inequality, so the passes' budgets add up to max_distance. Two passes of half
  // the budget clean more than one (bunny 64^3: 4.4% of the triangles off the true normal
  // instead of 6.8%), as each pass's bounds grow from the largest of the faces they replace.
  log->max_distance = max_distance / passes;
  log->max_volume_change = max_volume_change / passes;
  log->flip_margin = flip_margin;
  State state = state_of(mesh, frozen, log->max_distance, log->max_volume_change);
  state.log = log.get();
  std::size_t merges = 0, collapses = 0, flips = 0;
  {
    py::gil_scoped_release release;
    auto zero_length = mesh.add_property_map<Mesh::Edge_index, bool>("e:voro3d_zero_length", false).first;
    for (int pass = 0; pass < passes; ++pass) {
      for (const auto face : mesh.faces()) state.bound[face] = 0;
      state.volume_change = 0;
      log->add(Operation::kPass, 0, 0, Point(), {}, 0);
      merges += merge_close_vertices(mesh, state, merge_length);
      // Edges of length zero that merge_close_vertices refused (a frozen end, the link condition, ...)
      // are constrained: never collapsed, and kept when a neighbouring collapse merges two edges.
      for (const auto edge : mesh.edges()) {
        zero_length[edge] = mesh.point(mesh.vertex(edge, 0)) == mesh.point(mesh.vertex(edge, 1));
      }
      collapses += collapse_short_edges(mesh, state, collapse_length, zero_length);
      flips += flip_edges(mesh, state, flip_margin);
    }
  }
  const py::tuple arrays = arrays_of(mesh, state, static_cast<std::size_t>(n));
  return py::make_tuple(arrays[0], arrays[1], arrays[2], merges + collapses, flips, py::cast(log));
}

// Makes the changes of a clean_surface call again with more frozen vertices; see the binding below.
py::tuple replay_clean(const py::object& vertices_in, const py::object& triangles_in, const py::object& frozen_in,
                       const std::shared_ptr<CleanLog>& log) {
  const voro3d::Points vertices = voro3d::check_points(vertices_in, "vertices", 3);
  const py::ssize_t n = vertices.shape(0);
  const voro3d::Indices triangles = voro3d::check_indices(triangles_in, "triangles", 3, "t", n, "vertices");
  const std::vector<char> frozen = frozen_of(frozen_in, n);
  if (!log) throw py::type_error("log must be the log clean_surface returned, got None");
  if (log->n_vertices != static_cast<std::size_t>(n) || log->n_triangles != static_cast<std::size_t>(triangles.shape(0))) {
    throw py::value_error("log is of a surface of " + std::to_string(log->n_vertices) + " vertices and " +
                          std::to_string(log->n_triangles) + " triangles, got " + std::to_string(n) + " and " +
                          std::to_string(triangles.shape(0)));
  }
  const bool same_input =
      log->input &&
      std::memcmp(log->input_points.data(), vertices.data(), log->input_points.size() * sizeof(double)) == 0 &&
      std::memcmp(log->input_triangles.data(), triangles.data(),
                  log->input_triangles.size() * sizeof(std::int64_t)) == 0;
  Mesh mesh = same_input ? Mesh(*log->input) : mesh_of(vertices, triangles);
  State state = state_of(mesh, frozen, log->max_distance, log->max_volume_change);
  std::size_t collapses = 0, flips = 0;
  {
    py::gil_scoped_release release;
    replay(mesh, state, *log, collapses, flips);
  }
  const py::tuple arrays = arrays_of(mesh, state, static_cast<std::size_t>(n));
  return py::make_tuple(arrays[0], arrays[1], arrays[2], collapses, flips);
}

void register_clean(py::module_& module) {
  py::class_<CleanLog, std::shared_ptr<CleanLog>>(module, "CleanLog",
                                                 "The changes of a clean_surface call, for replay_clean.")
      .def("__len__", [](const CleanLog& log) { return log.operations.size(); });
  module.def("clean_surface", &clean_surface, py::arg("vertices"), py::arg("triangles"), py::arg("frozen"),
             py::arg("merge_length"), py::arg("collapse_length"), py::arg("max_distance"),
             py::arg("max_volume_change"), py::arg("flip_margin"), py::arg("passes"),
             "(vertices (m, 3) float64, triangles (s, 3) int64, label (n,) int64, collapses, flips, log) of a "
             "closed, manifold, consistently oriented surface of finite (n, 3) vertices and (t, 3) triangles, "
             "cleaned in `passes` passes of: the ends of edges shorter than merge_length merged at their midpoint; "
             "edges shorter than collapse_length collapsed (shortest first, Lindstrom-Turk placement near the "
             "edge, else its midpoint, no normal flipped); edges flipped where the smallest angle of their two "
             "triangles grows by more than flip_margin radians. No point of the result is farther than "
             "max_distance from the input, nor any point of the input from the result (a bound carried per "
             "face), and the enclosed volume changes by at most max_volume_change. Vertices where the (n,) bool "
             "frozen is set are never moved, merged or flipped around. label[i] is the output vertex input "
             "vertex i became, -1 if it was in no triangle. log lists the changes, for replay_clean. "
             "Self-intersections are not tested here.");
  module.def("replay_clean", &replay_clean, py::arg("vertices"), py::arg("triangles"), py::arg("frozen"),
             py::arg("log"),
             "(vertices, triangles, label, collapses, flips) as clean_surface returns them: the changes of `log` "
             "(a clean_surface call on the same vertices and triangles) made again in order, except those whose "
             "patch holds a frozen vertex (the (n,) bool frozen) or a vertex of a change left out. The changes "
             "made see what they saw the first time, so every bound of clean_surface holds.");
}
