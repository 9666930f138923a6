/// \file voxel_tracer.h
/// The interface shared by the tracers over a VoxelSet (sparse voxel octree, dense voxel grid,
/// brute force), so the integrator can shade voxel hits without knowing the structure.
///
/// Hit semantics (identical in every voxel tracer, so their results compare bit for bit):
/// - Rays are mapped to the grid's local frame (voxel (x, y, z) = [x, x+1] x [y, y+1] x [z, z+1])
///   once per ray; every boundary distance is computed as (plane - org) * (1 / dir) from the
///   exact integer plane, so all structures see the same numbers.
/// - A voxel is crossed when the ray's parameter interval inside its box,
///   [t_enter, t_exit] = [max(entry planes, tmin), min(exit planes, tmax)], has positive length
///   (t_enter < t_exit). A ray that only touches an edge or a corner, or lies in a face plane
///   while moving away, crosses nothing there. A direction component of +-0 (or one so small
///   that 1/d is not finite) does not move: on that axis the ray is inside voxel x exactly when
///   x <= org < x + 1 (half-open), so a ray running inside a face plane belongs to the voxel on
///   the plane's positive side. Crossed intervals of distinct voxels never overlap, so there are
///   no ties: the first hit is unique.
/// - Cubes: the hit is at t_enter. Normal: the outward normal of the face the ray entered
///   through (always against the ray); a ray starting inside the voxel (t_enter == tmin
///   without crossing a face) gets -sign(dir_k) e_k for the axis k of the largest |dir|
///   component (lowest axis on ties). Ties between entry faces (edges, corners) go to the
///   lowest axis.
/// - Contours: the slab lo <= dot(n, p - centre) <= hi of the voxel's attributes (n = normal)
///   is intersected with the ray; the hit is at t = max(t_enter, slab entry) when
///   t <= slab exit and t < t_exit (half-open on the exit side, so a hit on a shared face
///   belongs to the voxel being entered). Normal: the attribute normal as stored (not flipped
///   towards the ray, like triangle normals). Otherwise traversal continues behind the voxel.
/// - Hits at exactly tmax are misses; NaN / infinite rays, zero directions and tmin > tmax
///   miss (and are fully transmitted).
/// - Hit.prim is the voxel's index in the VoxelSet; for level-of-detail hits at inner octree
///   nodes it is set size + inner node index (see SparseVoxelOctree). u = v = 0.
/// - Transmittance: the product over the voxels the ray hits in (tmin, tmax) (every crossed
///   voxel in cube mode, every voxel whose contour slab is crossed in contour mode; each voxel
///   once) of Vec3(transparency); exactly 0 from the first voxel with transparency <= 0.
///   Multiplied in ray order.
#pragma once

#include <cstdint>
#include <span>
#include <memory>
#include <string>

#include "specula/tracer.h"
#include "specula/voxel.h"

namespace specula {

/// What a ray hits inside an occupied voxel: its whole cube, or its contour slab (seed 000).
enum class VoxelHitMode : uint8_t { Cubes, Contours };

/// Parses "cubes" / "contours"; throws specula::Error otherwise.
VoxelHitMode parse_voxel_hit_mode(const std::string& name);
const char* to_string(VoxelHitMode mode);

/// Options of every voxel tracer.
struct VoxelTracerOptions {
  VoxelHitMode mode = VoxelHitMode::Cubes;
  /// Level of detail (octree only): nodes at level lod are treated as leaves carrying their
  /// averaged attributes. 0 (or >= the grid depth) = full depth. Changing it needs no rebuild.
  int lod = 0;
  /// Build threads (octree attribute averaging); 0 = all hardware threads. Queries are
  /// single-threaded per call: callers parallelise over batches.
  int threads = 0;
  /// Most bytes the voxel grid may take: its brick table (4 bytes per 8^3 voxels, 512 MiB at
  /// depth 12) and 68 bytes per occupied brick (VoxelGridTracer::table_bytes).
  size_t max_grid_bytes = size_t{1} << 30;
};

/// A Tracer over voxels: adds what shading a voxel hit needs.
class VoxelTracer : public Tracer {
 public:
  /// Attributes of a hit's prim (a voxel index, or set size + inner node index for LOD hits).
  /// Throws specula::Error for an index out of range.
  virtual const VoxelAttributes& attributes(uint32_t prim) const = 0;
  /// The grid the voxels live in.
  virtual const VoxelGrid& grid() const = 0;
  /// Number of occupied voxels (the VoxelSet size).
  virtual size_t voxel_count() const = 0;
  virtual VoxelHitMode hit_mode() const = 0;
  virtual void set_hit_mode(VoxelHitMode mode) = 0;

  /// intersect() for rays travelling inside a medium made of voxels (seed 001's rule): ray i
  /// passes through every voxel whose attributes' material equals skip_material[i] and stops
  /// at the first voxel of another material; and through voxel skip_prim[i] (a Hit::prim: the
  /// voxel a secondary ray leaves, whose contour slab its origin may lie in). kNoHit (or an
  /// empty span) skips nothing.
  virtual void intersect_skipping(std::span<const Ray> rays, std::span<const uint32_t> skip_material,
                                  std::span<Hit> hits, TraceStats* stats = nullptr,
                                  std::span<const uint32_t> skip_prim = {}) const = 0;
  void intersect(std::span<const Ray> rays, std::span<Hit> hits, TraceStats* stats = nullptr) const override {
    intersect_skipping(rays, {}, hits, stats);
  }
};

/// Builds "svo", "grid" or "voxel_brute" over \p set (copies what it needs). Throws
/// specula::Error for an unknown kind or an invalid set (codes not sorted/unique or out of
/// range for the depth, attribute count not 0 or set size, non-finite attributes or grid).
std::unique_ptr<VoxelTracer> build_voxel_tracer(const std::string& kind, const VoxelSet& set,
                                                const VoxelTracerOptions& options = {});

/// Synthetic set for tests and benchmarks: the voxels of \p grid whose centre lies within
/// half a voxel diagonal of the sphere (centre, radius) surface, with radial unit normals,
/// contour planes tangent to the sphere (+-0.1 voxel) and colours varying with the position.
/// Every \p transparent_every th voxel (0 = none) gets transparency 0.5.
VoxelSet make_sphere_shell_set(const VoxelGrid& grid, const Vec3& centre, float radius,
                               uint32_t transparent_every = 0);

}  // namespace specula
