#include <gtest/gtest.h>

#include "specula/scene.h"

using namespace specula;

TEST(Scene, ComputedNormalsAreUnitAndNeverNaN) {
  const std::vector<Vec3> p{{0, 0, 0}, {1, 0, 0}, {0, 1, 0}, {5, 5, 5}};
  const std::vector<uint32_t> idx{0, 1, 2, 3, 3, 3};  // second triangle is degenerate
  const auto n = compute_vertex_normals(p, idx);
  ASSERT_EQ(n.size(), 4u);
  EXPECT_NEAR(n[0].z, 1.0f, 1e-6f);
  EXPECT_EQ(n[3], (Vec3{0, 1, 0}));
}

TEST(Scene, AddMeshRejectsOutOfRangeIndex) {
  Scene s;
  s.add_material({});
  const std::vector<Vec3> p{{0, 0, 0}, {1, 0, 0}, {0, 1, 0}};
  const std::vector<uint32_t> bad{0, 1, 3};
  EXPECT_THROW(s.add_mesh("m", p, bad, 0), std::runtime_error);
  const std::vector<uint32_t> good{0, 1, 2};
  s.add_mesh("m", p, good, 0, {}, Mat4::translate({1, 0, 0}));
  EXPECT_EQ(s.triangle_count(), 1u);
  EXPECT_EQ(s.positions[0], (Vec3{1, 0, 0}));
  EXPECT_NO_THROW(s.validate());
}
