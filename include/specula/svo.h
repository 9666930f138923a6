/// \file svo.h
/// Sparse voxel octree (seed 000, chapter 1.4): a flat node array in breadth-first order
/// (level 0 = the root, then every node of level 1 in Morton order, ...), each node a child
/// mask and the index of its first child, with the existing children stored contiguously in
/// child index order (child k is at first_child + popcount(mask & ((1 << k) - 1))). The
/// children of the nodes of level depth - 1 are the voxels themselves: their first_child
/// indexes the leaf attribute array, which is in VoxelSet (Morton) order, so a leaf's index is
/// its voxel index. Every inner node also carries averaged attributes (level of detail).
///
/// Traversal: the parametric algorithm of Revelles et al. ("An Efficient Parametric Algorithm
/// for Octree Traversal", WSCG 2000) as seed 000 extends it: per node the entry / exit
/// distances of the three slab pairs and of the three mid planes; negative directions are
/// mirrored (child index xor the mirror mask) and the next child is chosen by the plane
/// crossed first. A fixed stack of one frame per level (depth <= 21). Hit semantics are
/// those of voxel_tracer.h, identical to the voxel grid's and the brute-force tracer's.
///
/// Memory: 8 bytes per node plus 48 bytes of attributes per voxel and per inner node; nodes
/// are O(voxels * depth) in the worst case (scattered voxels), ~voxels / 3 for surfaces.
#pragma once

#include <cstdint>
#include <memory>
#include <new>
#include <span>
#include <string>
#include <utility>
#include <vector>

#include "specula/voxel.h"
#include "specula/voxel_tracer.h"

namespace specula {

class Timer;

/// One octree node: 8 bytes.
struct SvoNode {
  uint32_t first_child = 0;  ///< node index, or leaf (voxel) index for nodes of level depth - 1
  uint32_t mask = 0;         ///< bit k set: child k exists (k = x | y << 1 | z << 2); bits 8+ zero
};

/// A std::allocator whose value-initialising construct() does nothing: a resize() leaves the
/// new elements unwritten (for arrays that are written in full right after, in parallel, so
/// their pages are first touched there and never zero-filled). The element types used with it
/// are implicit-lifetime aggregates.
template <class T>
struct UninitAllocator : std::allocator<T> {
  template <class U>
  struct rebind {
    using other = UninitAllocator<U>;
  };
  UninitAllocator() = default;
  template <class U>
  explicit UninitAllocator(const UninitAllocator<U>& /*other*/) noexcept {}
  template <class U>
  void construct(U* /*p*/) noexcept {}
  template <class U, class... Args>
  void construct(U* p, Args&&... args) {
    ::new (static_cast<void*>(p)) U(std::forward<Args>(args)...);
  }
};

/// Figures of a built or loaded octree.
struct SvoInfo {
  double build_ms = 0.0;
  size_t nodes = 0;
  size_t voxels = 0;
  size_t bytes = 0;                  ///< memory_bytes()
  double node_bytes_per_voxel = 0;   ///< structure only (nodes * 8 / voxels)
  double bytes_per_voxel = 0;        ///< everything (nodes + leaf and inner attributes)
};

class SparseVoxelOctree final : public VoxelTracer {
 public:
  SparseVoxelOctree() = default;

  /// Builds from \p set (codes sorted unique; attributes empty or parallel to codes). A set
  /// without attributes gets default ones whose contour slab covers the whole cube, so contour
  /// mode then hits the cubes. Throws specula::Error on an invalid set.
  static SparseVoxelOctree build(const VoxelSet& set, const VoxelTracerOptions& options = {},
                                 SvoInfo* info = nullptr);
  /// The same, taking the set's attribute array instead of copying it (set.attrs is left
  /// empty; the codes stay): saves a copy as large as the attributes (172 MiB at depth 10).
  static SparseVoxelOctree build(VoxelSet&& set, const VoxelTracerOptions& options = {}, SvoInfo* info = nullptr);

  std::string name() const override { return "svo"; }
  void intersect_skipping(std::span<const Ray> rays, std::span<const uint32_t> skip_material, std::span<Hit> hits,
                          TraceStats* stats = nullptr,
                          std::span<const uint32_t> skip_prim = {}) const override;
  void transmittance(std::span<const Ray> rays, std::span<Vec3> out, TraceStats* stats = nullptr) const override;
  size_t memory_bytes() const override;

  const VoxelAttributes& attributes(uint32_t prim) const override;
  const VoxelGrid& grid() const override { return grid_; }
  size_t voxel_count() const override { return leaf_attrs_.size(); }
  VoxelHitMode hit_mode() const override { return mode_; }
  void set_hit_mode(VoxelHitMode mode) override { mode_ = mode; }

  /// Level of detail (see VoxelTracerOptions::lod); throws for lod < 0.
  void set_lod(int lod);
  int lod() const { return lod_; }

  std::span<const SvoNode> nodes() const { return nodes_; }
  std::span<const VoxelAttributes> leaf_attributes() const { return leaf_attrs_; }
  std::span<const VoxelAttributes> inner_attributes() const { return inner_attrs_; }
  /// First node index of each level 0..depth (the last entry = node count).
  std::span<const uint32_t> level_offsets() const { return level_offsets_; }
  SvoInfo info() const;

  /// The set at \p level (0..depth): codes of the occupied nodes of that level, attributes the
  /// nodes' averaged ones (the leaves' at level == depth), grid depth = level. Building an
  /// octree from it and tracing with lod 0 equals tracing this one with lod = level.
  VoxelSet level_set(int level) const;
  /// The set this octree was built from (codes recovered from the tree).
  VoxelSet to_voxel_set() const { return level_set(grid_.depth); }

 private:
  friend class SvoTraversal;
  friend SparseVoxelOctree svo_from_bytes(std::span<const uint8_t>, const std::string&, const VoxelTracerOptions&);
  /// Checks the node array (BFS layout, first_child == running child count, masks) and fills
  /// level_offsets_; returns an empty string or what is wrong.
  std::string check_structure();
  /// build(); takes *steal as the leaf attributes when given (the caller validated them).
  static SparseVoxelOctree build_from(const VoxelSet& set, std::vector<VoxelAttributes>* steal,
                                      const VoxelTracerOptions& options, SvoInfo* info, const Timer& timer);

  VoxelGrid grid_;
  std::vector<SvoNode, UninitAllocator<SvoNode>> nodes_;
  std::vector<VoxelAttributes> leaf_attrs_;
  std::vector<VoxelAttributes, UninitAllocator<VoxelAttributes>> inner_attrs_;  ///< parallel to nodes_
  std::vector<uint32_t> level_offsets_;
  VoxelHitMode mode_ = VoxelHitMode::Cubes;
  int lod_ = 0;
};

/// .svo files (docs/svo-format.md): header (magic "SPECSVO\0", version, grid, counts, FNV-1a 64
/// checksum), then nodes, leaf attributes and inner attributes, all little-endian.
/// Writes atomically (temporary file + rename); throws specula::Error.
void write_svo(const std::string& path, const SparseVoxelOctree& svo);
/// Reads and validates a .svo file: sizes are checked against the file size before anything
/// is allocated, then the checksum, the tree structure and the attribute values. Throws
/// specula::Error naming the file and the problem.
SparseVoxelOctree read_svo(const std::string& path, const VoxelTracerOptions& options = {});
/// The in-memory forms of the two above (\p name is used in error messages).
std::vector<uint8_t> svo_to_bytes(const SparseVoxelOctree& svo);
SparseVoxelOctree svo_from_bytes(std::span<const uint8_t> bytes, const std::string& name,
                                 const VoxelTracerOptions& options = {});

}  // namespace specula
