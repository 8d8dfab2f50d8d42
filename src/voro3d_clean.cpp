// Cleaning of a closed, oriented, manifold triangle surface (a VoroMesh), in passes of: nearly
// coincident vertices merged, short edges collapsed as CGAL's Surface_mesh_simplification does, then
// edges flipped where that raises the smallest angle. Frozen vertices are never moved, merged or
// flipped around. Self-intersections are tested by the caller (voro3d/cleaning.py), which freezes
// the input vertices behind crossing triangles and has the changes, logged by clean_surface, made
// again without them by replay_clean.
//
// The distance bounds are in src/clean/bounds.h, the collapse rules in src/clean/rules.h, the shared
// state and the log in src/clean/state.h; this file holds the passes and the bindings.

#include "clean/bounds.h"
#include "clean/rules.h"

#include <CGAL/Surface_mesh_simplification/Policies/Edge_collapse/Count_ratio_stop_predicate.h>
#include <CGAL/Surface_mesh_simplification/Policies/Edge_collapse/Edge_length_cost.h>
#include <CGAL/Surface_mesh_simplification/edge_collapse.h>

namespace {
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

namespace {
// Our profile of the edge of `h` (CGAL's edge_collapse builds its own, of another property-map type).
Profile profile_of(Mesh& mesh, Mesh::Halfedge_index h) {
  static const Kernel traits;
  return Profile(h, mesh, traits, get(CGAL::vertex_index, mesh), mesh.points(), get(CGAL::halfedge_index, mesh),
                 false);
}

// near_edge_placement as an edge_collapse placement policy.
struct NearEdgePlacement {
  Mesh* mesh;
  template <typename CgalProfile>
  boost::optional<Point> operator()(const CgalProfile& profile) const {
    return near_edge_placement(profile_of(*mesh, profile.v0_v1()));
  }
};

// At each edge edge_collapse takes up, our decision (keeps_topology and keeps_geometry at the same
// placement), then whether edge_collapse collapsed it.
struct DecisionRecorder : SMS::internal::Dummy_visitor {
  Mesh* mesh;
  State* state;
  const EdgeFlags* unconstrained;
  std::vector<std::array<char, 2>>* decisions;
  template <typename CgalProfile, typename Cost, typename Size>
  void OnSelected(const CgalProfile& cgal_profile, const Cost&, Size, Size) const {
    const Profile profile = profile_of(*mesh, cgal_profile.v0_v1());
    const bool ours = keeps_topology(*mesh, profile, *unconstrained, *state) &&
                      keeps_geometry(*mesh, profile, near_edge_placement(profile));
    decisions->push_back({static_cast<char>(ours), 0});
  }
  template <typename CgalProfile, typename Placement>
  void OnCollapsing(const CgalProfile&, const Placement&) const { decisions->back()[1] = 1; }
  // The edge selected last is not decided on: the run stops there.
  template <typename CgalProfile>
  void OnStopConditionReached(const CgalProfile&) const { decisions->pop_back(); }
};
}  // namespace

// For the tests: our collapse rules against CGAL's own edge_collapse; see the binding below.
py::array_t<bool> collapse_decisions(const py::object& vertices_in, const py::object& triangles_in, double ratio) {
  const voro3d::Points vertices = voro3d::check_points(vertices_in, "vertices", 3);
  const voro3d::Indices triangles =
      voro3d::check_indices(triangles_in, "triangles", 3, "t", vertices.shape(0), "vertices");
  if (!(ratio > 0 && ratio < 1)) throw py::value_error("ratio must be in (0, 1), got " + std::to_string(ratio));
  Mesh mesh = mesh_of(vertices, triangles);
  State state = state_of(mesh, std::vector<char>(static_cast<std::size_t>(vertices.shape(0)), 0),
                         std::numeric_limits<double>::infinity(), std::numeric_limits<double>::infinity());
  auto unconstrained = mesh.add_property_map<Mesh::Edge_index, bool>("e:voro3d_none", false).first;
  std::vector<std::array<char, 2>> decisions;
  {
    py::gil_scoped_release release;
    DecisionRecorder recorder;
    recorder.mesh = &mesh;
    recorder.state = &state;
    recorder.unconstrained = &unconstrained;
    recorder.decisions = &decisions;
    SMS::edge_collapse(mesh, SMS::Count_ratio_stop_predicate<Mesh>(ratio),
                       CGAL::parameters::get_cost(SMS::Edge_length_cost<Mesh>())
                           .get_placement(NearEdgePlacement{&mesh})
                           .visitor(recorder));
  }
  py::array_t<bool> out({static_cast<py::ssize_t>(decisions.size()), static_cast<py::ssize_t>(2)});
  auto o = out.mutable_unchecked<2>();
  for (std::size_t i = 0; i < decisions.size(); ++i) {
    o(i, 0) = decisions[i][0];
    o(i, 1) = decisions[i][1];
  }
  return out;
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
  module.def("collapse_decisions", &collapse_decisions, py::arg("vertices"), py::arg("triangles"), py::arg("ratio"),
             "(k, 2) bool: CGAL's edge_collapse run on a closed manifold surface (shortest edges first, the clean's "
             "placement, until `ratio` of the edges are left); for each of the k edges it takes up, whether the "
             "clean's rules (the link condition and CGAL's topological and geometric tests, as rewritten in "
             "src/clean/rules.h) would collapse it, and whether edge_collapse did.");
}
