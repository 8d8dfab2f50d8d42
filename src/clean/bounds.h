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
#pragma once

#include "state.h"

namespace {
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
}  // namespace
