// Brute-force voxel tracer and the checks shared by the voxel tracers (owner: voxel tracers).
#include "voxel/voxel_brute.h"

#include <algorithm>
#include <cmath>
#include <string>
#include <utility>
#include <vector>

#include "specula/error.h"

namespace specula::voxel {

namespace {
bool finite_attrs(const VoxelAttributes& a) {
  return is_finite(a.normal) && is_finite(a.colour) && std::isfinite(a.reflectivity) && std::isfinite(a.transparency) &&
         std::isfinite(a.ior) && std::isfinite(a.contour_lo) && std::isfinite(a.contour_hi);
}
}  // namespace

void validate_set(const VoxelSet& set, const char* who) {
  const VoxelGrid& g = set.grid;
  const std::string w(who);
  if (g.depth < 0 || g.depth > kMaxVoxelDepth)
    throw Error(w + ": grid depth " + std::to_string(g.depth) + " out of range 0.." + std::to_string(kMaxVoxelDepth));
  if (!is_finite(g.origin) || !std::isfinite(g.side) || !(g.side > 0.0f) ||
      !std::isfinite(static_cast<float>(g.resolution()) / g.side))
    throw Error(w + ": grid origin must be finite and side positive and finite (side " + std::to_string(g.side) + ")");
  if (!set.attrs.empty() && set.attrs.size() != set.codes.size())
    throw Error(w + ": " + std::to_string(set.attrs.size()) + " attributes for " + std::to_string(set.codes.size()) +
                " voxels (must be equal, or no attributes)");
  // Prim ids of level-of-detail hits are voxel count + node index < kNoHit; nodes <= voxels * depth.
  if (set.codes.size() >= (size_t{1} << 31) / static_cast<size_t>(std::max(g.depth, 1)))
    throw Error(w + ": too many voxels (" + std::to_string(set.codes.size()) + ") for 32-bit voxel indices");
  const uint64_t limit = g.depth == 0 ? 1 : uint64_t{1} << (3 * g.depth);
  for (size_t i = 0; i < set.codes.size(); ++i) {
    if (set.codes[i] >= limit)
      throw Error(w + ": voxel " + std::to_string(i) + ": code " + std::to_string(set.codes[i]) +
                  " out of range for depth " + std::to_string(g.depth));
    if (i > 0 && set.codes[i] <= set.codes[i - 1])
      throw Error(w + ": voxel codes must be sorted ascending and unique (voxel " + std::to_string(i) + ")");
  }
  for (size_t i = 0; i < set.attrs.size(); ++i) {
    const VoxelAttributes& a = set.attrs[i];
    if (!finite_attrs(a) || !(a.contour_lo <= a.contour_hi))
      throw Error(w + ": voxel " + std::to_string(i) + ": non-finite attributes or contour_lo > contour_hi");
  }
}

std::vector<VoxelAttributes> attributes_or_default(const VoxelSet& set) {
  if (!set.attrs.empty()) return set.attrs;
  VoxelAttributes a;
  a.normal = {0.0f, 0.0f, 1.0f};
  // Slightly wider than the cube so rounding never lets a ray through a face.
  a.contour_hi = 0.5f * set.grid.voxel_size() * 1.0001f;
  a.contour_lo = -a.contour_hi;
  return std::vector<VoxelAttributes>(set.codes.size(), a);
}

VoxelBruteTracer::VoxelBruteTracer(const VoxelSet& set, const VoxelTracerOptions& options)
    : grid_(set.grid), attrs_(attributes_or_default(set)), mode_(options.mode) {
  validate_set(set, "voxel_brute");
  cells_.resize(set.codes.size());
  for (size_t i = 0; i < set.codes.size(); ++i) morton_decode(set.codes[i], cells_[i].c[0], cells_[i].c[1], cells_[i].c[2]);
}

void VoxelBruteTracer::intersect_skipping(std::span<const Ray> rays, std::span<const uint32_t> skip,
                                          std::span<Hit> hits, TraceStats* stats,
                                          std::span<const uint32_t> skip_prim) const {
  if (hits.size() < rays.size()) throw Error("voxel_brute: hits span smaller than rays span");
  if (!skip.empty() && skip.size() < rays.size()) throw Error("voxel_brute: skip span smaller than rays span");
  if (!skip_prim.empty() && skip_prim.size() < rays.size())
    throw Error("voxel_brute: skip_prim span smaller than rays span");
  TraceStats local;
  for (size_t r = 0; r < rays.size(); ++r) {
    Hit hit;
    const uint32_t skip_material = skip.empty() ? kNoHit : skip[r];
    const uint32_t skip_voxel = skip_prim.empty() ? kNoHit : skip_prim[r];
    ++local.rays;
    LocalRay lr;
    if (make_local_ray(rays[r], grid_, lr)) {
      local.triangles_tested += cells_.size();
      for (size_t i = 0; i < cells_.size(); ++i) {
        CellHit h;
        if (attrs_[i].material != skip_material && i != skip_voxel && hit_cell(lr, cells_[i].c, attrs_[i], mode_, h) && h.t < hit.t) {
          hit.t = h.t;
          hit.prim = static_cast<uint32_t>(i);
          hit.ng = h.n;
        }
      }
    }
    hits[r] = hit;
  }
  if (stats) *stats += local;
}

void VoxelBruteTracer::transmittance(std::span<const Ray> rays, std::span<Vec3> out, TraceStats* stats) const {
  if (out.size() < rays.size()) throw Error("voxel_brute: output span smaller than rays span");
  TraceStats local;
  std::vector<std::pair<float, uint32_t>> crossed;
  for (size_t r = 0; r < rays.size(); ++r) {
    ++local.rays;
    Vec3 tr{1.0f, 1.0f, 1.0f};
    LocalRay lr;
    if (make_local_ray(rays[r], grid_, lr)) {
      local.triangles_tested += cells_.size();
      crossed.clear();
      for (size_t i = 0; i < cells_.size(); ++i) {
        CellHit h;
        if (hit_cell(lr, cells_[i].c, attrs_[i], mode_, h)) crossed.emplace_back(h.t, static_cast<uint32_t>(i));
      }
      std::sort(crossed.begin(), crossed.end());
      for (const auto& [t, i] : crossed) {
        const float tp = attrs_[i].transparency;
        if (!(tp > 0.0f)) {
          tr = Vec3{};
          break;
        }
        tr *= Vec3(tp);
      }
    }
    out[r] = tr;
  }
  if (stats) *stats += local;
}

size_t VoxelBruteTracer::memory_bytes() const {
  return cells_.size() * sizeof(Cell) + attrs_.size() * sizeof(VoxelAttributes);
}

const VoxelAttributes& VoxelBruteTracer::attributes(uint32_t prim) const {
  if (prim >= attrs_.size())
    throw Error("voxel_brute: prim " + std::to_string(prim) + " out of range (" + std::to_string(attrs_.size()) + " voxels)");
  return attrs_[prim];
}

}  // namespace specula::voxel
