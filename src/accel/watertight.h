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

#include <emmintrin.h>  // SSE2: x86-64 baseline

#include <cmath>
#include <cstddef>
#include <cstdint>
#include <limits>

#include "specula/bvh.h"
#include "specula/math.h"
#include "specula/ray.h"

/// Forces the small per-ray and per-block helpers below inline into the traversal loops, which
/// are large enough (packets included) that GCC's inlining budget would otherwise call them.
#define SPECULA_ACCEL_INLINE inline __attribute__((always_inline))

namespace specula::accel {

/// Per-ray constants of the watertight test.
struct WatertightRay {
  int kx = 0, ky = 1, kz = 2;  ///< permutation: kz = dominant axis of the direction
  float ox = 0, oy = 0, oz = 0;  ///< origin, permuted (org[kx], org[ky], org[kz])
  float sx = 0, sy = 0, sz = 0;  ///< shear (sx, sy) and scale (sz)

  explicit SPECULA_ACCEL_INLINE WatertightRay(const Ray& ray) {
    // The components are read by index (Vec3::operator[] is a chain of selects, which GCC
    // turned into three-way branches per read). The axes are chosen by the same comparisons
    // as always; GCC still branches on those (fully branch-free versions, bitwise or by a
    // lookup table, cost 6-30 more instructions per incoherent ray under callgrind, and their
    // saving in mispredictions could not be measured on the shared machine).
    static_assert(sizeof(Vec3) == 3 * sizeof(float), "Vec3 must be three packed floats");
    float o[3], d[3];
    __builtin_memcpy(o, &ray.org, sizeof o);
    __builtin_memcpy(d, &ray.dir, sizeof d);
    const float ax = std::fabs(d[0]), ay = std::fabs(d[1]), az = std::fabs(d[2]);
    const int not_x = static_cast<int>(!(ax >= ay && ax >= az));
    kz = not_x + static_cast<int>(not_x != 0 && !(ay >= az));
    const int nx = kz == 2 ? 0 : kz + 1, ny = nx == 2 ? 0 : nx + 1;
    // Swapping kx and ky preserves the triangle's winding when the dominant component is
    // negative (the paper's footnote); it keeps the sign of det meaningful.
    const bool neg = d[kz] < 0.0f;
    kx = neg ? ny : nx;
    ky = neg ? nx : ny;
    ox = o[kx];
    oy = o[ky];
    oz = o[kz];
    // For a zero or NaN direction these are NaN/inf; every comparison below is written so that
    // NaN rejects, so such rays simply miss.
    sz = 1.0f / d[kz];
    sx = d[kx] * sz;
    sy = d[ky] * sz;
  }
};

/// Result of one triangle test (only meaningful when the test returns true).
struct TriHit {
  float t, u, v;
};

/// How a ray that crosses a triangle exactly on an edge or vertex (an edge function exactly
/// zero, even in double) is counted.
enum class EdgeRule {
  /// Closed triangles: every triangle sharing the edge reports the hit. Right for closest-hit
  /// and occlusion queries (any one of them will do).
  Closed,
  /// Half-open triangles, as rasterizers' top-left rule: of the triangles sharing an edge or a
  /// vertex, exactly one reports the hit, so a transmittance product counts a surface once.
  HalfOpen,
};

namespace detail {
/// Whether the half-open rule gives a zero-function edge from (x0, y0) to (x1, y1) (in the
/// triangle's own vertex order, projected) to this triangle. \p det_sign normalises the
/// orientation: two triangles on either side of a shared edge then see it in opposite
/// directions, and exactly one of the two directions is accepted. Coordinates of shared
/// vertices are bit-identical in both triangles, and float subtraction is exactly
/// antisymmetric, so the two decisions are exact complements.
inline bool owns_edge(float x0, float y0, float x1, float y1, float det_sign) {
  const float ex = (x1 - x0) * det_sign, ey = (y1 - y0) * det_sign;
  return ey > 0.0f || (ey == 0.0f && ex > 0.0f);
}
}  // namespace detail

/// Tests the triangle with vertices v[0..2], v[3..5], v[6..8] against the ray; accepts hits
/// with tmin <= t <= tmax. On success (u, v) are the barycentrics of vertices 1 and 2.
/// NaN-safe: non-finite intermediate values miss. Brute force and BVH both call exactly this
/// function on the same floats, so they agree bit for bit.
inline bool intersect_watertight(const WatertightRay& r, const float* v, float tmin, float tmax,
                                 TriHit& out, EdgeRule rule = EdgeRule::Closed) {
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
  if (rule == EdgeRule::HalfOpen && (u == 0.0f || w1 == 0.0f || w2 == 0.0f)) [[unlikely]] {
    const float sign = det > 0.0f ? 1.0f : -1.0f;
    if (u == 0.0f && !detail::owns_edge(bx, by, cx, cy, sign)) return false;
    if (w1 == 0.0f && !detail::owns_edge(cx, cy, ax, ay, sign)) return false;
    if (w2 == 0.0f && !detail::owns_edge(ax, ay, bx, by, sign)) return false;
  }

  const float t_scaled = u * (r.sz * az) + w1 * (r.sz * bz) + w2 * (r.sz * cz);
  const float inv_det = 1.0f / det;
  const float t = t_scaled * inv_det;
  if (!(t >= tmin && t <= tmax)) return false;  // NaN rejects
  out.t = t;
  out.u = w1 * inv_det;
  out.v = w2 * inv_det;
  return true;
}

/// The per-ray constants of WatertightRay broadcast to four lanes (hoisted out of the leaf loop).
/// The axis permutation is kept as byte offsets into a block's vertex (kx * 16 ...), so a lane
/// load is one addressing mode (block + offset + vertex) and nothing is recomputed per leaf.
struct WatertightRay4 {
  size_t kx, ky, kz;  ///< byte offsets of the permuted axes within one vertex's [axis][lane] rows
  __m128 ox, oy, oz, sx, sy, sz;

  explicit SPECULA_ACCEL_INLINE WatertightRay4(const WatertightRay& r)
      : kx(static_cast<size_t>(r.kx) * sizeof(__m128)), ky(static_cast<size_t>(r.ky) * sizeof(__m128)),
        kz(static_cast<size_t>(r.kz) * sizeof(__m128)), ox(_mm_set1_ps(r.ox)), oy(_mm_set1_ps(r.oy)),
        oz(_mm_set1_ps(r.oz)), sx(_mm_set1_ps(r.sx)), sy(_mm_set1_ps(r.sy)), sz(_mm_set1_ps(r.sz)) {}
};

/// Lanes of vertex \p vertex, axis at byte offset \p axis_offset, of a block's v[3][3][4].
SPECULA_ACCEL_INLINE __m128 load_lanes(const float (&v)[3][3][4], int vertex, size_t axis_offset) {
  return _mm_load_ps(reinterpret_cast<const float*>(reinterpret_cast<const char*>(v[vertex]) + axis_offset));
}

/// intersect_watertight() for four triangles at once, \p v[vertex][axis][lane] holding one
/// coordinate of the four triangles (16-byte aligned; padding lanes NaN: never hit). The lanes
/// are loaded straight from memory by the ray's axis permutation (no copy of the block). The very same float operations in the
/// same order per lane (SSE arithmetic is IEEE single precision like the scalar code), so the
/// results are bit-identical. When an edge function is exactly zero in some lane (which needs
/// the double-precision fallback) the function returns -1 and the caller must test the group
/// with the scalar function. Otherwise returns the lane mask of hits in [tmin, tmax] with their
/// t, u, v.
SPECULA_ACCEL_INLINE int intersect_watertight4(const WatertightRay4& r, const float (&v)[3][3][4], __m128 tmin, __m128 tmax,
                                 __m128& t_out, __m128& u_out, __m128& v_out) {
  const __m128 az = _mm_sub_ps(load_lanes(v, 0, r.kz), r.oz), bz = _mm_sub_ps(load_lanes(v, 1, r.kz), r.oz),
               cz = _mm_sub_ps(load_lanes(v, 2, r.kz), r.oz);
  const __m128 ax = _mm_sub_ps(_mm_sub_ps(load_lanes(v, 0, r.kx), r.ox), _mm_mul_ps(r.sx, az));
  const __m128 ay = _mm_sub_ps(_mm_sub_ps(load_lanes(v, 0, r.ky), r.oy), _mm_mul_ps(r.sy, az));
  const __m128 bx = _mm_sub_ps(_mm_sub_ps(load_lanes(v, 1, r.kx), r.ox), _mm_mul_ps(r.sx, bz));
  const __m128 by = _mm_sub_ps(_mm_sub_ps(load_lanes(v, 1, r.ky), r.oy), _mm_mul_ps(r.sy, bz));
  const __m128 cx = _mm_sub_ps(_mm_sub_ps(load_lanes(v, 2, r.kx), r.ox), _mm_mul_ps(r.sx, cz));
  const __m128 cy = _mm_sub_ps(_mm_sub_ps(load_lanes(v, 2, r.ky), r.oy), _mm_mul_ps(r.sy, cz));
  const __m128 u = _mm_sub_ps(_mm_mul_ps(cx, by), _mm_mul_ps(cy, bx));
  const __m128 w1 = _mm_sub_ps(_mm_mul_ps(ax, cy), _mm_mul_ps(ay, cx));
  const __m128 w2 = _mm_sub_ps(_mm_mul_ps(bx, ay), _mm_mul_ps(by, ax));
  const __m128 zero = _mm_setzero_ps();
  // A zero edge function is recomputed in double by the scalar test, which may flip the sign
  // of the other two as well: check before rejecting.
  const __m128 on_edge = _mm_or_ps(_mm_or_ps(_mm_cmpeq_ps(u, zero), _mm_cmpeq_ps(w1, zero)), _mm_cmpeq_ps(w2, zero));
  // Inside: the smallest edge function >= 0 or the largest <= 0 (4 min/max and 2 compares
  // instead of 6 compares and 4 ands). min/max return their second operand when one is NaN, so
  // a lane with some but not all of u, w1, w2 NaN may pass here where the scalar test rejects
  // it; its det and t are NaN then, and the t range test below rejects it all the same. A lane
  // with all three NaN (padding) fails here.
  const __m128 lo = _mm_min_ps(_mm_min_ps(u, w1), w2), hi = _mm_max_ps(_mm_max_ps(u, w1), w2);
  const __m128 inside = _mm_or_ps(_mm_cmpge_ps(lo, zero), _mm_cmple_ps(hi, zero));
  // The common case, no lane inside nor on an edge, takes one test.
  if (_mm_movemask_ps(_mm_or_ps(inside, on_edge)) == 0) return 0;
  if (_mm_movemask_ps(on_edge) != 0) [[unlikely]] return -1;
  const __m128 det = _mm_add_ps(_mm_add_ps(u, w1), w2);
  const __m128 t_scaled = _mm_add_ps(_mm_add_ps(_mm_mul_ps(u, _mm_mul_ps(r.sz, az)), _mm_mul_ps(w1, _mm_mul_ps(r.sz, bz))),
                                     _mm_mul_ps(w2, _mm_mul_ps(r.sz, cz)));
  const __m128 inv_det = _mm_div_ps(_mm_set1_ps(1.0f), det);
  const __m128 t = _mm_mul_ps(t_scaled, inv_det);
  const __m128 ok = _mm_and_ps(_mm_and_ps(inside, _mm_cmpneq_ps(det, zero)),
                               _mm_and_ps(_mm_cmpge_ps(t, tmin), _mm_cmple_ps(t, tmax)));
  t_out = t;
  u_out = _mm_mul_ps(w1, inv_det);
  v_out = _mm_mul_ps(w2, inv_det);
  return _mm_movemask_ps(ok);
}

/// Fills \p blk with triangles [first, first + count) of \p tris (count <= 4); lane i gets
/// index ids[first + i] (the triangle's scene index), the unused lanes NaN vertices and kNoHit.
inline void fill_block(BvhTriangle4& blk, const BvhTriangle* tris, const uint32_t* ids, uint32_t first, uint32_t count) {
  for (uint32_t lane = 0; lane < 4; ++lane) {
    const bool used = lane < count;
    blk.index[lane] = used ? ids[first + lane] : kNoHit;
    for (int k = 0; k < 3; ++k)
      for (int a = 0; a < 3; ++a)
        blk.v[k][a][lane] = used ? tris[first + lane].v[3 * k + a] : std::numeric_limits<float>::quiet_NaN();
  }
}

/// The vertices of one lane of \p blk as intersect_watertight() takes them (v0, v1, v2).
inline void lane_vertices(const BvhTriangle4& blk, int lane, float (&v)[9]) {
  for (int k = 0; k < 3; ++k)
    for (int a = 0; a < 3; ++a) v[3 * k + a] = blk.v[k][a][lane];
}

namespace detail {
/// test_block()'s rare path (an edge function exactly zero in some lane): every lane through the
/// scalar test, which decides in double. Out of line and cold, so the traversal loops it is
/// instantiated in do not keep (or hoist to every leaf) the address arithmetic of its
/// permuted scalar loads.
template <class RuleOf, class OnHit>
[[gnu::noinline, gnu::cold]] bool test_block_scalar(const WatertightRay& wr, const BvhTriangle4& blk, float tmin,
                                                    const float& tmax, RuleOf& rule_of, OnHit& on_hit) {
  for (int lane = 0; lane < 4; ++lane) {
    const uint32_t i = blk.index[lane];
    if (i == kNoHit) continue;
    float v[9];
    lane_vertices(blk, lane, v);
    TriHit th;
    if (intersect_watertight(wr, v, tmin, tmax, th, rule_of(i)) && on_hit(i, lane, th.t, th.u, th.v)) return true;
  }
  return false;
}
}  // namespace detail

/// Tests one block of four triangles and calls on_hit(index, lane, t, u, v) for each hit lane in
/// lane order, as testing the lanes one by one with intersect_watertight() would: \p tmax is
/// read again before every scalar lane test, so a visitor that shrinks it (closest hit) sees the
/// same results as a scalar loop. on_hit returns true to stop; so does this function then.
/// The scalar fallback (edge functions exactly zero) reads the lane's own vertices; there
/// rule_of(index) gives the EdgeRule of that triangle.
template <class RuleOf, class OnHit>
SPECULA_ACCEL_INLINE bool test_block(const WatertightRay& wr, const WatertightRay4& wr4, const BvhTriangle4& blk, float tmin,
                       const float& tmax, RuleOf&& rule_of, OnHit&& on_hit) {
  __m128 t4, u4, v4;
  const int mask = intersect_watertight4(wr4, blk.v, _mm_set1_ps(tmin), _mm_set1_ps(tmax), t4, u4, v4);
  if (mask == 0) return false;
  if (mask > 0) {
    alignas(16) float ts[4], us[4], vs[4];
    _mm_store_ps(ts, t4);
    _mm_store_ps(us, u4);
    _mm_store_ps(vs, v4);
    for (int lane = 0; lane < 4; ++lane)
      if ((mask >> lane) & 1 && on_hit(blk.index[lane], lane, ts[lane], us[lane], vs[lane])) return true;
    return false;
  }
  // An edge function is exactly zero in some lane: the scalar test decides in double.
  return detail::test_block_scalar(wr, blk, tmin, tmax, rule_of, on_hit);
}

/// rule_of for test_block(): every triangle closed.
inline EdgeRule closed_edges(uint32_t) { return EdgeRule::Closed; }

/// Unit geometric normal of a triangle as its winding gives it; zero for degenerate triangles.
inline Vec3 geometric_normal(const float* v) {
  const Vec3 v0{v[0], v[1], v[2]}, v1{v[3], v[4], v[5]}, v2{v[6], v[7], v[8]};
  return normalize(cross(v1 - v0, v2 - v0));
}

/// geometric_normal() of one lane of a block (the vertices the hit was found on: no other
/// array, and no cache miss, to look them up in).
inline Vec3 geometric_normal(const BvhTriangle4& blk, int lane) {
  float v[9];
  lane_vertices(blk, lane, v);
  return geometric_normal(v);
}

}  // namespace specula::accel
