// 2D regular (weighted Delaunay) triangulation with exact predicates, for geoface's power
// diagrams.  CGAL's Regular_triangulation_2 over the Epick kernel (filtered exact predicates):
// every orientation and power test is decided exactly, so sites far closer together than
// floating point can separate by arithmetic still get their cells.  Plain C ABI, loaded with
// ctypes by geoface/param/native.py (no Python headers needed to build it).
#include <CGAL/Exact_predicates_inexact_constructions_kernel.h>
#include <CGAL/Regular_triangulation_2.h>
#include <CGAL/Triangulation_face_base_with_info_2.h>
#include <CGAL/Triangulation_vertex_base_with_info_2.h>

#include <cstdint>
#include <exception>
#include <utility>
#include <vector>

namespace {
typedef CGAL::Exact_predicates_inexact_constructions_kernel K;
typedef CGAL::Regular_triangulation_vertex_base_2<K> Vb0;
typedef CGAL::Triangulation_vertex_base_with_info_2<int64_t, K, Vb0> Vb;
typedef CGAL::Regular_triangulation_face_base_2<K> Fb0;
typedef CGAL::Triangulation_face_base_with_info_2<int64_t, K, Fb0> Fb;
typedef CGAL::Triangulation_data_structure_2<Vb, Fb> Tds;
typedef CGAL::Regular_triangulation_2<K, Tds> RT;
typedef K::Weighted_point_2 WP;
typedef K::Point_2 P2;
}  // namespace

extern "C" {

int geoface_rt2_abi(void) { return 1; }

// Regular triangulation of n weighted points (xy: n x 2, w: n; power |x - p|^2 - w).
// Writes up to `cap` finite triangles, counter-clockwise, into T (cap x 3 point indices) and
// N (cap x 3: the triangle across the edge opposite T[t][k], -1 across the convex hull).
// Returns the number of triangles; -m when m > cap (nothing written); -1 on failure
// (fewer than three affinely independent points, or an exception).
int64_t geoface_rt2(int64_t n, const double* xy, const double* w, int64_t cap, int64_t* T, int64_t* N) {
  try {
    std::vector<std::pair<WP, int64_t>> pts;
    pts.reserve(static_cast<size_t>(n));
    for (int64_t i = 0; i < n; ++i) pts.emplace_back(WP(P2(xy[2 * i], xy[2 * i + 1]), w[i]), i);
    RT rt;
    rt.insert(pts.begin(), pts.end());  // spatially sorted insertion
    if (rt.dimension() < 2) return -1;
    int64_t m = 0;
    for (auto f = rt.finite_faces_begin(); f != rt.finite_faces_end(); ++f) f->info() = m++;
    if (m > cap) return -m;
    for (auto f = rt.finite_faces_begin(); f != rt.finite_faces_end(); ++f) {
      const int64_t t = f->info();
      for (int k = 0; k < 3; ++k) {
        T[3 * t + k] = f->vertex(k)->info();
        auto g = f->neighbor(k);
        N[3 * t + k] = rt.is_infinite(g) ? -1 : g->info();
      }
    }
    return m;
  } catch (const std::exception&) {
    return -1;
  } catch (...) {
    return -1;
  }
}
}
