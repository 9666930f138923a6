// Voxel grid (DDA) tests: memory refusal, AABB entry, start cells, half-open face planes,
// agreement with the brute force. Owner: voxel tracers.
#include <gtest/gtest.h>

#include <algorithm>
#include <random>
#include <string>
#include <vector>

#include "specula/error.h"
#include "specula/voxel_grid.h"
#include "voxel/voxel_brute.h"
#include "ray_test_util.h"

namespace specula {
namespace {

using test::make_ray;
using test::trace1;

VoxelSet cube_set(int depth, std::initializer_list<std::array<uint32_t, 3>> cells) {
  VoxelSet set;
  set.grid = VoxelGrid{Vec3{0.0f, 0.0f, 0.0f}, static_cast<float>(1u << depth), depth};  // voxel side 1
  for (const auto& c : cells) set.codes.push_back(morton_encode(c[0], c[1], c[2]));
  std::sort(set.codes.begin(), set.codes.end());
  return set;
}

TEST(VoxelGrid, RefusesHugeBitmaskUpFront) {
  VoxelSet set;
  set.grid = VoxelGrid{Vec3{}, 1.0f, 12};
  set.codes = {5};
  try {
    VoxelGridTracer::build(set);
    FAIL() << "depth 12 must be refused by default";
  } catch (const Error& e) {
    const std::string msg = e.what();
    EXPECT_NE(msg.find("depth 12"), std::string::npos) << msg;
    EXPECT_NE(msg.find("8.00 GiB"), std::string::npos) << msg;
  }
  EXPECT_EQ(VoxelGridTracer::bitmask_bytes(11), uint64_t{1} << 30);
  VoxelTracerOptions small;
  small.max_grid_bytes = 1000;
  set.grid.depth = 4;  // 512 bytes: fine
  EXPECT_NO_THROW(VoxelGridTracer::build(set, small));
  set.grid.depth = 5;  // 4096 bytes: refused
  EXPECT_THROW(VoxelGridTracer::build(set, small), Error);
}

TEST(VoxelGrid, OccupancyAndAttributes) {
  VoxelSet set = cube_set(3, {{1, 2, 3}, {7, 7, 7}, {0, 0, 0}});
  set.attrs.resize(3);
  for (size_t i = 0; i < 3; ++i) set.attrs[i].material = static_cast<uint32_t>(i);
  const VoxelGridTracer g = VoxelGridTracer::build(set);
  EXPECT_TRUE(g.occupied(1, 2, 3));
  EXPECT_TRUE(g.occupied(7, 7, 7));
  EXPECT_FALSE(g.occupied(3, 2, 1));
  EXPECT_FALSE(g.occupied(8, 0, 0));
  const Hit h = trace1(g, make_ray(Vec3(-5, 7.5f, 7.5f), Vec3(1, 0, 0)));
  ASSERT_TRUE(h.hit());
  EXPECT_EQ(h.t, 12.0f);
  EXPECT_EQ(h.ng, Vec3(-1, 0, 0));
  EXPECT_EQ(g.attributes(h.prim).material, 2u);  // codes sorted: (7,7,7) is last
  EXPECT_THROW(g.attributes(3), Error);
  EXPECT_GT(g.memory_bytes(), 64u);
}

TEST(VoxelGrid, EntersFromOutsideOnEveryFaceAndStartsInside) {
  const VoxelSet set = cube_set(2, {{0, 1, 2}, {3, 1, 2}, {1, 0, 2}, {1, 3, 2}, {1, 1, 0}, {1, 1, 3}});
  const VoxelGridTracer g = VoxelGridTracer::build(set);
  struct Expect {
    Ray ray;
    std::array<uint32_t, 3> cell;
    float t;
    Vec3 n;
  };
  const Expect cases[] = {
      {make_ray(Vec3(-2, 1.5f, 2.5f), Vec3(1, 0, 0)), {0, 1, 2}, 2.0f, Vec3(-1, 0, 0)},
      {make_ray(Vec3(6, 1.5f, 2.5f), Vec3(-2, 0, 0)), {3, 1, 2}, 1.0f, Vec3(1, 0, 0)},
      {make_ray(Vec3(1.5f, -1, 2.5f), Vec3(0, 0.5f, 0)), {1, 0, 2}, 2.0f, Vec3(0, -1, 0)},
      {make_ray(Vec3(1.5f, 9, 2.5f), Vec3(0, -1, 0)), {1, 3, 2}, 5.0f, Vec3(0, 1, 0)},
      {make_ray(Vec3(1.5f, 1.5f, -3), Vec3(0, 0, 1)), {1, 1, 0}, 3.0f, Vec3(0, 0, -1)},
      {make_ray(Vec3(1.5f, 1.5f, 7), Vec3(0, 0, -1)), {1, 1, 3}, 3.0f, Vec3(0, 0, 1)},
      // From inside the grid (empty cell (1, 1, 2)) towards +x: hits (3, 1, 2) at its face.
      {make_ray(Vec3(1.5f, 1.5f, 2.5f), Vec3(1, 0, 0)), {3, 1, 2}, 1.5f, Vec3(-1, 0, 0)},
      // From inside an occupied voxel: t = tmin.
      {make_ray(Vec3(0.5f, 1.5f, 2.5f), Vec3(0, 1, 0), 0.25f), {0, 1, 2}, 0.25f, Vec3(0, -1, 0)},
      // Exactly on the grid's entry plane, -0 components: starts at the boundary.
      {make_ray(Vec3(0.0f, 1.5f, 2.5f), Vec3(1, -0.0f, 0.0f)), {0, 1, 2}, 0.0f, Vec3(-1, 0, 0)},
  };
  for (const Expect& e : cases) {
    const Hit h = trace1(g, e.ray);
    ASSERT_TRUE(h.hit());
    const uint64_t code = morton_encode(e.cell[0], e.cell[1], e.cell[2]);
    EXPECT_EQ(set.codes[h.prim], code);
    EXPECT_EQ(h.t, e.t);
    EXPECT_EQ(h.ng, e.n);
  }
  // Misses: pointing away, ending before the voxel, passing beside it.
  EXPECT_FALSE(trace1(g, make_ray(Vec3(-2, 1.5f, 2.5f), Vec3(-1, 0, 0))).hit());
  EXPECT_FALSE(trace1(g, make_ray(Vec3(-2, 1.5f, 2.5f), Vec3(1, 0, 0), 0.0f, 2.0f)).hit());  // tmax at the face
  EXPECT_FALSE(trace1(g, make_ray(Vec3(-2, 2.5f, 2.5f), Vec3(1, 0, 0))).hit());
}

TEST(VoxelGrid, FacePlaneRaysBelongToThePositiveSide) {
  // Voxel (1, 1, 1) only; rays running inside its face planes.
  const VoxelSet set = cube_set(2, {{1, 1, 1}});
  const VoxelGridTracer g = VoxelGridTracer::build(set);
  for (const float zero : {0.0f, -0.0f}) {
    EXPECT_TRUE(trace1(g, make_ray(Vec3(-1, 1.0f, 1.5f), Vec3(1, zero, zero))).hit());   // y = 1: lower face
    EXPECT_FALSE(trace1(g, make_ray(Vec3(-1, 2.0f, 1.5f), Vec3(1, zero, zero))).hit());  // y = 2: upper face
    EXPECT_TRUE(trace1(g, make_ray(Vec3(1.0f, 1.0f, -3), Vec3(zero, zero, 1))).hit());  // along the edge x = y = 1
    EXPECT_FALSE(trace1(g, make_ray(Vec3(2.0f, 1.5f, -3), Vec3(zero, zero, 1))).hit());
  }
  // Touching a corner only: miss. Crossing it diagonally: hit at the corner.
  EXPECT_FALSE(trace1(g, make_ray(Vec3(0, 0, 4), Vec3(1, 1, -1))).hit());
  const Hit h = trace1(g, make_ray(Vec3(0, 0, 0), Vec3(1, 1, 1)));
  ASSERT_TRUE(h.hit());
  EXPECT_EQ(h.t, 1.0f);
}

TEST(VoxelGrid, MatchesBruteForceOnRandomSets) {
  std::mt19937 rng(42);
  std::uniform_real_distribution<float> u(-1.0f, 1.0f);
  for (const int depth : {1, 3, 5}) {
    VoxelSet set;
    set.grid = VoxelGrid{Vec3{-0.3f, 0.2f, 1.7f}, 2.9f, depth};
    const uint64_t cells = uint64_t{1} << (3 * depth);
    for (uint64_t c = 0; c < cells; ++c)
      if (rng() % 5 == 0) set.codes.push_back(c);
    for (const VoxelHitMode mode : {VoxelHitMode::Cubes, VoxelHitMode::Contours}) {
      VoxelTracerOptions o;
      o.mode = mode;
      const VoxelGridTracer g = VoxelGridTracer::build(set, o);
      const voxel::VoxelBruteTracer brute(set, o);
      std::vector<Ray> rays;
      const Vec3 c = set.grid.bounds().center();
      for (int i = 0; i < 5000; ++i) {
        const Vec3 org = c + Vec3(u(rng), u(rng), u(rng)) * (set.grid.side * (i % 2 ? 0.5f : 2.0f));
        Vec3 d(u(rng), u(rng), u(rng));
        if (i % 7 == 0) d.y = 0.0f;
        if (i % 11 == 0) d.z = -0.0f;
        rays.push_back(make_ray(org, d));
      }
      std::vector<Hit> hg(rays.size()), hb(rays.size());
      g.intersect(rays, hg);
      brute.intersect(rays, hb);
      size_t hits = 0;
      for (size_t i = 0; i < rays.size(); ++i) {
        ASSERT_EQ(hg[i].prim, hb[i].prim) << "ray " << i;
        if (!hb[i].hit()) continue;
        ++hits;
        EXPECT_EQ(hg[i].t, hb[i].t);
        EXPECT_EQ(hg[i].ng, hb[i].ng);
      }
      EXPECT_GT(hits, 500u);
    }
  }
}

}  // namespace
}  // namespace specula
