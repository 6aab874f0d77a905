// 2D regular (weighted Delaunay) triangulation with exact predicates, for geoface's power
// diagrams.  CGAL's Regular_triangulation_2 over the Epick kernel (filtered exact predicates):
// every orientation and power test is decided exactly, so sites far closer together than
// floating point can separate by arithmetic still get their cells.  Plain C ABI, loaded with
// ctypes by geoface/param/native.py (no Python headers needed to build it).
#include <CGAL/Exact_predicates_inexact_constructions_kernel.h>
#include <CGAL/Regular_triangulation_2.h>
#include <CGAL/Spatial_sort_traits_adapter_2.h>
#include <CGAL/spatial_sort.h>
#include <CGAL/Triangulation_face_base_with_info_2.h>
#include <CGAL/Triangulation_vertex_base_with_info_2.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <exception>
#include <limits>
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
namespace {
// Rotates triangle t (and its neighbours with it) to start at its smallest vertex index: the
// same triangles then give the same power centres to the last bit however they were built.
inline void canonical(int64_t t, int64_t* T, int64_t* N) {
  int64_t* a = T + 3 * t;
  int64_t* b = N + 3 * t;
  const int r = a[1] < a[0] ? (a[2] < a[1] ? 2 : 1) : (a[2] < a[0] ? 2 : 0);
  if (r == 0) return;
  const int64_t ta[3] = {a[r], a[(r + 1) % 3], a[(r + 2) % 3]}, tb[3] = {b[r], b[(r + 1) % 3], b[(r + 2) % 3]};
  for (int k = 0; k < 3; ++k) a[k] = ta[k], b[k] = tb[k];
}

// Writes rt's finite triangles (see geoface_rt2); returns their number, or -m when m > cap.
int64_t write_faces(RT& rt, int64_t cap, int64_t* T, int64_t* N) {
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
    canonical(t, T, N);
  }
  return m;
}
}  // namespace

int64_t geoface_rt2(int64_t n, const double* xy, const double* w, int64_t cap, int64_t* T, int64_t* N) {
  try {
    std::vector<std::pair<WP, int64_t>> pts;
    pts.reserve(static_cast<size_t>(n));
    for (int64_t i = 0; i < n; ++i) pts.emplace_back(WP(P2(xy[2 * i], xy[2 * i + 1]), w[i]), i);
    RT rt;
    rt.insert(pts.begin(), pts.end());  // spatially sorted insertion
    if (rt.dimension() < 2) return -1;
    return write_faces(rt, cap, T, N);
  } catch (const std::exception&) {
    return -1;
  } catch (...) {
    return -1;
  }
}

// A spatial (Hilbert, median policy) order of the first n points of xy (n x 2), written to
// order (n): the order in which CGAL's range insertion would insert them.  Returns 0, or -1
// on an exception.
int64_t geoface_spatial_order(int64_t n, const double* xy, int64_t* order) {
  try {
    std::vector<std::pair<P2, int64_t>> q;
    q.reserve(static_cast<size_t>(n));
    for (int64_t i = 0; i < n; ++i) q.emplace_back(P2(xy[2 * i], xy[2 * i + 1]), i);
    typedef CGAL::First_of_pair_property_map<std::pair<P2, int64_t>> Pmap;
    CGAL::spatial_sort(q.begin(), q.end(), CGAL::Spatial_sort_traits_adapter_2<K, Pmap>());
    for (int64_t i = 0; i < n; ++i) order[i] = q[static_cast<size_t>(i)].second;
    return 0;
  } catch (...) {
    return -1;
  }
}

// geoface_rt2 with the insertion order given (order: a permutation of 0..n-1, e.g. the guard
// sites first and then geoface_spatial_order of the others), each point located from the last
// one's face.  The sort is the part of a range insertion that does not depend on the weights:
// a Newton solve over fixed sites computes it once.  Same triangulation as geoface_rt2.
int64_t geoface_rt2_ordered(int64_t n, const double* xy, const double* w, const int64_t* order, int64_t cap,
                            int64_t* T, int64_t* N) {
  try {
    RT rt;
    RT::Face_handle hint;
    for (int64_t j = 0; j < n; ++j) {
      const int64_t i = order[j];
      if (i < 0 || i >= n) return -1;
      RT::Vertex_handle v = rt.insert(WP(P2(xy[2 * i], xy[2 * i + 1]), w[i]), hint);
      if (v != RT::Vertex_handle()) {
        v->info() = i;
        hint = v->face();
      }
    }
    if (rt.dimension() < 2) return -1;
    return write_faces(rt, cap, T, N);
  } catch (const std::exception&) {
    return -1;
  } catch (...) {
    return -1;
  }
}

// Lawson flips from a regular triangulation of the same points under other weights to the one
// of the weights w, in place.  T, N (m x 3) as geoface_rt2 writes them, every point a vertex.
// Each interior edge whose opposite vertex lies strictly inside the oriented power circle of
// its triangle (CGAL's exact predicate) is flipped when its quad is strictly convex; each flip
// lowers the lifted surface, so the flips end, and the four outer edges of a flipped quad are
// tested again.  Returns the number of flips; -1 when an edge stays non-regular with a quad that
// is not convex (a point must disappear: the caller triangulates anew) or after max_flips.
int64_t geoface_rt2_flip(int64_t n, const double* xy, const double* w, int64_t m, int64_t* T, int64_t* N,
                         int64_t max_flips) {
  try {
    // CGAL's points are made only where a test needs them (most are decided by the filter)
    auto pt = [&](int64_t i) { return P2(xy[2 * i], xy[2 * i + 1]); };
    auto wp = [&](int64_t i) { return WP(pt(i), w[i]); };
    const auto power_side = K().power_side_of_oriented_power_circle_2_object();
    const auto orient = K().orientation_2_object();
    // d strictly inside the oriented power circle of the counter-clockwise (c, a, b): the sign
    // of the lifted in-circle determinant in double precision when its error bound (Shewchuk's
    // for the in-circle test, with room for the weights) decides it, CGAL's exact test otherwise
    auto violated = [&](int64_t c, int64_t a, int64_t b, int64_t d) -> bool {
      const double dx = xy[2 * d], dy = xy[2 * d + 1], dw = w[d];
      const double ax = xy[2 * c] - dx, ay = xy[2 * c + 1] - dy;
      const double bx = xy[2 * a] - dx, by = xy[2 * a + 1] - dy;
      const double cx = xy[2 * b] - dx, cy = xy[2 * b + 1] - dy;
      const double al = ax * ax + ay * ay, bl = bx * bx + by * by, cl = cx * cx + cy * cy;
      const double aw = w[c] - dw, bw = w[a] - dw, cw = w[b] - dw;
      const double az = al - aw, bz = bl - bw, cz = cl - cw;
      const double bxcy = bx * cy, cxby = cx * by, cxay = cx * ay, axcy = ax * cy, axby = ax * by, bxay = bx * ay;
      const double det = az * (bxcy - cxby) + bz * (cxay - axcy) + cz * (axby - bxay);
      const double perm = (al + std::fabs(aw)) * (std::fabs(bxcy) + std::fabs(cxby)) +
                          (bl + std::fabs(bw)) * (std::fabs(cxay) + std::fabs(axcy)) +
                          (cl + std::fabs(cw)) * (std::fabs(axby) + std::fabs(bxay));
      const double bound = 1e-14 * perm;
      if (det > bound) return true;
      if (det < -bound) return false;
      return power_side(wp(c), wp(a), wp(b), wp(d)) == CGAL::ON_POSITIVE_SIDE;
    };
    auto opposite = [&](int64_t s, int64_t t) -> int {
      for (int j = 0; j < 3; ++j)
        if (N[3 * s + j] == t) return j;
      return -1;
    };
    std::vector<int64_t> stack, stuck;
    stack.reserve(static_cast<size_t>(3 * m));
    for (int64_t e = 3 * m - 1; e >= 0; --e)
      if (N[e] > e / 3) stack.push_back(e);
    int64_t flips = 0;
    while (!stack.empty()) {
      const int64_t e = stack.back();
      stack.pop_back();
      const int64_t t = e / 3, s = N[e];
      const int k = static_cast<int>(e % 3);
      if (s < 0) continue;
      const int j = opposite(s, t);
      if (j < 0) return -1;  // not a valid triangulation
      const int64_t c = T[3 * t + k], a = T[3 * t + (k + 1) % 3], b = T[3 * t + (k + 2) % 3], d = T[3 * s + j];
      if (c < 0 || c >= n || a < 0 || a >= n || b < 0 || b >= n || d < 0 || d >= n) return -1;
      if (!violated(c, a, b, d)) continue;
      if (orient(pt(c), pt(a), pt(d)) != CGAL::LEFT_TURN || orient(pt(c), pt(d), pt(b)) != CGAL::LEFT_TURN) {
        stuck.push_back(e);
        continue;
      }
      if (++flips > max_flips) return -1;
      const int64_t nt_b = N[3 * t + (k + 2) % 3], nt_a = N[3 * t + (k + 1) % 3];
      const int64_t ns_b = N[3 * s + (j + 1) % 3], ns_a = N[3 * s + (j + 2) % 3];
      // t becomes (c, a, d), s becomes (c, d, b)
      T[3 * t] = c, T[3 * t + 1] = a, T[3 * t + 2] = d;
      N[3 * t] = ns_b, N[3 * t + 1] = s, N[3 * t + 2] = nt_b;
      T[3 * s] = c, T[3 * s + 1] = d, T[3 * s + 2] = b;
      N[3 * s] = ns_a, N[3 * s + 1] = nt_a, N[3 * s + 2] = t;
      if (ns_b >= 0) {
        const int jj = opposite(ns_b, s);
        if (jj < 0) return -1;
        N[3 * ns_b + jj] = t;
      }
      if (nt_a >= 0) {
        const int jj = opposite(nt_a, t);
        if (jj < 0) return -1;
        N[3 * nt_a + jj] = s;
      }
      stack.push_back(3 * t);
      stack.push_back(3 * t + 2);
      stack.push_back(3 * s);
      stack.push_back(3 * s + 1);
    }
    // an edge set aside is still there unless a flip around it tested it again
    for (const int64_t e : stuck) {
      const int64_t t = e / 3, s = N[e];
      if (s < 0) continue;
      const int j = opposite(s, t);
      if (j < 0) return -1;
      const int k = static_cast<int>(e % 3);
      if (violated(T[3 * t + k], T[3 * t + (k + 1) % 3], T[3 * t + (k + 2) % 3], T[3 * s + j])) return -1;
    }
    for (int64_t t = 0; t < m; ++t) canonical(t, T, N);
    return flips;
  } catch (...) {
    return -1;
  }
}

// The interior part of a power diagram's cells clipped to the square [-0.5, 0.5]^2, from its
// regular triangulation (T, N: m x 3 as geoface_rt2 writes them; cen: m x 2 power centres;
// xy: the n real sites, re-centred, followed by the guard sites).  Each dual edge (the segment
// between the power centres of two adjacent triangles) is clipped to the square (Liang-Barsky)
// and oriented counter-clockwise around each of its two cells; the shoelace formula, taken
// relative to the site, adds its part of the cell's area and first moment.  Edges between two
// real sites with a clipped length above 1e-15 are written to E (k x 2, i < j) and L (k).
// area (n) and mom (n x 2) are accumulated into (the caller zeroes them).  Returns k.
// Same arithmetic as geoface.param.power._cells (its NumPy fallback).
int64_t geoface_power_cells(int64_t n, const double* xy, int64_t m, const int64_t* T, const int64_t* N,
                            const double* cen, double* area, double* mom, int64_t* E, double* L) {
  const double lo = -0.5, hi = 0.5;
  const double inf = std::numeric_limits<double>::infinity();
  int64_t k_out = 0;
  auto add = [&](int64_t c, double ax, double ay, double bx, double by) {
    if (c >= n) return;
    const double rx = xy[2 * c], ry = xy[2 * c + 1];
    const double rax = ax - rx, ray = ay - ry, rbx = bx - rx, rby = by - ry;
    const double cr = rax * rby - ray * rbx;
    area[c] += 0.5 * cr;
    const double s = cr / 6.0;
    mom[2 * c] += s * (rax + rbx);
    mom[2 * c + 1] += s * (ray + rby);
  };
  for (int64_t t = 0; t < m; ++t) {
    for (int k = 0; k < 3; ++k) {
      const int64_t s = N[3 * t + k];
      if (!(t < s)) continue;
      const int64_t vi = T[3 * t + (k + 1) % 3], vj = T[3 * t + (k + 2) % 3];
      if (vi >= n && vj >= n) continue;
      const double a[2] = {cen[2 * t], cen[2 * t + 1]};
      const double d[2] = {cen[2 * s] - a[0], cen[2 * s + 1] - a[1]};
      double t0 = 0.0, t1 = 1.0;
      for (int c = 0; c < 2; ++c) {
        double tmin, tmax;
        if (d[c] == 0.0) {
          const bool inside = a[c] >= lo && a[c] <= hi;
          tmin = inside ? -inf : inf;
          tmax = inside ? inf : -inf;
        } else {
          const double ta = (lo - a[c]) / d[c], tb = (hi - a[c]) / d[c];
          tmin = std::min(ta, tb);
          tmax = std::max(ta, tb);
        }
        t0 = std::max(t0, tmin);
        t1 = std::min(t1, tmax);
      }
      if (!(t1 > t0)) continue;
      double qax = a[0] + t0 * d[0], qay = a[1] + t0 * d[1];
      double qbx = a[0] + t1 * d[0], qby = a[1] + t1 * d[1];
      const double px = xy[2 * vj] - xy[2 * vi], py = xy[2 * vj + 1] - xy[2 * vi + 1];
      if ((qbx - qax) * py - (qby - qay) * px > 0) {
        std::swap(qax, qbx);
        std::swap(qay, qby);
      }
      add(vi, qax, qay, qbx, qby);
      add(vj, qbx, qby, qax, qay);
      const double len = std::hypot(qbx - qax, qby - qay);
      if (vi < n && vj < n && len > 1e-15) {
        E[2 * k_out] = std::min(vi, vj);
        E[2 * k_out + 1] = std::max(vi, vj);
        L[k_out] = len;
        ++k_out;
      }
    }
  }
  return k_out;
}

// Power centres of m triangles T (m x 3) of weighted points (xy, w), relative to each
// triangle's first vertex (the arithmetic of geoface.param.power_triangulation._power_centres:
// NaN or infinity for a triangle too flat for double precision).  Returns how many triangles
// are not counter-clockwise with a positive floating-point area (twice the signed area,
// relative to the first vertex, <= 0).
int64_t geoface_power_centres(int64_t m, const double* xy, const double* w, const int64_t* T, double* cen) {
  int64_t flat = 0;
  for (int64_t t = 0; t < m; ++t) {
    const int64_t a = T[3 * t], b = T[3 * t + 1], c = T[3 * t + 2];
    const double bx = xy[2 * b] - xy[2 * a], by = xy[2 * b + 1] - xy[2 * a + 1];
    const double cx = xy[2 * c] - xy[2 * a], cy = xy[2 * c + 1] - xy[2 * a + 1];
    const double rb = (bx * bx + by * by) - w[b] + w[a];
    const double rc = (cx * cx + cy * cy) - w[c] + w[a];
    const double o = bx * cy - by * cx;
    const double det = 2.0 * o;
    cen[2 * t] = xy[2 * a] + (rb * cy - rc * by) / det;
    cen[2 * t + 1] = xy[2 * a + 1] + (bx * rc - cx * rb) / det;
    if (!(o > 0)) ++flat;
  }
  return flat;
}

// The square's sides' part of the power cells: on each side A + t d (t in [0, 1]) the power of
// candidate site c is t^2 + slope_c t + icept_c, so the side is split among the lower envelope
// of the lines slope_c t + icept_c (taken in order of decreasing slope, ties by increasing
// intercept, then by position in cand); each piece is added to its cell's area and first
// moment (relative to the site) as the interior pieces are.  X: the n sites re-centred on the
// square [-0.5, 0.5]^2, w their weights; cand: the nc sites that may reach a side.
// Same arithmetic as geoface.param.power._lower_envelope and its caller (the NumPy fallback).
void geoface_power_sides(int64_t n, const double* X, const double* w, int64_t nc, const int64_t* cand,
                         double* area, double* mom) {
  static const double side_a[4][2] = {{-0.5, -0.5}, {0.5, -0.5}, {0.5, 0.5}, {-0.5, 0.5}};
  static const double side_d[4][2] = {{1.0, 0.0}, {0.0, 1.0}, {-1.0, 0.0}, {0.0, -1.0}};
  std::vector<double> slope(static_cast<size_t>(nc)), icept(static_cast<size_t>(nc));
  std::vector<int64_t> order(static_cast<size_t>(nc));
  std::vector<double> hm, hb;
  std::vector<int64_t> hi;
  for (int sd = 0; sd < 4; ++sd) {
    const double ax = side_a[sd][0], ay = side_a[sd][1], dx = side_d[sd][0], dy = side_d[sd][1];
    for (int64_t k = 0; k < nc; ++k) {
      const int64_t c = cand[k];
      const double fx = ax - X[2 * c], fy = ay - X[2 * c + 1];
      slope[k] = 2.0 * (fx * dx + fy * dy);
      icept[k] = (fx * fx + fy * fy) - w[c];
      order[k] = k;
    }
    std::stable_sort(order.begin(), order.end(), [&](int64_t a, int64_t b) {
      if (slope[a] != slope[b]) return slope[a] > slope[b];
      return icept[a] < icept[b];
    });
    hm.clear();
    hb.clear();
    hi.clear();
    bool first = true;
    double last_m = 0.0;
    for (int64_t idx : order) {
      const double m = slope[idx], b = icept[idx];
      if (!first && m == last_m) continue;  // same slope, higher intercept: never below
      first = false;
      last_m = m;
      while (!hm.empty()) {
        const double m1 = hm.back(), b1 = hb.back();
        const double x_new = (b - b1) / (m1 - m);
        double x_prev = -std::numeric_limits<double>::infinity();
        if (hm.size() >= 2) {
          const double m0 = hm[hm.size() - 2], b0 = hb[hb.size() - 2];
          x_prev = (b1 - b0) / (m0 - m1);
        }
        if (x_new <= x_prev) {
          hm.pop_back();
          hb.pop_back();
          hi.pop_back();
        } else {
          break;
        }
      }
      hm.push_back(m);
      hb.push_back(b);
      hi.push_back(idx);
    }
    const size_t h = hm.size();
    for (size_t j = 0; j < h; ++j) {
      double lo = j == 0 ? -std::numeric_limits<double>::infinity() : (hb[j] - hb[j - 1]) / (hm[j - 1] - hm[j]);
      double up = j + 1 == h ? std::numeric_limits<double>::infinity() : (hb[j + 1] - hb[j]) / (hm[j] - hm[j + 1]);
      lo = std::min(std::max(lo, 0.0), 1.0);
      up = std::min(std::max(up, 0.0), 1.0);
      if (!(up > lo)) continue;
      const int64_t c = cand[hi[j]];
      if (c >= n) continue;
      const double rx = X[2 * c], ry = X[2 * c + 1];
      const double rax = ax + lo * dx - rx, ray = ay + lo * dy - ry;
      const double rbx = ax + up * dx - rx, rby = ay + up * dy - ry;
      const double cr = rax * rby - ray * rbx;
      area[c] += 0.5 * cr;
      const double s = cr / 6.0;
      mom[2 * c] += s * (rax + rbx);
      mom[2 * c + 1] += s * (ray + rby);
    }
  }
}
}
