#include "accel/brute_tracer.h"

#include <algorithm>

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
}

void BruteTracer::intersect(std::span<const Ray> rays, std::span<Hit> hits, TraceStats* stats) const {
  if (hits.size() < rays.size()) throw Error("BruteTracer::intersect: hits span smaller than rays span");
  const uint32_t n = static_cast<uint32_t>(tris_.size());
  for (size_t r = 0; r < rays.size(); ++r) {
    const Ray& ray = rays[r];
    const WatertightRay wr(ray);
    Hit hit;
    hit.t = ray.tmax;
    TriHit th{};
    for (uint32_t i = 0; i < n; ++i) {
      if (intersect_watertight(wr, tris_[i].v, ray.tmin, hit.t, th)) {
        hit.t = th.t;
        hit.u = th.u;
        hit.v = th.v;
        hit.prim = i;
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
    for (uint32_t i = 0; i < n; ++i) {
      ++tested;
      if (intersect_watertight(wr, tris_[i].v, ray.tmin, ray.tmax, th) &&
          th.t > ray.tmin && th.t < ray.tmax) {
        if (transmittance_.empty() || is_opaque(transmittance_[i])) {
          tr = Vec3{};
          break;
        }
        tr *= transmittance_[i];
      }
    }
    out[r] = tr;
  }
  if (stats) {
    stats->rays += rays.size();
    stats->nodes_visited += rays.size();
    stats->triangles_tested += tested;
  }
}

size_t BruteTracer::memory_bytes() const {
  return tris_.size() * sizeof(BvhTriangle) + ids_.size() * sizeof(uint32_t) + transmittance_.size() * sizeof(Vec3);
}

}  // namespace specula::accel
