// What the clean's passes share: the patch a change is tested on, index sets, merges, the log of
// changes, the state of a run.
#pragma once

#include "types.h"

namespace {
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
}  // namespace
