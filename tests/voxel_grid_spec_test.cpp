#include <gtest/gtest.h>

#include <random>

#include "specula/voxel.h"

using namespace specula;

TEST(Morton, RoundTripsAndOrdersChildren) {
  std::mt19937 rng(7);
  std::uniform_int_distribution<uint32_t> d(0, (1u << 21) - 1);
  for (int i = 0; i < 10000; ++i) {
    const uint32_t x = d(rng), y = d(rng), z = d(rng);
    uint32_t a, b, c;
    morton_decode(morton_encode(x, y, z), a, b, c);
    ASSERT_EQ(a, x);
    ASSERT_EQ(b, y);
    ASSERT_EQ(c, z);
  }
  EXPECT_EQ(morton_encode(1, 0, 0), 1u);
  EXPECT_EQ(morton_encode(0, 1, 0), 2u);
  EXPECT_EQ(morton_encode(0, 0, 1), 4u);
  EXPECT_EQ(morton_encode(2, 0, 0), 8u);
  EXPECT_EQ(morton_encode((1u << 21) - 1, (1u << 21) - 1, (1u << 21) - 1), (1ull << 63) - 1);
}

TEST(VoxelGrid, RootCubeIsMinCornerAndLargestExtent) {
  const Aabb b{{-1.0f, 2.0f, 0.5f}, {3.0f, 3.0f, 1.0f}};
  const VoxelGrid g = VoxelGrid::around(b, 3);
  EXPECT_EQ(g.origin, b.min);
  EXPECT_FLOAT_EQ(g.side, 4.0f);
  EXPECT_EQ(g.resolution(), 8u);
  EXPECT_FLOAT_EQ(g.voxel_size(), 0.5f);
  const Aabb v = g.voxel_box(1, 0, 7);
  EXPECT_FLOAT_EQ(v.min.x, -0.5f);
  EXPECT_FLOAT_EQ(v.max.z, 4.5f);
  const VoxelGrid flat = VoxelGrid::around(Aabb{{1, 1, 1}, {1, 1, 1}}, 2);
  EXPECT_GT(flat.side, 0.0f);
}
