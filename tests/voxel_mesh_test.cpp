// The voxel tracers on real voxelized meshes (issue 3): for every shipped mesh, voxelized
// exactly, the octree and the grid return the same voxel, t and normal for 100k random rays,
// in cube and contour mode, and the brute force over the voxel list agrees on a subset.
#include <gtest/gtest.h>

#include <random>
#include <string>
#include <vector>

#include "ray_test_util.h"
#include "specula/load.h"
#include "specula/voxel_scene.h"
#include "specula/voxel_tracer.h"
#include "specula/voxelize.h"
#include "test_util.h"

namespace specula {
namespace {

/// Rays from around the grid towards random points inside it, rays starting inside the grid,
/// and axis-parallel rays (zero components) through the middle.
std::vector<Ray> mesh_rays(const VoxelGrid& g, size_t count, uint32_t seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<float> u01(0.0f, 1.0f), u(-1.0f, 1.0f);
  const Vec3 c = g.origin + Vec3(0.5f * g.side);
  const auto inside = [&] { return g.origin + Vec3(u01(rng), u01(rng), u01(rng)) * g.side; };
  std::vector<Ray> rays;
  rays.reserve(count);
  while (rays.size() < count) {
    const uint32_t kind = rng() % 8;
    if (kind < 5) {
      Vec3 d;
      do d = Vec3(u(rng), u(rng), u(rng));
      while (length(d) < 0.1f);
      const Vec3 org = c + normalize(d) * (1.5f * g.side);
      rays.push_back(test::make_ray(org, inside() - org));
    } else if (kind < 7) {
      Vec3 d;
      do d = Vec3(u(rng), u(rng), u(rng));
      while (length(d) < 0.1f);
      rays.push_back(test::make_ray(inside(), d));
    } else {
      Vec3 d{};
      d[static_cast<int>(rng() % 3)] = (rng() & 1) ? 1.0f : -1.0f;
      Vec3 org = inside();
      org = org - d * (2.0f * g.side) * std::abs(d.x + d.y + d.z);
      rays.push_back(test::make_ray(org, d));
    }
  }
  return rays;
}

class VoxelMesh : public ::testing::TestWithParam<const char*> {};

TEST_P(VoxelMesh, OctreeEqualsGridOnHundredThousandRays) {
  SPECULA_REQUIRE_MESH(path, GetParam());
  const Scene scene = load_scene(path.string());
  const std::vector<TriangleAttributes> attrs = triangle_attributes(scene);
  // A coarse, a middle and a fine depth (at 9 most of the grid's bricks are empty: the walk
  // crosses them in one step).
  for (const int depth : {4, 7, 9}) {
    VoxelizeOptions vo;
    vo.depth = depth;
    vo.bounds = scene.bounds();
    const VoxelSet set = voxelize(VoxelizeInput{scene.positions, scene.indices, attrs}, vo);
    ASSERT_GT(set.size(), depth > 4 ? 100u : 10u) << GetParam();
    const std::vector<Ray> rays = mesh_rays(set.grid, 100000, 7);
    const std::string where = std::string(GetParam()) + " depth " + std::to_string(depth);
    for (const VoxelHitMode mode : {VoxelHitMode::Cubes, VoxelHitMode::Contours}) {
      VoxelTracerOptions to;
      to.mode = mode;
      const auto svo = build_voxel_tracer("svo", set, to);
      const auto grid = build_voxel_tracer("grid", set, to);
      // Different records no tracer returns: a ray left unwritten shows as a difference.
      std::vector<Hit> a(rays.size(), test::unwritten_hit(0xFFFFFFF0u)), b(rays.size(), test::unwritten_hit(0xFFFFFFF1u));
      svo->intersect(rays, a);
      grid->intersect(rays, b);
      size_t hits = 0;
      for (size_t i = 0; i < rays.size(); ++i) {
        ASSERT_EQ(a[i].prim, b[i].prim) << where << " " << to_string(mode) << " ray " << i << ": "
                                        << test::describe(rays[i]);
        if (a[i].hit()) {
          ++hits;
          ASSERT_EQ(a[i].t, b[i].t) << where << " ray " << i;
          ASSERT_EQ(a[i].ng, b[i].ng) << where << " ray " << i;
        }
      }
      EXPECT_GT(hits, rays.size() / 20) << where << " " << to_string(mode);
      EXPECT_LT(hits, rays.size()) << where << " " << to_string(mode);
      // The brute force over the voxel list on a subset (it tests every voxel for every ray).
      const auto brute = build_voxel_tracer("voxel_brute", set, to);
      const std::span<const Ray> some(rays.data(), 300);
      std::vector<Hit> c(some.size());
      brute->intersect(some, c);
      for (size_t i = 0; i < some.size(); ++i) {
        ASSERT_EQ(c[i].prim, a[i].prim) << where << " brute, ray " << i;
        if (c[i].hit()) {
          ASSERT_EQ(c[i].t, a[i].t) << where << " brute, ray " << i;
        }
      }
    }
  }
}

INSTANTIATE_TEST_SUITE_P(Shared, VoxelMesh, ::testing::ValuesIn(test::kSharedMeshes), test::mesh_param_name);

}  // namespace
}  // namespace specula
