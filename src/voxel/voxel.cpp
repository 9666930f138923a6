/// \file voxel.cpp
/// The voxel grid of seed 000 and Morton codes.
#include "specula/voxel.h"

#include <algorithm>
#include <cmath>

namespace specula {

VoxelGrid VoxelGrid::around(const Aabb& scene_bounds, int depth) {
  VoxelGrid g;
  g.depth = depth;
  g.origin = scene_bounds.min;
  const Vec3 e = scene_bounds.extent();
  const float largest = std::max({e.x, e.y, e.z});
  // A flat or point-like scene still needs voxels of positive size.
  const float floor = std::max(1e-30f, 1e-6f * std::max({std::fabs(g.origin.x), std::fabs(g.origin.y),
                                                         std::fabs(g.origin.z)}));
  g.side = std::max(largest, floor);
  return g;
}

namespace {
/// Inverse of detail::spread3: gathers bits 0, 3, 6, ... of x into the low 21 bits.
uint32_t compact3(uint64_t x) {
  x &= 0x1249249249249249ull;
  x = (x ^ (x >> 2)) & 0x10C30C30C30C30C3ull;
  x = (x ^ (x >> 4)) & 0x100F00F00F00F00Full;
  x = (x ^ (x >> 8)) & 0x1F0000FF0000FFull;
  x = (x ^ (x >> 16)) & 0x1F00000000FFFFull;
  x = (x ^ (x >> 32)) & 0x1FFFFFull;
  return static_cast<uint32_t>(x);
}
}  // namespace

void morton_decode(uint64_t code, uint32_t& x, uint32_t& y, uint32_t& z) {
  x = compact3(code);
  y = compact3(code >> 1);
  z = compact3(code >> 2);
}

}  // namespace specula
