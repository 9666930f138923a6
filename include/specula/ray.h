/// \file ray.h
/// Rays and hit records shared by every acceleration structure and integrator.
#pragma once

#include <cmath>
#include <cstdint>
#include <cstring>

#include "specula/math.h"

namespace specula {

inline constexpr uint32_t kNoHit = 0xFFFFFFFFu;

struct Ray {
  Vec3 org;
  float tmin = 0.0f;
  Vec3 dir;  ///< need not be unit length; t is measured in units of |dir|
  float tmax = kInf;
};

/// Result of a closest-hit query. `prim` is the triangle index in scene order (kNoHit on a
/// miss); (u, v) are barycentrics of vertices 1 and 2; `ng` is the unit geometric normal,
/// oriented as the triangle's winding gives it (not flipped towards the ray).
struct Hit {
  float t = kInf;
  uint32_t prim = kNoHit;
  float u = 0.0f, v = 0.0f;
  Vec3 ng;

  bool hit() const { return prim != kNoHit; }
};

/// Counters a traversal may add to (for the traversal-cost AOV and benchmarks).
struct TraceStats {
  uint64_t rays = 0;
  uint64_t nodes_visited = 0;
  uint64_t triangles_tested = 0;
  /// Ray packets traced (tracers that group coherent rays; each packet's node visits and leaf
  /// triangles count once in the two counters above, however many rays it carries).
  uint64_t packets = 0;
  uint64_t packet_rays = 0;  ///< rays traced inside those packets

  TraceStats& operator+=(const TraceStats& o) {
    rays += o.rays;
    nodes_visited += o.nodes_visited;
    triangles_tested += o.triangles_tested;
    packets += o.packets;
    packet_rays += o.packet_rays;
    return *this;
  }
};

/// Moves a surface point \p p (computed from barycentrics, so it lies within float error of
/// the triangle) off the surface along \p n (the geometric normal, pointing to the side the
/// new ray leaves into). The offset is a few ulps of the position's own magnitude instead of a
/// fixed epsilon, so it works at any scene scale. Near the origin, where ulps become tiny,
/// a small absolute offset takes over. See Waechter and Binder, "A Fast and Robust Method for
/// Avoiding Self-Intersection", Ray Tracing Gems (2019), chapter 6.
inline Vec3 offset_ray_origin(const Vec3& p, const Vec3& n) {
  constexpr float kOrigin = 1.0f / 32.0f;
  constexpr float kFloatScale = 1.0f / 65536.0f;
  constexpr float kIntScale = 256.0f;
  Vec3 out;
  for (int i = 0; i < 3; ++i) {
    const int32_t of = static_cast<int32_t>(kIntScale * n[i]);
    int32_t bits;
    float pi = p[i];
    std::memcpy(&bits, &pi, sizeof bits);
    bits += (p[i] < 0.0f) ? -of : of;  // moves away from the surface in ulps
    std::memcpy(&pi, &bits, sizeof pi);
    out[i] = std::fabs(p[i]) < kOrigin ? p[i] + kFloatScale * n[i] : pi;
  }
  return out;
}

}  // namespace specula
