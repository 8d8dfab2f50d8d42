// The rules a collapse obeys, as CGAL's Surface_mesh_simplification states them (the link condition,
// its topological and geometric validity tests, the bounded normal change) and its placement.
// tests/test_clean.py compares these decisions with CGAL's own edge_collapse (collapse_decisions).
#pragma once

#include "state.h"

namespace {
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
}  // namespace
