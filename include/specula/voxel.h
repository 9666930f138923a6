/// \file voxel.h
/// Plain data shared by the voxel pipeline: the voxel grid seed 000 defines, the sparse set of
/// occupied voxels the voxelizer produces, and their leaf attributes. The voxelizer writes a
/// VoxelSet; the voxel grid (DDA) and the sparse voxel octree are built from one. Nothing here
/// knows about shading: attributes are averaged material numbers, carried as data.
#pragma once

#include <cstdint>
#include <vector>

#include "specula/math.h"

namespace specula {

/// Deepest voxel level supported: 2^kMaxVoxelDepth voxels per axis, 3 * depth bits of Morton
/// code (depth 21 = 63 bits). Memory limits are checked separately, before allocating.
inline constexpr int kMaxVoxelDepth = 21;

/// The grid of seed 000: the root cube's minimum corner is the minimum of the scene's bounding
/// box and its side is the largest extent of that box. At depth D it holds 2^D voxels per axis;
/// voxel (x, y, z) spans [origin + (x, y, z) s, origin + (x+1, y+1, z+1) s], s = side / 2^D.
/// Boxes are closed.
struct VoxelGrid {
  Vec3 origin;
  float side = 0.0f;
  int depth = 0;

  uint32_t resolution() const { return 1u << depth; }
  float voxel_size() const { return side / static_cast<float>(resolution()); }
  Aabb voxel_box(uint32_t x, uint32_t y, uint32_t z) const {
    const float s = voxel_size();
    const Vec3 lo = origin + Vec3{static_cast<float>(x), static_cast<float>(y), static_cast<float>(z)} * s;
    return Aabb{lo, lo + Vec3{s, s, s}};
  }
  Aabb bounds() const { return Aabb{origin, origin + Vec3{side, side, side}}; }

  /// The grid seed 000 puts around \p scene_bounds at \p depth. A flat or point-like box gets a
  /// side of at least a tiny positive value so voxel sizes are never zero.
  static VoxelGrid around(const Aabb& scene_bounds, int depth);
};

namespace detail {
/// Spreads the low 21 bits of v so that bit i lands on bit 3i.
constexpr uint64_t spread3(uint32_t v) {
  uint64_t x = v & 0x1FFFFFu;
  x = (x | x << 32) & 0x1F00000000FFFFull;
  x = (x | x << 16) & 0x1F0000FF0000FFull;
  x = (x | x << 8) & 0x100F00F00F00F00Full;
  x = (x | x << 4) & 0x10C30C30C30C30C3ull;
  x = (x | x << 2) & 0x1249249249249249ull;
  return x;
}
}  // namespace detail

/// Morton (Z-order) code of voxel (x, y, z): bit 3i of the code is bit i of x, 3i+1 of y,
/// 3i+2 of z. Sorting by code groups the eight children of every octree node together, in
/// child index order (child index = x_bit | y_bit << 1 | z_bit << 2). Inline: the voxelizer
/// encodes every binned triangle's brick (an out-of-line call was a sixth of its binning).
constexpr uint64_t morton_encode(uint32_t x, uint32_t y, uint32_t z) {
  return detail::spread3(x) | detail::spread3(y) << 1 | detail::spread3(z) << 2;
}
void morton_decode(uint64_t code, uint32_t& x, uint32_t& y, uint32_t& z);

/// Averaged attributes of one occupied voxel (area-weighted over the triangle parts inside it),
/// and seed 000's two contour planes: with n = normal and c = the voxel's centre, every point p
/// of the voxel's triangle parts satisfies contour_lo <= dot(n, p - c) <= contour_hi.
struct VoxelAttributes {
  Vec3 normal{0.0f, 0.0f, 1.0f};  ///< unit, area-weighted average of the triangles' normals
  Vec3 colour{0.8f, 0.8f, 0.8f};  ///< diffuse colour
  float reflectivity = 0.0f;
  float transparency = 0.0f;
  float ior = 1.0f;
  float contour_lo = 0.0f;
  float contour_hi = 0.0f;
  uint32_t material = 0;  ///< material of the triangle with the largest area in the voxel
};

/// The occupied voxels at one depth: codes sorted ascending and unique; attributes parallel to
/// codes (attrs[i] belongs to codes[i]) or empty when only occupancy was asked for.
struct VoxelSet {
  VoxelGrid grid;
  std::vector<uint64_t> codes;
  std::vector<VoxelAttributes> attrs;

  size_t size() const { return codes.size(); }
};

}  // namespace specula
