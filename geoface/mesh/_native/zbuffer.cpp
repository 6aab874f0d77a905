// The z-buffer of geoface.mesh.raster.rasterize_mesh in C++: the same pixel centres, the same
// barycentric arithmetic (term by term, in the same order, no fused multiply-adds) and the same
// rule for equally near triangles (the first kept), so it writes what the NumPy loop writes, many
// times faster on the small renders the face search makes by the thousand.  Plain C ABI, loaded
// with ctypes by geoface/mesh/raster.py (no Python headers needed to build it); optional: where
// it is not built, the NumPy loop runs.
#include <cstdint>

extern "C" {

int geoface_zbuffer_abi(void) { return 1; }

// m triangles: pixel coordinates x, y (m x 3, pixel centres at integers), camera depths zf
// (m x 3), twice the signed areas det (m), bounding boxes [j0, j1] x [i0, i1] (inclusive, in the
// image) and on (m: 0 skips the triangle).  zbuf (H*W, +inf where empty), face (H*W, -1 where
// empty) and bary (H*W x 3) are updated in place.
void geoface_zbuffer(int64_t m, const double* x, const double* y, const double* zf, const double* det,
                     const int64_t* j0, const int64_t* j1, const int64_t* i0, const int64_t* i1,
                     const uint8_t* on, int64_t W, double* zbuf, int64_t* face, double* bary) {
  for (int64_t t = 0; t < m; ++t) {
    if (!on[t]) continue;
    const double xa0 = x[3 * t], xa1 = x[3 * t + 1], xa2 = x[3 * t + 2];
    const double ya0 = y[3 * t], ya1 = y[3 * t + 1], ya2 = y[3 * t + 2];
    const double z0 = zf[3 * t], z1 = zf[3 * t + 1], z2 = zf[3 * t + 2];
    const double d = det[t];
    for (int64_t i = i0[t]; i <= i1[t]; ++i) {
      const double py = static_cast<double>(i);
      for (int64_t j = j0[t]; j <= j1[t]; ++j) {
        const double px = static_cast<double>(j);
        const double b1 = ((px - xa0) * (ya2 - ya0) - (xa2 - xa0) * (py - ya0)) / d;
        const double b2 = ((xa1 - xa0) * (py - ya0) - (px - xa0) * (ya1 - ya0)) / d;
        const double b0 = 1.0 - b1 - b2;
        if (!(b0 >= -1e-9 && b1 >= -1e-9 && b2 >= -1e-9)) continue;
        const double w0 = (b0 > 0.0 ? b0 : 0.0) / z0, w1 = (b1 > 0.0 ? b1 : 0.0) / z1, w2 = (b2 > 0.0 ? b2 : 0.0) / z2;
        const double zc = 1.0 / (w0 + w1 + w2);
        const int64_t p = i * W + j;
        if (zc < zbuf[p]) {
          zbuf[p] = zc;
          face[p] = t;
          bary[3 * p] = w0 * zc;
          bary[3 * p + 1] = w1 * zc;
          bary[3 * p + 2] = w2 * zc;
        }
      }
    }
  }
}

}  // extern "C"
