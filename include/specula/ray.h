/// \file ray.h
/// Rays and hit records shared by every acceleration structure and integrator.
#pragma once

#include <cstdint>

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

  TraceStats& operator+=(const TraceStats& o) {
    rays += o.rays;
    nodes_visited += o.nodes_visited;
    triangles_tested += o.triangles_tested;
    return *this;
  }
};

}  // namespace specula
