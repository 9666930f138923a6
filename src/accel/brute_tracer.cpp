#include "accel/brute_tracer.h"

#include <algorithm>
#include <limits>

#include "accel/watertight.h"
#include "specula/error.h"

namespace specula::accel {

BruteTracer::BruteTracer(const TriangleInput& input) {
  const std::vector<BvhTriangle> all = gather_triangles(input);
  const bool any_transparent =
      std::any_of(input.transmittance.begin(), input.transmittance.end(),
                  [](const Vec3& t) { return !is_opaque(t); });
  for (uint32_t i = 0; i < all.size(); ++i) {
    if (is_degenerate(all[i].vertex(0), all[i].vertex(1), all[i].vertex(2))) continue;
    tris_.push_back(all[i]);
    ids_.push_back(i);
    if (any_transparent) transmittance_.push_back(input.transmittance[i]);
  }
  groups_.resize((tris_.size() + 3) / 4);
  for (size_t g = 0; g < groups_.size(); ++g) {
    alignas(16) float lanes[3][3][4];
    for (int lane = 0; lane < 4; ++lane) {
      const size_t i = 4 * g + static_cast<size_t>(lane);
      for (int k = 0; k < 3; ++k)
        for (int a = 0; a < 3; ++a)
          lanes[k][a][lane] = i < tris_.size() ? tris_[i].v[3 * k + a] : std::numeric_limits<float>::quiet_NaN();
    }
    for (int k = 0; k < 3; ++k)
      for (int a = 0; a < 3; ++a) groups_[g].v[k][a] = _mm_load_ps(lanes[k][a]);
  }
}

namespace {

/// intersect_watertight() for four triangles at once: the very same float operations in the
/// same order per lane (SSE arithmetic is IEEE single precision like the scalar code), so the
/// results are bit-identical. Groups where an edge function is exactly zero in some lane (which
/// needs the double-precision fallback) are left to the scalar function. Returns a lane mask
/// of hits in [tmin, tmax] and their t, u, v; or -1 when the group must go scalar.
inline int intersect4(const WatertightRay& r, const __m128 (&v)[3][3], float tmin, float tmax, __m128& t_out,
                      __m128& u_out, __m128& v_out) {
  const __m128 ox = _mm_set1_ps(r.ox), oy = _mm_set1_ps(r.oy), oz = _mm_set1_ps(r.oz);
  const __m128 sx = _mm_set1_ps(r.sx), sy = _mm_set1_ps(r.sy), sz = _mm_set1_ps(r.sz);
  const __m128 az = _mm_sub_ps(v[0][r.kz], oz), bz = _mm_sub_ps(v[1][r.kz], oz), cz = _mm_sub_ps(v[2][r.kz], oz);
  const __m128 ax = _mm_sub_ps(_mm_sub_ps(v[0][r.kx], ox), _mm_mul_ps(sx, az));
  const __m128 ay = _mm_sub_ps(_mm_sub_ps(v[0][r.ky], oy), _mm_mul_ps(sy, az));
  const __m128 bx = _mm_sub_ps(_mm_sub_ps(v[1][r.kx], ox), _mm_mul_ps(sx, bz));
  const __m128 by = _mm_sub_ps(_mm_sub_ps(v[1][r.ky], oy), _mm_mul_ps(sy, bz));
  const __m128 cx = _mm_sub_ps(_mm_sub_ps(v[2][r.kx], ox), _mm_mul_ps(sx, cz));
  const __m128 cy = _mm_sub_ps(_mm_sub_ps(v[2][r.ky], oy), _mm_mul_ps(sy, cz));
  const __m128 u = _mm_sub_ps(_mm_mul_ps(cx, by), _mm_mul_ps(cy, bx));
  const __m128 w1 = _mm_sub_ps(_mm_mul_ps(ax, cy), _mm_mul_ps(ay, cx));
  const __m128 w2 = _mm_sub_ps(_mm_mul_ps(bx, ay), _mm_mul_ps(by, ax));
  const __m128 zero = _mm_setzero_ps();
  const __m128 nonneg = _mm_and_ps(_mm_and_ps(_mm_cmpge_ps(u, zero), _mm_cmpge_ps(w1, zero)), _mm_cmpge_ps(w2, zero));
  const __m128 nonpos = _mm_and_ps(_mm_and_ps(_mm_cmple_ps(u, zero), _mm_cmple_ps(w1, zero)), _mm_cmple_ps(w2, zero));
  const __m128 inside = _mm_or_ps(nonneg, nonpos);
  // A zero edge function is recomputed in double by the scalar test, which may flip the sign
  // of the other two as well: check before rejecting.
  const __m128 on_edge = _mm_or_ps(_mm_or_ps(_mm_cmpeq_ps(u, zero), _mm_cmpeq_ps(w1, zero)), _mm_cmpeq_ps(w2, zero));
  if (_mm_movemask_ps(on_edge) != 0) return -1;
  if (_mm_movemask_ps(inside) == 0) return 0;  // the common case: no lane inside
  const __m128 det = _mm_add_ps(_mm_add_ps(u, w1), w2);
  const __m128 t_scaled = _mm_add_ps(_mm_add_ps(_mm_mul_ps(u, _mm_mul_ps(sz, az)), _mm_mul_ps(w1, _mm_mul_ps(sz, bz))),
                                     _mm_mul_ps(w2, _mm_mul_ps(sz, cz)));
  const __m128 inv_det = _mm_div_ps(_mm_set1_ps(1.0f), det);
  const __m128 t = _mm_mul_ps(t_scaled, inv_det);
  const __m128 ok = _mm_and_ps(_mm_and_ps(inside, _mm_cmpneq_ps(det, zero)),
                               _mm_and_ps(_mm_cmpge_ps(t, _mm_set1_ps(tmin)), _mm_cmple_ps(t, _mm_set1_ps(tmax))));
  t_out = t;
  u_out = _mm_mul_ps(w1, inv_det);
  v_out = _mm_mul_ps(w2, inv_det);
  return _mm_movemask_ps(ok);
}

}  // namespace

void BruteTracer::intersect(std::span<const Ray> rays, std::span<Hit> hits, TraceStats* stats) const {
  if (hits.size() < rays.size()) throw Error("BruteTracer::intersect: hits span smaller than rays span");
  const uint32_t n = static_cast<uint32_t>(tris_.size());
  for (size_t r = 0; r < rays.size(); ++r) {
    const Ray& ray = rays[r];
    const WatertightRay wr(ray);
    Hit hit;
    hit.t = ray.tmax;
    TriHit th{};
    for (uint32_t g = 0; g < groups_.size(); ++g) {
      __m128 t4, u4, v4;
      const int mask = intersect4(wr, groups_[g].v, ray.tmin, hit.t, t4, u4, v4);
      if (mask == 0) continue;
      if (mask > 0) {
        // Same outcome as testing the lanes in order with t <= best: the smallest t wins,
        // ties go to the later lane.
        alignas(16) float ts[4], us[4], vs[4];
        _mm_store_ps(ts, t4);
        _mm_store_ps(us, u4);
        _mm_store_ps(vs, v4);
        for (int lane = 0; lane < 4; ++lane) {
          if ((mask >> lane) & 1 && ts[lane] <= hit.t) {
            hit.t = ts[lane];
            hit.u = us[lane];
            hit.v = vs[lane];
            hit.prim = 4 * g + static_cast<uint32_t>(lane);
          }
        }
        continue;
      }
      for (uint32_t i = 4 * g; i < std::min(n, 4 * g + 4); ++i) {
        if (intersect_watertight(wr, tris_[i].v, ray.tmin, hit.t, th)) {
          hit.t = th.t;
          hit.u = th.u;
          hit.v = th.v;
          hit.prim = i;
        }
      }
    }
    if (hit.hit()) {
      hit.ng = geometric_normal(tris_[hit.prim].v);
      hit.prim = ids_[hit.prim];
    } else {
      hit = Hit{};
    }
    hits[r] = hit;
  }
  if (stats) {
    stats->rays += rays.size();
    stats->nodes_visited += rays.size();
    stats->triangles_tested += rays.size() * static_cast<uint64_t>(n);
  }
}

void BruteTracer::transmittance(std::span<const Ray> rays, std::span<Vec3> out, TraceStats* stats) const {
  if (out.size() < rays.size()) throw Error("BruteTracer::transmittance: out span smaller than rays span");
  const uint32_t n = static_cast<uint32_t>(tris_.size());
  uint64_t tested = 0;
  for (size_t r = 0; r < rays.size(); ++r) {
    const Ray& ray = rays[r];
    const WatertightRay wr(ray);
    Vec3 tr{1.0f, 1.0f, 1.0f};
    TriHit th{};
    // Every triangle crossed in (tmin, tmax), in input order; stop at the first opaque one.
    const auto crossed = [&](uint32_t i) {
      if (transmittance_.empty() || is_opaque(transmittance_[i])) {
        tr = Vec3{};
        return true;
      }
      tr *= transmittance_[i];
      return false;
    };
    bool done = false;
    uint32_t g = 0;
    for (; g < groups_.size() && !done; ++g) {
      __m128 t4, u4, v4;
      const int mask = intersect4(wr, groups_[g].v, ray.tmin, ray.tmax, t4, u4, v4);
      if (mask == 0) continue;
      if (mask > 0) {
        alignas(16) float ts[4];
        _mm_store_ps(ts, t4);
        for (int lane = 0; lane < 4 && !done; ++lane)
          if ((mask >> lane) & 1 && ts[lane] > ray.tmin && ts[lane] < ray.tmax) done = crossed(4 * g + static_cast<uint32_t>(lane));
        continue;
      }
      for (uint32_t i = 4 * g; i < std::min(n, 4 * g + 4) && !done; ++i)
        if (intersect_watertight(wr, tris_[i].v, ray.tmin, ray.tmax, th) && th.t > ray.tmin && th.t < ray.tmax)
          done = crossed(i);
    }
    tested += std::min(n, 4 * g);
    out[r] = tr;
  }
  if (stats) {
    stats->rays += rays.size();
    stats->nodes_visited += rays.size();
    stats->triangles_tested += tested;
  }
}

size_t BruteTracer::memory_bytes() const {
  return tris_.size() * sizeof(BvhTriangle) + groups_.size() * sizeof(Group4) + ids_.size() * sizeof(uint32_t) + transmittance_.size() * sizeof(Vec3);
}

}  // namespace specula::accel
