// CGAL's 3D alpha wrapping of a point set, the closed baseline of bench_pointcloud (--alpha-wrap).
// Usage: alpha_wrap in.xyz out.off alpha offset   (points: "x y z" per line; alpha and offset in
// the points' units). Built by bench_pointcloud.alpha_wrap_binary with the system's CGAL.
#include <CGAL/Exact_predicates_inexact_constructions_kernel.h>
#include <CGAL/Surface_mesh.h>
#include <CGAL/alpha_wrap_3.h>

#include <cstdlib>
#include <fstream>
#include <iostream>
#include <vector>

using Kernel = CGAL::Exact_predicates_inexact_constructions_kernel;
using Point = Kernel::Point_3;

int main(int argc, char** argv) {
  if (argc != 5) {
    std::cerr << "usage: alpha_wrap in.xyz out.off alpha offset\n";
    return 2;
  }
  std::ifstream in(argv[1]);
  std::vector<Point> points;
  double x, y, z;
  while (in >> x >> y >> z) points.emplace_back(x, y, z);
  if (points.empty()) {
    std::cerr << "no points read from " << argv[1] << "\n";
    return 2;
  }
  CGAL::Surface_mesh<Point> wrap;
  CGAL::alpha_wrap_3(points, std::atof(argv[3]), std::atof(argv[4]), wrap);
  std::ofstream out(argv[2]);
  out.precision(17);
  out << wrap;
  return out ? 0 : 1;
}
