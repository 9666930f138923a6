// BVH traversal: closest hit and transmittance/any-hit (owner: accel).
//
// Stack-based traversal of the binary BVH that tests both children of an interior node, descends
// into the nearer one and pushes the farther one with its entry distance (seed 004; seed 002,
// section 3.3.4). Popped nodes farther than the current closest hit are skipped.
//
// Ray/box: slab test with a precomputed reciprocal direction, both children at once with SSE2
// (see intersect_pair). Zero direction components get a finite +-FLT_MAX reciprocal (see
// safe_rcp), so no NaN can arise from 0 * inf. The far distance is scaled by
// 1 + 2 gamma(3) as in Ize 2013, "Robust BVH Ray Traversal" (JCGT 2(2)), so that rounding can
// never make a ray miss a box that contains a triangle it hits (flat boxes of axis-aligned
// triangles in particular). Triangles use the watertight test (watertight.h).
#include <emmintrin.h>  // SSE2: x86-64 baseline
#include <xmmintrin.h>  // _mm_prefetch

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <limits>

#include "accel/triangles.h"
#include "accel/watertight.h"
#include "specula/bvh.h"
#include "specula/error.h"

namespace specula {

namespace {

/// Maximum BVH depth the traversal stack supports; the builder bounds the depth well below
/// (kMedianDepth + 32 in bvh_build.cpp).
constexpr int kStackSize = 128;
/// 1 + 2 * gamma(3), gamma(n) = n eps / (1 - n eps), eps = 2^-24 (Ize 2013).
constexpr float kFarScale = 1.0f + 2.0f * (3.0f * 0x1p-24f) / (1.0f - 3.0f * 0x1p-24f);

/// Reciprocal of a direction component that is never infinite: 1/0 (or 1/denormal) becomes
/// +-FLT_MAX with the component's sign. Then (bound - org) * rcp is 0 (not 0 * inf = NaN) when
/// the origin lies exactly on a slab plane, and +-large otherwise, so the slab test needs no NaN
/// handling at all: a ray lying in a box's face plane counts as inside (the face is part of
/// the closed box), which is what the edge-inclusive watertight triangle test needs.
inline float safe_rcp(float d) {
  const float r = 1.0f / d;
  return std::isfinite(r) ? r : std::copysign(std::numeric_limits<float>::max(), d);
}

/// Per-ray constants of the box test, broadcast for the SSE sibling test.
struct BoxRay {
  __m128 ox, oy, oz;
  __m128 rx, ry, rz;
  __m128 tmin;
  float sox, soy, soz, srx, sry, srz;  ///< scalar copies for the root test

  explicit BoxRay(const Ray& ray) {
    sox = ray.org.x, soy = ray.org.y, soz = ray.org.z;
    srx = safe_rcp(ray.dir.x), sry = safe_rcp(ray.dir.y), srz = safe_rcp(ray.dir.z);
    ox = _mm_set1_ps(sox), oy = _mm_set1_ps(soy), oz = _mm_set1_ps(soz);
    rx = _mm_set1_ps(srx), ry = _mm_set1_ps(sry), rz = _mm_set1_ps(srz);
    tmin = _mm_set1_ps(ray.tmin);
  }
};

/// Scalar slab test of one node (used for the root only). Returns the entry distance within
/// [tmin, tmax] or kInf on a miss.
inline float intersect_box(const BvhNode& n, const BoxRay& r, float tmin, float tmax) {
  const float tx1 = (n.min.x - r.sox) * r.srx, tx2 = (n.max.x - r.sox) * r.srx;
  const float ty1 = (n.min.y - r.soy) * r.sry, ty2 = (n.max.y - r.soy) * r.sry;
  const float tz1 = (n.min.z - r.soz) * r.srz, tz2 = (n.max.z - r.soz) * r.srz;
  const float tnear = std::max(std::max(std::min(tx1, tx2), std::min(ty1, ty2)), std::max(std::min(tz1, tz2), tmin));
  const float tfar = std::min(std::min(std::max(tx1, tx2), std::max(ty1, ty2)), std::min(std::max(tz1, tz2), tmax)) * kFarScale;
  return tnear <= tfar ? tnear : kInf;
}

/// Slab test of both children of an interior node at once (SSE2). The two 32-byte siblings
/// are adjacent (one cache line); their bounds are transposed into x/y/z registers holding
/// (min0, min1, max0, max1). Returns a 2-bit hit mask; \p tnear lanes 0/1 get entry distances.
inline int intersect_pair(const BvhNode* c, const BoxRay& r, __m128 tmax, __m128& tnear) {
  const float* p = &c[0].min.x;
  const __m128 a = _mm_load_ps(p), b = _mm_load_ps(p + 4), cc = _mm_load_ps(p + 8), d = _mm_load_ps(p + 12);
  const __m128 t0 = _mm_unpacklo_ps(a, cc), t1 = _mm_unpacklo_ps(b, d);
  const __m128 t2 = _mm_unpackhi_ps(a, cc), t3 = _mm_unpackhi_ps(b, d);
  const __m128 x = _mm_movelh_ps(t0, t1), y = _mm_movehl_ps(t1, t0), z = _mm_movelh_ps(t2, t3);
  const __m128 tx = _mm_mul_ps(_mm_sub_ps(x, r.ox), r.rx);
  const __m128 ty = _mm_mul_ps(_mm_sub_ps(y, r.oy), r.ry);
  const __m128 tz = _mm_mul_ps(_mm_sub_ps(z, r.oz), r.rz);
  const __m128 txs = _mm_shuffle_ps(tx, tx, _MM_SHUFFLE(1, 0, 3, 2));
  const __m128 tys = _mm_shuffle_ps(ty, ty, _MM_SHUFFLE(1, 0, 3, 2));
  const __m128 tzs = _mm_shuffle_ps(tz, tz, _MM_SHUFFLE(1, 0, 3, 2));
  tnear = _mm_max_ps(_mm_max_ps(_mm_min_ps(tx, txs), _mm_min_ps(ty, tys)), _mm_max_ps(_mm_min_ps(tz, tzs), r.tmin));
  const __m128 tfar = _mm_mul_ps(
      _mm_min_ps(_mm_min_ps(_mm_max_ps(tx, txs), _mm_max_ps(ty, tys)), _mm_min_ps(_mm_max_ps(tz, tzs), tmax)),
      _mm_set1_ps(kFarScale));
  return _mm_movemask_ps(_mm_cmple_ps(tnear, tfar)) & 3;
}

/// Rays the traversal can answer at all: finite origin and direction, non-zero direction,
/// tmin <= tmax. Everything else misses (and is fully transmitted), without touching the tree.
inline bool valid_ray(const Ray& ray) {
  return is_finite(ray.org) && is_finite(ray.dir) && (ray.dir.x != 0.0f || ray.dir.y != 0.0f || ray.dir.z != 0.0f) &&
         ray.tmin <= ray.tmax;
}

/// Starts loading what a child will need next (its children pair, or its triangles) so the
/// memory latency overlaps with the work on its sibling. Worth it: the tree does not fit in L2
/// and incoherent rays would otherwise wait on every level.
inline void prefetch_child(const BvhNode& child, const BvhNode* nodes, const BvhTriangle* tris) {
  const char* p = child.count > 0 ? reinterpret_cast<const char*>(tris + child.left_first)
                                  : reinterpret_cast<const char*>(nodes + child.left_first);
  _mm_prefetch(p, _MM_HINT_T0);
}

struct StackEntry {
  const BvhNode* node;
  float t;
};

}  // namespace

class BvhTraversal {
 public:
  template <bool kStats>
  static Hit closest(const Bvh& bvh, const Ray& ray, TraceStats& stats) {
    Hit hit;
    if constexpr (kStats) ++stats.rays;
    if (bvh.tris_.empty() || !valid_ray(ray)) return hit;
    const BvhNode* nodes = bvh.nodes_.data();
    const BvhTriangle* tris = bvh.tris_.data();
    const BoxRay br(ray);
    float best_t = ray.tmax;
    uint32_t best = kNoHit;
    float bu = 0.0f, bv = 0.0f;

    const BvhNode* node = nodes;
    if (intersect_box(*node, br, ray.tmin, best_t) == kInf) return hit;
    const accel::WatertightRay wr(ray);
    StackEntry stack[kStackSize];
    int sp = 0;
    for (;;) {
      if constexpr (kStats) ++stats.nodes_visited;
      if (node->count > 0) {
        const uint32_t end = node->left_first + node->count;
        if constexpr (kStats) stats.triangles_tested += node->count;
        for (uint32_t i = node->left_first; i < end; ++i) {
          accel::TriHit th;
          if (accel::intersect_watertight(wr, tris[i].v, ray.tmin, best_t, th)) {
            best_t = th.t;
            best = i;
            bu = th.u;
            bv = th.v;
          }
        }
      } else {
        const BvhNode* c = nodes + node->left_first;
        __m128 tnear;
        const int mask = intersect_pair(c, br, _mm_set1_ps(best_t), tnear);
        if (mask != 0) {
          if (mask & 1) prefetch_child(c[0], nodes, tris);
          if (mask & 2) prefetch_child(c[1], nodes, tris);
          // Branch-free ordering: the nearer child is next; when both are hit the farther
          // one is pushed (the push always writes, sp only moves when both were hit).
          const float d0 = _mm_cvtss_f32(tnear);
          const float d1 = _mm_cvtss_f32(_mm_shuffle_ps(tnear, tnear, 1));
          const int both = mask == 3;
          const int near = both ? static_cast<int>(d1 < d0) : (mask >> 1);
          stack[sp] = {c + (1 - near), std::max(d0, d1)};
          sp += both;
          node = c + near;
          continue;
        }
      }
      // Pop the next node that may still hold a closer hit.
      for (;;) {
        if (sp == 0) goto done;
        const StackEntry& e = stack[--sp];
        if (e.t <= best_t) {
          node = e.node;
          break;
        }
      }
    }
  done:
    if (best != kNoHit) {
      hit.t = best_t;
      hit.prim = bvh.prim_ids_[best];
      hit.u = bu;
      hit.v = bv;
      hit.ng = accel::geometric_normal(tris[best].v);
    }
    return hit;
  }

  /// Product of the transmittance of every triangle crossed in (tmin, tmax); 0 at the first
  /// opaque one. With kAnyHit every crossed triangle counts as opaque (occlusion query).
  template <bool kStats, bool kAnyHit>
  static Vec3 transmit(const Bvh& bvh, const Ray& ray, TraceStats& stats) {
    if constexpr (kStats) ++stats.rays;
    Vec3 tr{1.0f, 1.0f, 1.0f};
    if (bvh.tris_.empty() || !valid_ray(ray)) return tr;
    const BvhNode* nodes = bvh.nodes_.data();
    const BvhTriangle* tris = bvh.tris_.data();
    const Vec3* trans = bvh.transmittance_.empty() ? nullptr : bvh.transmittance_.data();
    const BoxRay br(ray);
    const float tmin = ray.tmin, tmax = ray.tmax;
    const __m128 tmax4 = _mm_set1_ps(tmax);

    const BvhNode* node = nodes;
    if (intersect_box(*node, br, tmin, tmax) == kInf) return tr;
    const accel::WatertightRay wr(ray);
    const BvhNode* stack[kStackSize];
    int sp = 0;
    for (;;) {
      if constexpr (kStats) ++stats.nodes_visited;
      if (node->count > 0) {
        const uint32_t end = node->left_first + node->count;
        if constexpr (kStats) stats.triangles_tested += node->count;
        for (uint32_t i = node->left_first; i < end; ++i) {
          accel::TriHit th;
          if (accel::intersect_watertight(wr, tris[i].v, tmin, tmax, th) && th.t > tmin && th.t < tmax) {
            if (kAnyHit || trans == nullptr || accel::is_opaque(trans[i])) return Vec3{};
            tr *= trans[i];
          }
        }
      } else {
        const BvhNode* c = nodes + node->left_first;
        __m128 tnear;
        const int mask = intersect_pair(c, br, tmax4, tnear);
        if (mask != 0) {
          if (mask & 1) prefetch_child(c[0], nodes, tris);
          if (mask & 2) prefetch_child(c[1], nodes, tris);
          const float d0 = _mm_cvtss_f32(tnear);
          const float d1 = _mm_cvtss_f32(_mm_shuffle_ps(tnear, tnear, 1));
          const int both = mask == 3;
          const int near = both ? static_cast<int>(d1 < d0) : (mask >> 1);
          stack[sp] = c + (1 - near);
          sp += both;
          node = c + near;
          continue;
        }
      }
      if (sp == 0) break;
      node = stack[--sp];
    }
    return tr;
  }
};

void Bvh::intersect(std::span<const Ray> rays, std::span<Hit> hits, TraceStats* stats) const {
  if (hits.size() < rays.size()) throw Error("Bvh::intersect: hits span smaller than rays span");
  if (stats) {
    TraceStats local;
    for (size_t i = 0; i < rays.size(); ++i) hits[i] = BvhTraversal::closest<true>(*this, rays[i], local);
    *stats += local;
  } else {
    TraceStats unused;
    for (size_t i = 0; i < rays.size(); ++i) hits[i] = BvhTraversal::closest<false>(*this, rays[i], unused);
  }
}

void Bvh::transmittance(std::span<const Ray> rays, std::span<Vec3> out, TraceStats* stats) const {
  if (out.size() < rays.size()) throw Error("Bvh::transmittance: out span smaller than rays span");
  TraceStats local;
  if (transmittance_.empty()) {
    // All opaque: a pure occlusion query.
    if (stats) {
      for (size_t i = 0; i < rays.size(); ++i) out[i] = BvhTraversal::transmit<true, true>(*this, rays[i], local);
    } else {
      for (size_t i = 0; i < rays.size(); ++i) out[i] = BvhTraversal::transmit<false, true>(*this, rays[i], local);
    }
  } else {
    if (stats) {
      for (size_t i = 0; i < rays.size(); ++i) out[i] = BvhTraversal::transmit<true, false>(*this, rays[i], local);
    } else {
      for (size_t i = 0; i < rays.size(); ++i) out[i] = BvhTraversal::transmit<false, false>(*this, rays[i], local);
    }
  }
  if (stats) *stats += local;
}

Hit Bvh::intersect(const Ray& ray) const {
  TraceStats unused;
  return BvhTraversal::closest<false>(*this, ray, unused);
}

bool Bvh::occluded(const Ray& ray) const {
  TraceStats unused;
  return BvhTraversal::transmit<false, true>(*this, ray, unused).x == 0.0f;
}

}  // namespace specula
