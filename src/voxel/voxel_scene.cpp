/// \file voxel_scene.cpp
/// Scene triangles -> voxelizer -> voxel tracer, and the stand-in scene of a bare .svo file.
#include "specula/voxel_scene.h"

#include "specula/error.h"
#include "specula/timer.h"
#include "specula/voxelize.h"

namespace specula {

std::unique_ptr<VoxelTracer> voxelize_scene(const Scene& scene, const SceneVoxelOptions& options,
                                            SceneVoxelInfo* info) {
  if (options.kind != "svo" && options.kind != "grid" && options.kind != "voxel_brute")
    throw Error("unknown voxel structure '" + options.kind + "' (valid: svo, grid, voxel_brute)");
  const std::vector<TriangleAttributes> attrs = triangle_attributes(scene);
  VoxelizeOptions v;
  v.depth = options.depth;
  v.threads = options.threads;
  v.memory_limit = options.memory_limit;
  v.progress = options.progress;
  v.bounds = scene.bounds();  // seed 000's grid around the whole scene
  VoxelizeStats stats;
  const VoxelSet set = voxelize(VoxelizeInput{scene.positions, scene.indices, attrs}, v, &stats);
  const Timer timer;
  VoxelTracerOptions t = options.tracer;
  t.threads = options.threads;
  std::unique_ptr<VoxelTracer> tracer = build_voxel_tracer(options.kind, set, t);
  if (info) {
    info->voxelize_ms = stats.ms;
    info->build_ms = timer.ms();
    info->voxels = set.size();
    info->bytes = tracer->memory_bytes();
  }
  return tracer;
}

Scene svo_scene(const VoxelTracer& voxels, const std::string& name) {
  Scene scene;
  scene.name = name;
  // No triangles: two corner vertices only give the scene its bounds (for the framing camera).
  const Aabb b = voxels.grid().bounds();
  scene.positions = {b.min, b.max};
  add_default_camera_and_light(scene);
  return scene;
}

}  // namespace specula
