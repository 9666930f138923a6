// Dense voxel grid with Amanatides-Woo DDA traversal (owner: voxel tracers).
//
// Entry (seed 001, section 3.5): the ray is clipped to the grid's box first. The start cell is
// estimated from the entry point and then corrected against the exact plane distances, so that
// on every axis entry <= t_start < exit holds with the same numbers the kernel uses (the
// seed's "random misses" came from trusting floor(o + t d) alone). Stepping (section 3.4)
// recomputes each next boundary directly from its integer plane instead of accumulating a
// t-delta, which keeps the distances bit-identical to the octree's.
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <span>
#include <string>

#include "specula/error.h"
#include "specula/voxel_grid.h"
#include "voxel/voxel_brute.h"

namespace specula {

using voxel::CellHit;
using voxel::LocalRay;

uint64_t VoxelGridTracer::bitmask_bytes(int depth) {
  const uint64_t bits = uint64_t{1} << (3 * std::clamp(depth, 0, kMaxVoxelDepth));
  return (bits + 63) / 64 * 8;
}

VoxelGridTracer VoxelGridTracer::build(const VoxelSet& set, const VoxelTracerOptions& options) {
  voxel::validate_set(set, "grid");
  const uint64_t bytes = bitmask_bytes(set.grid.depth);
  if (bytes > options.max_grid_bytes) {
    char msg[320];
    std::snprintf(msg, sizeof msg,
                  "grid: a dense bitmask at depth %d (%u^3 voxels) needs %.2f GiB, over the limit of %.2f GiB "
                  "(VoxelTracerOptions::max_grid_bytes); use the SVO or a smaller depth",
                  set.grid.depth, set.grid.resolution(), static_cast<double>(bytes) / 1073741824.0,
                  static_cast<double>(options.max_grid_bytes) / 1073741824.0);
    throw Error(msg);
  }
  VoxelGridTracer g;
  g.grid_ = set.grid;
  g.mode_ = options.mode;
  g.bits_.assign(bytes / 8, 0);
  const uint64_t res = set.grid.resolution();
  for (const uint64_t code : set.codes) {
    uint32_t x, y, z;
    morton_decode(code, x, y, z);
    const uint64_t bit = x + res * (y + res * z);
    g.bits_[bit >> 6] |= uint64_t{1} << (bit & 63);
  }
  g.codes_ = set.codes;
  g.attrs_ = voxel::attributes_or_default(set);
  return g;
}

bool VoxelGridTracer::occupied(uint32_t x, uint32_t y, uint32_t z) const {
  const uint64_t res = grid_.resolution();
  if (x >= res || y >= res || z >= res || bits_.empty()) return false;
  const uint64_t bit = x + res * (y + res * z);
  return (bits_[bit >> 6] >> (bit & 63)) & 1u;
}

size_t VoxelGridTracer::memory_bytes() const {
  return bits_.size() * sizeof(uint64_t) + codes_.size() * sizeof(uint64_t) + attrs_.size() * sizeof(VoxelAttributes);
}

const VoxelAttributes& VoxelGridTracer::attributes(uint32_t prim) const {
  if (prim >= attrs_.size())
    throw Error("grid: prim " + std::to_string(prim) + " out of range (" + std::to_string(attrs_.size()) + " voxels)");
  return attrs_[prim];
}

class GridTraversal {
 public:
  /// Visits the occupied voxels the ray crosses, in ray order; leaf(lr, cell, attrs, index)
  /// returns true to stop.
  template <bool kStats, class Leaf>
  static void walk(const VoxelGridTracer& g, const Ray& ray, TraceStats& stats, Leaf&& leaf) {
    if constexpr (kStats) ++stats.rays;
    LocalRay r;
    if (g.codes_.empty() || !voxel::make_local_ray(ray, g.grid_, r)) return;
    const uint32_t res = g.grid_.resolution();
    const float fres = static_cast<float>(res);
    const auto plane_t = [&r](uint32_t plane, int i) { return (static_cast<float>(plane) - r.o[i]) * r.inv[i]; };

    // Clip to the grid box.
    float t0[3], t1[3];
    for (int i = 0; i < 3; ++i) {
      if ((r.fixed >> i) & 1u) {
        if (!(0.0f <= r.o[i] && r.o[i] < fres)) return;
        t0[i] = -kInf;
        t1[i] = kInf;
      } else {
        const bool neg = (r.mirror >> i) & 1u;
        t0[i] = plane_t(neg ? res : 0u, i);
        t1[i] = plane_t(neg ? 0u : res, i);
      }
    }
    const float tstart = std::max(std::max(t0[0], t0[1]), std::max(t0[2], r.tmin));
    if (!(tstart < std::min(std::min(t1[0], t1[1]), std::min(t1[2], r.tmax)))) return;

    // Start cell: on every moving axis entry plane <= tstart < exit plane (exact distances).
    uint32_t c[3];
    float tprev[3], tnext[3];
    for (int i = 0; i < 3; ++i) {
      if ((r.fixed >> i) & 1u) {
        c[i] = static_cast<uint32_t>(std::floor(r.o[i]));
        tprev[i] = -kInf;
        tnext[i] = kInf;
        continue;
      }
      const double est = std::floor(static_cast<double>(r.o[i]) + static_cast<double>(tstart) * static_cast<double>(r.d[i]));
      uint32_t ci = static_cast<uint32_t>(std::clamp(est, 0.0, static_cast<double>(res - 1)));
      if (!((r.mirror >> i) & 1u)) {
        while (ci > 0 && plane_t(ci, i) > tstart) --ci;
        while (ci + 1 < res && plane_t(ci + 1, i) <= tstart) ++ci;
        tprev[i] = plane_t(ci, i);
        tnext[i] = plane_t(ci + 1, i);
      } else {
        while (ci + 1 < res && plane_t(ci + 1, i) > tstart) ++ci;
        while (ci > 0 && plane_t(ci, i) <= tstart) --ci;
        tprev[i] = plane_t(ci + 1, i);
        tnext[i] = plane_t(ci, i);
      }
      c[i] = ci;
    }

    const uint64_t* bits = g.bits_.data();
    const uint64_t res64 = res;
    for (;;) {
      if constexpr (kStats) ++stats.nodes_visited;
      const uint64_t bit = c[0] + res64 * (c[1] + res64 * c[2]);
      if ((bits[bit >> 6] >> (bit & 63)) & 1u) {
        const float te = std::max(std::max(tprev[0], tprev[1]), std::max(tprev[2], r.tmin));
        const float tx = std::min(std::min(tnext[0], tnext[1]), std::min(tnext[2], r.tmax));
        if (te < tx) {
          if constexpr (kStats) ++stats.triangles_tested;
          const uint64_t code = morton_encode(c[0], c[1], c[2]);
          const auto it = std::lower_bound(g.codes_.begin(), g.codes_.end(), code);
          const uint32_t index = static_cast<uint32_t>(it - g.codes_.begin());
          if (leaf(r, c, g.attrs_[index], index)) return;
        }
      }
      int k = tnext[0] <= tnext[1] ? 0 : 1;
      if (tnext[2] < tnext[k]) k = 2;
      if (tnext[k] >= r.tmax) return;
      if ((r.mirror >> k) & 1u) {
        if (c[k] == 0) return;
        --c[k];
        tprev[k] = tnext[k];
        tnext[k] = plane_t(c[k], k);
      } else {
        if (c[k] + 1 >= res) return;
        ++c[k];
        tprev[k] = tnext[k];
        tnext[k] = plane_t(c[k] + 1, k);
      }
    }
  }
};

void VoxelGridTracer::intersect_skipping(std::span<const Ray> rays, std::span<const uint32_t> skip,
                                         std::span<Hit> hits, TraceStats* stats,
                                         std::span<const uint32_t> skip_prim) const {
  if (hits.size() < rays.size()) throw Error("grid: hits span smaller than rays span");
  if (!skip.empty() && skip.size() < rays.size()) throw Error("grid: skip span smaller than rays span");
  if (!skip_prim.empty() && skip_prim.size() < rays.size()) throw Error("grid: skip_prim span smaller than rays span");
  TraceStats local;
  for (size_t i = 0; i < rays.size(); ++i) {
    Hit hit;
    const uint32_t skip_material = skip.empty() ? kNoHit : skip[i];
    const uint32_t skip_voxel = skip_prim.empty() ? kNoHit : skip_prim[i];
    const auto visit = [&](const LocalRay& r, const uint32_t* cell, const VoxelAttributes& attrs, uint32_t prim) {
      CellHit h;
      if (attrs.material == skip_material || prim == skip_voxel || !voxel::hit_cell(r, cell, attrs, mode_, h)) return false;
      hit.t = h.t;
      hit.prim = prim;
      hit.ng = h.n;
      return true;
    };
    if (stats) GridTraversal::walk<true>(*this, rays[i], local, visit);
    else GridTraversal::walk<false>(*this, rays[i], local, visit);
    hits[i] = hit;
  }
  if (stats) *stats += local;
}

void VoxelGridTracer::transmittance(std::span<const Ray> rays, std::span<Vec3> out, TraceStats* stats) const {
  if (out.size() < rays.size()) throw Error("grid: output span smaller than rays span");
  TraceStats local;
  for (size_t i = 0; i < rays.size(); ++i) {
    Vec3 tr{1.0f, 1.0f, 1.0f};
    const auto visit = [&](const LocalRay& r, const uint32_t* cell, const VoxelAttributes& attrs, uint32_t) {
      CellHit h;
      if (!voxel::hit_cell(r, cell, attrs, mode_, h)) return false;
      if (!(attrs.transparency > 0.0f)) {
        tr = Vec3{};
        return true;
      }
      tr *= Vec3(attrs.transparency);
      return false;
    };
    if (stats) GridTraversal::walk<true>(*this, rays[i], local, visit);
    else GridTraversal::walk<false>(*this, rays[i], local, visit);
    out[i] = tr;
  }
  if (stats) *stats += local;
}

}  // namespace specula
