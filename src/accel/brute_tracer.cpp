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
  std::vector<BvhTriangle> tris;
  std::vector<uint32_t> ids;
  for (uint32_t i = 0; i < all.size(); ++i) {
    if (is_degenerate(all[i].vertex(0), all[i].vertex(1), all[i].vertex(2))) continue;
    tris.push_back(all[i]);
    ids.push_back(i);
  }
  if (any_transparent) transmittance_.assign(input.transmittance.begin(), input.transmittance.end());
  count_ = static_cast<uint32_t>(tris.size());
  groups_.resize((tris.size() + 3) / 4);
  for (size_t g = 0; g < groups_.size(); ++g) {
    const uint32_t first = static_cast<uint32_t>(4 * g);
    fill_block(groups_[g], tris.data(), ids.data(), first, std::min<uint32_t>(4, count_ - first));
  }
}


void BruteTracer::intersect(std::span<const Ray> rays, std::span<Hit> hits, TraceStats* stats) const {
  if (hits.size() < rays.size()) throw Error("BruteTracer::intersect: hits span smaller than rays span");
  const uint32_t n = count_;
  for (size_t r = 0; r < rays.size(); ++r) {
    const Ray& ray = rays[r];
    const WatertightRay wr(ray);
    Hit hit;
    hit.t = ray.tmax;
    const WatertightRay4 wr4(wr);
    const BvhTriangle4* best_blk = nullptr;
    int best_lane = 0;
    for (const BvhTriangle4& blk : groups_) {
      const auto closer = [&](uint32_t i, int lane, float t, float u, float v) {
        // The smallest t wins; ties go to the later triangle (as a scalar loop with t <= best).
        if (t <= hit.t) hit.t = t, hit.u = u, hit.v = v, hit.prim = i, best_blk = &blk, best_lane = lane;
        return false;
      };
      test_block(wr, wr4, blk, ray.tmin, hit.t, closed_edges, closer);
    }
    if (hit.hit()) {
      hit.ng = geometric_normal(*best_blk, best_lane);
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
  const uint32_t n = count_;
  uint64_t tested = 0;
  for (size_t r = 0; r < rays.size(); ++r) {
    const Ray& ray = rays[r];
    const WatertightRay wr(ray);
    Vec3 tr{1.0f, 1.0f, 1.0f};
    const WatertightRay4 wr4(wr);
    // Every triangle crossed in (tmin, tmax), in input order; stop at the first opaque one.
    // Transparent triangles are half-open: a ray exactly on an edge between two of them counts
    // the surface once (see EdgeRule).
    const auto rule_of = [&](uint32_t i) {
      return transmittance_.empty() || is_opaque(transmittance_[i]) ? EdgeRule::Closed : EdgeRule::HalfOpen;
    };
    const auto crossed = [&](uint32_t i, int, float t, float, float) {
      if (!(t > ray.tmin && t < ray.tmax)) return false;
      if (transmittance_.empty() || is_opaque(transmittance_[i])) {
        tr = Vec3{};
        return true;
      }
      tr *= transmittance_[i];
      return false;
    };
    uint32_t g = 0;
    while (g < groups_.size() && !test_block(wr, wr4, groups_[g], ray.tmin, ray.tmax, rule_of, crossed)) ++g;
    if (g < groups_.size()) ++g;
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
  return groups_.size() * sizeof(BvhTriangle4) + transmittance_.size() * sizeof(Vec3);
}

}  // namespace specula::accel
