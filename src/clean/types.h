// The mesh types of the clean (voro3d_clean.cpp and src/clean/*.h: one translation unit).
#pragma once

#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>

#include "../voro3d_checks.h"

#include <CGAL/Exact_predicates_inexact_constructions_kernel.h>
#include <CGAL/Surface_mesh.h>
#include <CGAL/Surface_mesh_simplification/Policies/Edge_collapse/Edge_profile.h>
#include <CGAL/Surface_mesh_simplification/Policies/Edge_collapse/LindstromTurk_placement.h>
#include <CGAL/boost/graph/helpers.h>
#include <CGAL/boost/graph/Euler_operations.h>

#include <algorithm>
#include <limits>
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
using Profile = SMS::Edge_profile<Mesh>;
using EdgeFlags = Mesh::Property_map<Mesh::Edge_index, bool>;
}  // namespace
