/// \file watertight.h
/// Watertight ray/triangle intersection shared by every triangle accelerator (brute force and
/// BVH), so that they agree bit for bit on which triangles a ray hits.
///
/// See Woop, Benthin, Wald 2013, "Watertight Ray/Triangle Intersection", JCGT 2(1). The ray is
/// sheared and scaled so that it points along +z from the origin; the triangle is transformed
/// the same way and tested with 2D edge functions. Because the transform of a vertex depends
/// only on the vertex and the ray (never on the triangle), two triangles sharing an edge see
/// bit-identical edge functions for it, so a ray can never slip through a shared edge or vertex.
/// Edge functions that evaluate to exactly 0 in float are recomputed in double (section 4 of
/// the paper) so that the sign decision on an edge is consistent for both neighbours.
#pragma once

#include <cmath>
#include <cstdint>

#include "specula/math.h"
#include "specula/ray.h"

namespace specula::accel {

/// Per-ray constants of the watertight test.
struct WatertightRay {
  int kx = 0, ky = 1, kz = 2;  ///< permutation: kz = dominant axis of the direction
  float ox = 0, oy = 0, oz = 0;  ///< origin, permuted (org[kx], org[ky], org[kz])
  float sx = 0, sy = 0, sz = 0;  ///< shear (sx, sy) and scale (sz)

  explicit WatertightRay(const Ray& ray) {
    const Vec3 a = abs(ray.dir);
    kz = (a.x >= a.y && a.x >= a.z) ? 0 : (a.y >= a.z ? 1 : 2);
    kx = kz == 2 ? 0 : kz + 1;
    ky = kx == 2 ? 0 : kx + 1;
    // Swapping kx and ky preserves the triangle's winding when the dominant component is
    // negative (the paper's footnote); it keeps the sign of det meaningful.
    if (ray.dir[kz] < 0.0f) {
      const int tmp = kx;
      kx = ky;
      ky = tmp;
    }
    ox = ray.org[kx];
    oy = ray.org[ky];
    oz = ray.org[kz];
    // For a zero or NaN direction these are NaN/inf; every comparison below is written so that
    // NaN rejects, so such rays simply miss.
    sz = 1.0f / ray.dir[kz];
    sx = ray.dir[kx] * sz;
    sy = ray.dir[ky] * sz;
  }
};

/// Result of one triangle test (only meaningful when the test returns true).
struct TriHit {
  float t, u, v;
};

/// Tests the triangle with vertices v[0..2], v[3..5], v[6..8] against the ray; accepts hits
/// with tmin <= t <= tmax. On success (u, v) are the barycentrics of vertices 1 and 2.
/// NaN-safe: non-finite intermediate values miss. Brute force and BVH both call exactly this
/// function on the same floats, so they agree bit for bit.
inline bool intersect_watertight(const WatertightRay& r, const float* v, float tmin, float tmax,
                                 TriHit& out) {
  const int kx = r.kx, ky = r.ky, kz = r.kz;
  const float az = v[kz] - r.oz, bz = v[3 + kz] - r.oz, cz = v[6 + kz] - r.oz;
  const float ax = (v[kx] - r.ox) - r.sx * az, ay = (v[ky] - r.oy) - r.sy * az;
  const float bx = (v[3 + kx] - r.ox) - r.sx * bz, by = (v[3 + ky] - r.oy) - r.sy * bz;
  const float cx = (v[6 + kx] - r.ox) - r.sx * cz, cy = (v[6 + ky] - r.oy) - r.sy * cz;

  float u = cx * by - cy * bx;  // edge v1-v2: weight of v0
  float w1 = ax * cy - ay * cx;  // edge v2-v0: weight of v1
  float w2 = bx * ay - by * ax;  // edge v0-v1: weight of v2

  if (u == 0.0f || w1 == 0.0f || w2 == 0.0f) [[unlikely]] {
    // Exactly on an edge in float: decide in double so neighbours agree (paper, section 4).
    u = static_cast<float>(static_cast<double>(cx) * by - static_cast<double>(cy) * bx);
    w1 = static_cast<float>(static_cast<double>(ax) * cy - static_cast<double>(ay) * cx);
    w2 = static_cast<float>(static_cast<double>(bx) * ay - static_cast<double>(by) * ax);
  }
  // Inside iff all edge functions have the same sign (two-sided). Written so NaN rejects.
  const bool all_nonneg = u >= 0.0f && w1 >= 0.0f && w2 >= 0.0f;
  const bool all_nonpos = u <= 0.0f && w1 <= 0.0f && w2 <= 0.0f;
  if (!(all_nonneg || all_nonpos)) return false;
  const float det = u + w1 + w2;
  if (!(det != 0.0f)) return false;  // degenerate (or edge-on) triangle, or NaN

  const float t_scaled = u * (r.sz * az) + w1 * (r.sz * bz) + w2 * (r.sz * cz);
  const float inv_det = 1.0f / det;
  const float t = t_scaled * inv_det;
  if (!(t >= tmin && t <= tmax)) return false;  // NaN rejects
  out.t = t;
  out.u = w1 * inv_det;
  out.v = w2 * inv_det;
  return true;
}

/// Unit geometric normal of a triangle as its winding gives it; zero for degenerate triangles.
inline Vec3 geometric_normal(const float* v) {
  const Vec3 v0{v[0], v[1], v[2]}, v1{v[3], v[4], v[5]}, v2{v[6], v[7], v[8]};
  return normalize(cross(v1 - v0, v2 - v0));
}

}  // namespace specula::accel
