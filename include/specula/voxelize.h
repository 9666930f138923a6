/// \file voxelize.h
/// Exact, multi-threaded, sparse surface voxelization (seed 000, chapter 1.4.1).
///
/// `voxelize` finds every voxel of VoxelGrid::around(bounds, depth) that a triangle really
/// intersects (closed boxes: touching counts), using exact integer triangle-box tests
/// (src/voxel/tri_box.h), and averages the triangles' attributes in each occupied voxel,
/// weighted by the area of each triangle's part inside the voxel (the triangle clipped to the
/// voxel). It also computes seed 000's two contour planes per voxel. Memory is proportional to
/// the occupied voxels; an upper bound is checked against a limit before anything big is
/// allocated. The result is the same, bit for bit, for any number of threads.
///
/// The voxelizer takes plain per-triangle data, never a Scene; `triangle_attributes` is the
/// small adapter that derives the per-triangle numbers from a Scene's materials.
/// See docs/voxels.md for the strategies, the grid, the averaging and the limits.
#pragma once

#include <cstdint>
#include <functional>
#include <optional>
#include <span>
#include <string>
#include <vector>

#include "specula/math.h"
#include "specula/scene.h"
#include "specula/voxel.h"

namespace specula {

/// Material numbers of one triangle, averaged into the voxels it touches.
struct TriangleAttributes {
  Vec3 colour{0.8f, 0.8f, 0.8f};
  float reflectivity = 0.0f;
  float transparency = 0.0f;
  float ior = 1.0f;
  uint32_t material = 0;  ///< passed through: a voxel keeps its largest triangle's material
};

/// Triangles to voxelize: triangle i uses positions[indices[3i + 0..2]] and attributes[i]
/// (attributes may be empty: every triangle then has TriangleAttributes{}).
struct VoxelizeInput {
  std::span<const Vec3> positions;
  std::span<const uint32_t> indices;
  std::span<const TriangleAttributes> attributes;
};

/// How the octree is walked and which of seed 000's tests decide occupancy.
enum class VoxelTraversal : uint8_t {
  /// Seed 000's algorithm: descend an implicit octree from the root; at every level each
  /// child is tested with the AABB test (the shared-centre trick: 2 comparisons per axis
  /// decide all 8 children), then the plane test and SAT as the strategy says.
  Octree,
  /// Fast: triangles are sorted into bricks of up to 32^3 voxels (descending the octree only to the
  /// brick level), then each triangle tests the leaf voxels of its bounding box inside the
  /// brick. Same voxels as Octree for the same tests (the tests are exact and monotone).
  Range,
};

/// Where the separating-axis test runs (the AABB and plane tests, when on, run at every level).
enum class SatLevel : uint8_t {
  Leaf,  ///< only on leaves (seed 000's faster choice)
  All,   ///< on every level of the descent (VoxelTraversal::Octree only)
};

struct VoxelStrategy {
  bool plane = true;            ///< triangle-plane vs box test
  bool sat = true;              ///< full separating-axis test (exact); off = inexact result
  SatLevel sat_at = SatLevel::Leaf;
  bool vertex_shortcut = true;  ///< a vertex inside the leaf voxel accepts it without SAT
  /// With attributes (the triangle is clipped to each voxel anyway): a voxel whose clipped
  /// part lies inside it, by a margin far above the clipping's rounding, is accepted without
  /// the tests. Exact (true overlap passes every strategy's tests); a pure speed-up.
  bool clip_shortcut = true;
  VoxelTraversal traversal = VoxelTraversal::Range;

  /// True when the result is the exact voxel set (the SAT runs).
  bool exact() const { return sat; }
  /// "aabb+plane+sat, sat at leaf, vertex shortcut, range".
  std::string describe() const;
};

struct VoxelizeOptions {
  int depth = 8;                 ///< 1 .. kMaxVoxelDepth; 2^depth voxels per axis
  VoxelStrategy strategy;
  int threads = 0;               ///< 0 = all hardware threads
  bool attributes = true;        ///< false: occupancy only (VoxelSet::attrs stays empty)
  /// Refuse (specula::Error, before allocating) when the memory estimate exceeds this many
  /// bytes. 0 = half the machine's physical memory; UINT64_MAX = no limit.
  uint64_t memory_limit = 0;
  /// Bounds the grid is built around; default: the bounding box of the triangles' vertices.
  /// Must contain every vertex. Pass Scene::bounds() to match other users of the scene's grid.
  std::optional<Aabb> bounds;
  /// Called with the fraction of the work done (0..1], bricks counted, as each brick's voxels
  /// join the result; from one thread at a time, so it need not be thread-safe. May be empty.
  std::function<void(double)> progress;
};

struct VoxelizeStats {
  double ms = 0.0;               ///< total wall time of voxelize()
  double prepare_ms = 0.0;       ///< validation, snapping to the lattice, memory estimate
  double bin_ms = 0.0;           ///< bricks of each triangle (tests for those in several), sort
  double voxel_ms = 0.0;         ///< leaf tests, clipping and averaging per brick, and appending
                                 ///< the bricks' outputs to the VoxelSet (done as they finish)
  uint64_t triangles = 0;
  uint64_t degenerate_triangles = 0;  ///< zero area (still voxelized as segments / points)
  uint64_t voxels = 0;
  uint64_t pairs = 0;            ///< (voxel, triangle) incidences found
  uint64_t bricks = 0;           ///< occupied bricks (up to 32^3 voxels each)
  uint64_t aabb_tests = 0;       ///< box-vs-box tests (children of octree nodes, brick ranges)
  uint64_t plane_tests = 0;
  uint64_t sat_tests = 0;        ///< 9-axis edge tests (the expensive part of the SAT)
  uint64_t vertex_hits = 0;      ///< leaves accepted by the vertex-inside shortcut
  uint64_t clip_accepts = 0;     ///< leaves accepted by the clipped-part shortcut (no tests run)
  uint64_t bytes = 0;            ///< size of the returned VoxelSet's arrays
  uint64_t estimate_bytes = 0;   ///< the up-front upper bound checked against the limit
  uint64_t memory_limit = 0;     ///< the limit that was applied
  int threads = 0;
};

/// Voxelizes \p input at options.depth. Throws specula::Error for bad input (an index out of
/// range, a non-finite vertex, no triangles, depth outside 1..kMaxVoxelDepth, an impossible
/// strategy) and when the memory estimate exceeds the limit (the message gives the estimate).
VoxelSet voxelize(const VoxelizeInput& input, const VoxelizeOptions& options, VoxelizeStats* stats = nullptr);

/// The adapter from a Scene: colour = diffuse, reflectivity, transparency, ior and material
/// id of each triangle's material.
std::vector<TriangleAttributes> triangle_attributes(const Scene& scene);

/// Upper bound, in bytes, of what voxelize() would allocate for \p input at \p options (the
/// number it compares with the limit: a quick bound when that is within the limit, else a
/// tighter one). Also validates the input like voxelize().
uint64_t voxelize_memory_estimate(const VoxelizeInput& input, const VoxelizeOptions& options);

/// Default memory limit: half the physical memory (4 GiB when it cannot be determined).
uint64_t default_voxelize_memory_limit();

}  // namespace specula
