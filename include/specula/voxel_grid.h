/// \file voxel_grid.h
/// Voxel grid traced with the 3D DDA of Amanatides and Woo ("A Fast Voxel Traversal
/// Algorithm for Ray Tracing", Eurographics 1987; seed 001, sections 3.4-3.5): an AABB entry
/// for rays starting outside, then one voxel step at a time along the axis whose next boundary
/// is nearest. Boundary distances are computed directly from the integer planes (never
/// accumulated), so they equal the octree's bit for bit; it is the reference the octree is
/// tested against (same first voxel for every ray).
///
/// Storage is a brick grid: bricks of 8^3 voxels, a dense table over all bricks (4 bytes each:
/// the slot of an occupied brick, or none) and per occupied brick 512 occupancy bits (one cache
/// line, in Morton order) and the attribute index of its first voxel, so a voxel's attribute
/// index is that plus a popcount. Coarser blocks (64^3 voxels, 512^3, ...) have an occupancy
/// bit each. The walk crosses the largest empty block around its cell in one step, to the plane
/// where the ray leaves it (an exact plane distance like every other), so a ray through empty
/// space costs a few steps per level instead of one per voxel. Memory: the table,
/// 2^(3 depth - 7) bytes (64 MiB at depth 11, 512 MiB at depth 12), plus 68 bytes per occupied
/// brick (and the coarse bits, 1/16384 of the table); a build over
/// VoxelTracerOptions::max_grid_bytes is refused up front with the estimate.
#pragma once

#include <cstdint>
#include <span>
#include <string>
#include <vector>

#include "specula/voxel.h"
#include "specula/voxel_tracer.h"

namespace specula {

class VoxelGridTracer final : public VoxelTracer {
 public:
  VoxelGridTracer() = default;

  /// Builds over \p set (see SparseVoxelOctree::build for the attribute defaults). Throws
  /// specula::Error on an invalid set or when the grid would exceed options.max_grid_bytes.
  static VoxelGridTracer build(const VoxelSet& set, const VoxelTracerOptions& options = {});

  /// Bytes of the dense brick table at \p depth: the part of the grid's memory known before
  /// voxelizing (the occupied bricks add 68 bytes each).
  static uint64_t table_bytes(int depth);

  std::string name() const override { return "grid"; }
  void intersect_skipping(std::span<const Ray> rays, std::span<const uint32_t> skip_material, std::span<Hit> hits,
                          TraceStats* stats = nullptr,
                          std::span<const uint32_t> skip_prim = {}) const override;
  void transmittance(std::span<const Ray> rays, std::span<Vec3> out, TraceStats* stats = nullptr) const override;
  size_t memory_bytes() const override;

  const VoxelAttributes& attributes(uint32_t prim) const override;
  const VoxelGrid& grid() const override { return grid_; }
  size_t voxel_count() const override { return attrs_.size(); }
  VoxelHitMode hit_mode() const override { return mode_; }
  void set_hit_mode(VoxelHitMode mode) override { mode_ = mode; }

  /// Whether voxel (x, y, z) is occupied (false outside the grid).
  bool occupied(uint32_t x, uint32_t y, uint32_t z) const;

 private:
  friend class GridTraversal;
  /// Occupancy of one 8^3 brick: bit morton_encode(x & 7, y & 7, z & 7) of voxel (x, y, z).
  struct alignas(64) Brick {
    uint64_t bits[8];
  };
  static constexpr uint32_t kEmptyBrick = 0xFFFFFFFFu;
  VoxelGrid grid_;
  uint32_t bricks_per_axis_ = 0;
  std::vector<uint32_t> table_;  ///< per brick bx + n (by + n bz): its slot, or kEmptyBrick
  std::vector<Brick> bricks_;    ///< per slot (slots in Morton order of the bricks)
  std::vector<uint32_t> first_;  ///< per slot: attribute index of the brick's first voxel
  /// Occupancy of the blocks of 2^shift voxels per side, shift = 6, 9, ... while a level has
  /// more than one block per axis; coarsest first. Bit bx + n (by + n bz).
  struct Level {
    int shift;
    uint64_t per_axis;
    std::vector<uint64_t> bits;
  };
  std::vector<Level> levels_;
  std::vector<VoxelAttributes> attrs_;
  VoxelHitMode mode_ = VoxelHitMode::Cubes;
};

}  // namespace specula
