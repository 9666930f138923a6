/// \file voxel_scene.h
/// A scene's triangles as voxels behind the Tracer interface: voxelize (exactly, with the
/// averaged material numbers), then build the sparse voxel octree or the voxel grid. The
/// Whitted integrator shades the hits through VoxelTracer::attributes().
#pragma once

#include <cstdint>
#include <functional>
#include <memory>
#include <string>

#include "specula/scene.h"
#include "specula/voxel_tracer.h"

namespace specula {

struct SceneVoxelOptions {
  std::string kind = "svo";  ///< "svo", "grid" or "voxel_brute"
  int depth = 8;             ///< voxel depth: 2^depth voxels along the scene's largest extent
  VoxelTracerOptions tracer;  ///< hit mode, level of detail, grid memory limit
  int threads = 0;           ///< voxelizer and build threads; 0 = all
  /// The voxelizer's up-front memory limit (VoxelizeOptions::memory_limit): 0 = half the
  /// physical memory, UINT64_MAX = none.
  uint64_t memory_limit = 0;
  /// The voxelizer's progress callback (VoxelizeOptions::progress); may be empty.
  std::function<void(double)> progress;
};

struct SceneVoxelInfo {
  double voxelize_ms = 0.0;
  double build_ms = 0.0;
  size_t voxels = 0;
  size_t bytes = 0;  ///< the tracer's memory_bytes()
};

/// Voxelizes \p scene at options.depth (the grid of seed 000 around the scene's bounds) and
/// builds the requested voxel tracer. Throws specula::Error for an unknown kind, a scene
/// without triangles, or a depth whose memory estimate exceeds the limits.
std::unique_ptr<VoxelTracer> voxelize_scene(const Scene& scene, const SceneVoxelOptions& options,
                                            SceneVoxelInfo* info = nullptr);

/// The scene of a bare .svo file: no triangles, one default material, and a camera and a point
/// light framing the occupied voxels (add_default_camera_and_light over their bounds).
Scene svo_scene(const VoxelTracer& voxels, const std::string& name);

}  // namespace specula
