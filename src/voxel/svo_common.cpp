// Voxel tracer factory, hit mode names and synthetic voxel sets (owner: voxel tracers).
#include <algorithm>
#include <cmath>
#include <memory>
#include <string>
#include <utility>
#include <vector>

#include "specula/error.h"
#include "specula/svo.h"
#include "specula/voxel_grid.h"
#include "specula/voxel_tracer.h"
#include "voxel/voxel_brute.h"

namespace specula {

VoxelHitMode parse_voxel_hit_mode(const std::string& name) {
  if (name == "cubes") return VoxelHitMode::Cubes;
  if (name == "contours") return VoxelHitMode::Contours;
  throw Error("unknown voxel hit mode '" + name + "' (valid: cubes, contours)");
}

const char* to_string(VoxelHitMode mode) { return mode == VoxelHitMode::Cubes ? "cubes" : "contours"; }

std::unique_ptr<VoxelTracer> build_voxel_tracer(const std::string& kind, const VoxelSet& set,
                                                const VoxelTracerOptions& options) {
  if (kind == "svo") return std::make_unique<SparseVoxelOctree>(SparseVoxelOctree::build(set, options));
  if (kind == "grid") return std::make_unique<VoxelGridTracer>(VoxelGridTracer::build(set, options));
  if (kind == "voxel_brute") return std::make_unique<voxel::VoxelBruteTracer>(set, options);
  throw Error("unknown voxel tracer '" + kind + "' (valid: svo, grid, voxel_brute)");
}

VoxelSet make_sphere_shell_set(const VoxelGrid& grid, const Vec3& centre, float radius, uint32_t transparent_every) {
  VoxelSet set;
  set.grid = grid;
  const uint32_t res = grid.resolution();
  const double s = grid.voxel_size();
  const double h = 0.5 * std::sqrt(3.0) * s;
  const double r = radius;
  std::vector<std::pair<uint64_t, VoxelAttributes>> voxels;
  const auto centre_of = [&](uint32_t i, int axis) { return grid.origin[axis] + (static_cast<double>(i) + 0.5) * s; };
  const auto add = [&](uint32_t x, uint32_t y, uint32_t z) {
    const double px = centre_of(x, 0), py = centre_of(y, 1), pz = centre_of(z, 2);
    const double dx = px - centre.x, dy = py - centre.y, dz = pz - centre.z;
    const double dist = std::sqrt(dx * dx + dy * dy + dz * dz);
    if (std::fabs(dist - r) > h) return;
    VoxelAttributes a;
    if (dist > 0.0) a.normal = Vec3(static_cast<float>(dx / dist), static_cast<float>(dy / dist), static_cast<float>(dz / dist));
    const float off = static_cast<float>(r - dist);  // tangent plane through the sphere point on the radial line
    a.contour_lo = off - 0.1f * static_cast<float>(s);
    a.contour_hi = off + 0.1f * static_cast<float>(s);
    a.colour = Vec3(static_cast<float>(x) / static_cast<float>(res), static_cast<float>(y) / static_cast<float>(res),
                    static_cast<float>(z) / static_cast<float>(res));
    a.reflectivity = 0.25f;
    a.material = (x + y + z) % 3;
    voxels.emplace_back(morton_encode(x, y, z), a);
  };
  const auto index_of = [&](double w, int axis) {
    return static_cast<int64_t>(std::floor((w - grid.origin[axis]) / s));
  };
  for (uint32_t y = 0; y < res; ++y) {
    for (uint32_t x = 0; x < res; ++x) {
      const double dx = centre_of(x, 0) - centre.x, dy = centre_of(y, 1) - centre.y;
      const double q2 = dx * dx + dy * dy;
      const double outer = (r + h) * (r + h) - q2;
      if (outer < 0.0) continue;
      const double inner = std::max(0.0, r - h) * std::max(0.0, r - h) - q2;
      const double dmax = std::sqrt(outer), dmin = inner > 0.0 ? std::sqrt(inner) : 0.0;
      // Two z ranges (below and above the centre), widened by one voxel, merged when they meet.
      int64_t r0a = index_of(centre.z - dmax, 2) - 1, r0b = index_of(centre.z - dmin, 2) + 1;
      int64_t r1a = index_of(centre.z + dmin, 2) - 1, r1b = index_of(centre.z + dmax, 2) + 1;
      if (r1a <= r0b + 1) {
        r0b = r1b;
        r1a = 1;
        r1b = 0;
      }
      for (const auto& [za, zb] : {std::pair{r0a, r0b}, std::pair{r1a, r1b}}) {
        for (int64_t z = std::max<int64_t>(za, 0); z <= std::min<int64_t>(zb, res - 1); ++z) add(x, y, static_cast<uint32_t>(z));
      }
    }
  }
  std::sort(voxels.begin(), voxels.end(), [](const auto& a, const auto& b) { return a.first < b.first; });
  set.codes.reserve(voxels.size());
  set.attrs.reserve(voxels.size());
  for (size_t i = 0; i < voxels.size(); ++i) {
    set.codes.push_back(voxels[i].first);
    VoxelAttributes a = voxels[i].second;
    if (transparent_every > 0 && i % transparent_every == 0) a.transparency = 0.5f;
    set.attrs.push_back(a);
  }
  return set;
}

}  // namespace specula
