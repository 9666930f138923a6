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

TEST(VoxelGrid, RefusesHugeBrickTableUpFront) {
  VoxelSet set;
  set.grid = VoxelGrid{Vec3{}, 1.0f, 13};
  set.codes = {5};
  try {
    VoxelGridTracer::build(set);
    FAIL() << "depth 13 must be refused by default";
  } catch (const Error& e) {
    const std::string msg = e.what();
    EXPECT_NE(msg.find("depth 13"), std::string::npos) << msg;
    EXPECT_NE(msg.find("4.00 GiB"), std::string::npos) << msg;  // 2^30 bricks of 4 bytes
  }
  EXPECT_EQ(VoxelGridTracer::table_bytes(11), uint64_t{64} << 20);
  EXPECT_EQ(VoxelGridTracer::table_bytes(3), 4u);  // one brick
  EXPECT_EQ(VoxelGridTracer::table_bytes(0), 4u);
  VoxelTracerOptions small;
  small.max_grid_bytes = 1000;
  set.grid.depth = 5;  // 64 bricks: a 256-byte table and one brick of 68 bytes: fine
  EXPECT_NO_THROW(VoxelGridTracer::build(set, small));
  set.grid.depth = 6;  // 512 bricks: a 2048-byte table: refused
  EXPECT_THROW(VoxelGridTracer::build(set, small), Error);
  // Occupied bricks count too: 64 bytes of bits and 4 of index each.
  set.grid.depth = 5;
  set.codes.clear();
  for (uint64_t b = 0; b < 10; ++b) set.codes.push_back(b << 9);  // voxel 0 of bricks 0..9
  EXPECT_NO_THROW(VoxelGridTracer::build(set, small));             // 256 + 10 * 68 = 936 bytes
  set.codes.push_back(uint64_t{10} << 9);
  EXPECT_THROW(VoxelGridTracer::build(set, small), Error);  // 256 + 11 * 68 = 1004 bytes
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

// The walk crosses an empty 8^3 brick in one step. Sparse bricks (most of them empty), rays
// through brick faces, edges and corners exactly (voxel side 1: local coordinates are world
// coordinates), rays that start or end inside empty bricks, +-0 components: the same voxel, t
// and normal as the brute force, and the same transmittance.
TEST(VoxelGrid, SkipsEmptyBricksExactly) {
  std::mt19937 rng(7);
  std::uniform_real_distribution<float> u(0.0f, 1.0f);
  VoxelSet set;
  set.grid = VoxelGrid{Vec3{0.0f, 0.0f, 0.0f}, 64.0f, 6};  // 8^3 bricks of 8^3 voxels
  for (uint64_t brick = 0; brick < 512; ++brick) {
    if (rng() % 8 != 0) continue;
    for (uint64_t v = 0; v < 512; ++v)
      if (rng() % 10 == 0) set.codes.push_back(brick << 9 | v);
  }
  set.attrs.resize(set.codes.size());
  for (size_t i = 0; i < set.attrs.size(); ++i) {
    set.attrs[i].transparency = i % 3 == 0 ? 0.0f : 0.5f;
    set.attrs[i].normal = Vec3(0.0f, 0.0f, 1.0f);
    set.attrs[i].contour_lo = -0.3f;
    set.attrs[i].contour_hi = 0.2f;
  }
  std::vector<Ray> rays;
  const auto lattice = [&](uint32_t m) { return static_cast<float>(8u * (rng() % m)); };  // a brick plane
  for (int i = 0; i < 20000; ++i) {
    Vec3 org(u(rng) * 80.0f - 8.0f, u(rng) * 80.0f - 8.0f, u(rng) * 80.0f - 8.0f);
    Vec3 d(u(rng) - 0.5f, u(rng) - 0.5f, u(rng) - 0.5f);
    switch (i % 7) {
      case 1:  // along an axis, in brick planes
        org = Vec3(lattice(9), lattice(9), -4.0f);
        d = Vec3(i % 4 < 2 ? 0.0f : -0.0f, 0.0f, 1.0f);
        break;
      case 2:  // diagonally through brick corners
        org = Vec3(lattice(8), lattice(8), 0.0f) - Vec3(3.0f);
        d = Vec3(1.0f, i % 4 < 2 ? 1.0f : -1.0f, 1.0f);
        break;
      case 3:  // in a brick plane, through brick edges
        org = Vec3(lattice(9), u(rng) * 64.0f, -1.0f);
        d = Vec3(0.0f, u(rng) - 0.5f, 1.0f);
        break;
      case 4: {  // slopes of small ratios: where the ray crosses one axis's plane it is close to
                 // (or exactly on) another's, so o + t d rounds to either side of the plane
        const float steps[] = {1.0f, 2.0f, 3.0f, 0.5f, 1.0f / 3.0f, 0.1f, 7.0f};
        org = Vec3(lattice(8), lattice(8) + static_cast<float>(rng() % 3) / 3.0f, -0.5f);
        d = Vec3(steps[rng() % 7], steps[rng() % 7], steps[rng() % 7]);
        if (rng() % 2) d.x = -d.x, org.x += 64.0f;
        break;
      }
      default: break;
    }
    const float tmax = i % 5 == 0 ? u(rng) * 40.0f : kInf;
    rays.push_back(make_ray(org, d, i % 7 == 0 ? u(rng) * 5.0f : 0.0f, tmax));
  }
  for (const VoxelHitMode mode : {VoxelHitMode::Cubes, VoxelHitMode::Contours}) {
    VoxelTracerOptions o;
    o.mode = mode;
    const VoxelGridTracer g = VoxelGridTracer::build(set, o);
    const voxel::VoxelBruteTracer brute(set, o);
    // Both outputs start as records no tracer returns (and differ): every ray must be written.
    std::vector<Hit> hg(rays.size(), test::unwritten_hit(0xFFFFFFF0u)), hb(rays.size(), test::unwritten_hit(0xFFFFFFF1u));
    g.intersect(rays, hg);
    brute.intersect(rays, hb);
    size_t hits = 0;
    for (size_t i = 0; i < rays.size(); ++i) {
      ASSERT_EQ(hg[i].prim, hb[i].prim) << "ray " << i << ", mode " << to_string(mode);
      if (!hb[i].hit()) continue;
      ++hits;
      EXPECT_EQ(hg[i].t, hb[i].t) << "ray " << i;
      EXPECT_EQ(hg[i].ng, hb[i].ng) << "ray " << i;
    }
    EXPECT_GT(hits, 2000u);
    EXPECT_LT(hits, rays.size() - 2000u);  // and many rays cross the grid without a hit
    std::vector<Vec3> tg(rays.size(), Vec3(-1.0f)), tb(rays.size(), Vec3(-2.0f));
    g.transmittance(rays, tg);
    brute.transmittance(rays, tb);
    for (size_t i = 0; i < rays.size(); ++i) ASSERT_EQ(tg[i], tb[i]) << "ray " << i;
  }
  // Most bricks are empty: the grid stores only the occupied ones.
  const VoxelGridTracer g = VoxelGridTracer::build(set);
  EXPECT_LT(g.memory_bytes(), VoxelGridTracer::table_bytes(6) + 100 * 68 + set.codes.size() * sizeof(VoxelAttributes));
}

}  // namespace
}  // namespace specula
