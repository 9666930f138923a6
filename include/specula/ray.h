/// \file ray.h
/// Rays and hit records shared by every acceleration structure and integrator.
#pragma once

#include <cmath>
#include <cstdint>
#include <cstring>
#if defined(__SSE2__)
#include <emmintrin.h>
#endif

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
#if defined(__SSE2__)
  // The scalar formula below, three lanes at a time (the integrator calls this for every
  // secondary and shadow ray): the same truncation, integer add and select per lane, so the
  // result is the same bit for bit.
  const __m128 pv = _mm_setr_ps(p.x, p.y, p.z, 0.0f), nv = _mm_setr_ps(n.x, n.y, n.z, 0.0f);
  const __m128i of = _mm_cvttps_epi32(_mm_mul_ps(_mm_set1_ps(kIntScale), nv));
  const __m128i neg = _mm_castps_si128(_mm_cmplt_ps(pv, _mm_setzero_ps()));
  const __m128i step = _mm_sub_epi32(_mm_xor_si128(of, neg), neg);  // p < 0 ? -of : of
  const __m128 pi = _mm_castsi128_ps(_mm_add_epi32(_mm_castps_si128(pv), step));
  const __m128 abs_p = _mm_andnot_ps(_mm_set1_ps(-0.0f), pv);
  const __m128 near_origin = _mm_cmplt_ps(abs_p, _mm_set1_ps(kOrigin));
  const __m128 nudged = _mm_add_ps(pv, _mm_mul_ps(_mm_set1_ps(kFloatScale), nv));
  const __m128 r = _mm_or_ps(_mm_and_ps(near_origin, nudged), _mm_andnot_ps(near_origin, pi));
  alignas(16) float out[4];
  _mm_store_ps(out, r);
  return {out[0], out[1], out[2]};
#else
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
#endif
}

}  // namespace specula
