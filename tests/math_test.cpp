#include <gtest/gtest.h>

#include "specula/math.h"

using namespace specula;

namespace {
void expect_vec_near(const Vec3& a, const Vec3& b, float eps = 1e-5f) {
  EXPECT_NEAR(a.x, b.x, eps);
  EXPECT_NEAR(a.y, b.y, eps);
  EXPECT_NEAR(a.z, b.z, eps);
}
}  // namespace

TEST(Math, RotationTurnsPointsAndNormalsAlike) {
  const Mat4 r = Mat4::rotate({0, 0, 1}, kPi / 2);  // +x -> +y
  expect_vec_near(r.transform_point({1, 0, 0}), {0, 1, 0});
  expect_vec_near(normalize(r.transform_normal({1, 0, 0})), {0, 1, 0});
  const Mat4 q = Mat4::from_quaternion(0, 0, std::sin(kPi / 4), std::cos(kPi / 4));
  expect_vec_near(q.transform_vector({1, 0, 0}), {0, 1, 0});
}

TEST(Math, NormalsStayPerpendicularUnderNonUniformScaleAndShear) {
  // A general affine map: the transformed normal must stay perpendicular to transformed edges.
  Mat4 m = Mat4::rotate({1, 2, 3}, 0.7f) * Mat4::scale({3, 0.5f, 2});
  m.m[1] += 0.8f;  // shear
  const Vec3 a{0.3f, -1, 2}, b{1, 0.5f, -0.25f};
  const Vec3 n = cross(a, b);
  const Vec3 tn = normalize(m.transform_normal(n));
  EXPECT_NEAR(dot(tn, normalize(m.transform_vector(a))), 0.0f, 1e-5f);
  EXPECT_NEAR(dot(tn, normalize(m.transform_vector(b))), 0.0f, 1e-5f);
  // Same side as the transformed face normal (det > 0 here).
  EXPECT_GT(dot(tn, cross(m.transform_vector(a), m.transform_vector(b))), 0.0f);
}

TEST(Math, MirroringKeepsOutwardNormalsOutward) {
  // Mirror x: the face at x = +1 with outward normal +x lands at x = -1, facing -x.
  const Mat4 m = Mat4::scale({-1, 1, 1});
  expect_vec_near(normalize(m.transform_normal({1, 0, 0})), {-1, 0, 0});
  expect_vec_near(normalize(m.transform_normal({0, 1, 0})), {0, 1, 0});
}

TEST(Math, NormalizeNeverReturnsNaN) {
  EXPECT_EQ(normalize(Vec3{}), Vec3{});
  EXPECT_EQ(normalize(Vec3{kInf, 0, 0}), Vec3{});
  expect_vec_near(normalize(Vec3{0, 3, 4}), {0, 0.6f, 0.8f});
}

TEST(Math, AabbBasics) {
  Aabb b;
  EXPECT_TRUE(b.empty());
  EXPECT_EQ(b.area(), 0.0f);
  b.grow(Vec3{0, 0, 0});
  b.grow(Vec3{1, 2, 3});
  EXPECT_FLOAT_EQ(b.area(), 2 * (2 + 6 + 3));
  EXPECT_EQ(b.largest_axis(), 2);
}
