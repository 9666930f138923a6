/// \file voxel_grid.h
/// Dense voxel grid traced with the 3D DDA of Amanatides and Woo ("A Fast Voxel Traversal
/// Algorithm for Ray Tracing", Eurographics 1987; seed 001, sections 3.4-3.5): one occupancy
/// bit per voxel, an AABB entry for rays starting outside, then one voxel step at a time
/// along the axis whose next boundary is nearest. Boundary distances are computed directly
/// from the integer planes (never accumulated), so they equal the octree's bit for bit; it is
/// the reference the octree is tested against (same first voxel for every ray). Occupied
/// voxels are mapped to their attribute index by binary search over the sorted codes.
///
/// The bitmask needs 2^(3 depth) / 8 bytes; a build over VoxelTracerOptions::max_grid_bytes
/// is refused up front with the estimate.
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
  /// specula::Error on an invalid set or when the bitmask would exceed options.max_grid_bytes.
  static VoxelGridTracer build(const VoxelSet& set, const VoxelTracerOptions& options = {});

  /// Bytes of the dense bitmask at \p depth.
  static uint64_t bitmask_bytes(int depth);

  std::string name() const override { return "grid"; }
  void intersect_skipping(std::span<const Ray> rays, std::span<const uint32_t> skip_material, std::span<Hit> hits,
                          TraceStats* stats = nullptr,
                          std::span<const uint32_t> skip_prim = {}) const override;
  void transmittance(std::span<const Ray> rays, std::span<Vec3> out, TraceStats* stats = nullptr) const override;
  size_t memory_bytes() const override;

  const VoxelAttributes& attributes(uint32_t prim) const override;
  const VoxelGrid& grid() const override { return grid_; }
  size_t voxel_count() const override { return codes_.size(); }
  VoxelHitMode hit_mode() const override { return mode_; }
  void set_hit_mode(VoxelHitMode mode) override { mode_ = mode; }

  /// Whether voxel (x, y, z) is occupied (false outside the grid).
  bool occupied(uint32_t x, uint32_t y, uint32_t z) const;

 private:
  friend class GridTraversal;
  VoxelGrid grid_;
  std::vector<uint64_t> bits_;  ///< bit x + res (y + res z)
  std::vector<uint64_t> codes_;
  std::vector<VoxelAttributes> attrs_;
  VoxelHitMode mode_ = VoxelHitMode::Cubes;
};

}  // namespace specula
