// Built-in scenes: names, errors, validity, closed solids wound outwards, the bunny stand-in.
#include <gtest/gtest.h>

#include <cmath>
#include <string>
#include <vector>

#include "scene/builtin_scenes.h"
#include "specula/error.h"
#include "specula/load.h"
#include "test_util.h"

using namespace specula;

namespace {

/// Signed volume of one mesh range (positive when the triangles wind outwards).
double signed_volume(const Scene& s, const MeshRange& m) {
  double v = 0.0;
  for (uint32_t t = m.first_triangle; t < m.first_triangle + m.triangle_count; ++t) {
    const Vec3 a = s.positions[s.indices[3 * t]], b = s.positions[s.indices[3 * t + 1]],
               c = s.positions[s.indices[3 * t + 2]];
    v += static_cast<double>(dot(a, cross(b, c))) / 6.0;
  }
  return v;
}

const MeshRange* find_mesh(const Scene& s, const std::string& name) {
  for (const MeshRange& m : s.meshes)
    if (m.name == name) return &m;
  return nullptr;
}

LoadOptions quiet(std::vector<std::string>* warnings) {
  LoadOptions o;
  o.warn = [warnings](const std::string& w) { warnings->push_back(w); };
  return o;
}

}  // namespace

TEST(Builtin, NamesAndUnknownNameError) {
  const auto names = builtin_scene_names();
  ASSERT_EQ(names.size(), 4u);
  for (const auto& n : names) EXPECT_TRUE(is_builtin_scene(n)) << n;
  EXPECT_FALSE(is_builtin_scene("Pool"));
  EXPECT_FALSE(is_builtin_scene(""));
  try {
    make_builtin_scene("swimmingpool");
    FAIL() << "expected an error";
  } catch (const Error& e) {
    const std::string msg = e.what();
    EXPECT_NE(msg.find("swimmingpool"), std::string::npos) << msg;
    for (const auto& n : names) EXPECT_NE(msg.find(n), std::string::npos) << msg;
  }
}

TEST(Builtin, EverySceneIsValidAndHasCamerasAndLights) {
  std::vector<std::string> warnings;
  for (const auto& n : builtin_scene_names()) {
    const Scene s = make_builtin_scene(n, quiet(&warnings));
    EXPECT_NO_THROW(s.validate()) << n;
    EXPECT_EQ(s.name, n);
    EXPECT_FALSE(s.cameras.empty()) << n;
    EXPECT_FALSE(s.lights.empty()) << n;
    EXPECT_GT(s.triangle_count(), 100u) << n;
    // The city is the big benchmark scene (about 600k triangles, tests/city_test.cpp).
    EXPECT_LT(s.triangle_count(), n == "city" ? 700000u : 200000u) << n;
    for (const Vec3& nn : s.normals) EXPECT_NEAR(length(nn), 1.0f, 1e-3f) << n;
  }
}

TEST(Builtin, ClosedSolidsWindOutwards) {
  const Scene g = make_builtin_scene("glassbox");
  for (const char* m : {"frame", "glass_panes", "semi_solid_core"}) {
    const MeshRange* r = find_mesh(g, m);
    ASSERT_NE(r, nullptr) << m;
    EXPECT_GT(signed_volume(g, *r), 0.0) << m;
  }
  // Pane volume: five square slabs 2*0.873 wide with a 0.5 hole, 0.121 thick.
  const double pane = (std::pow(2.0 * (0.875 - 0.002), 2) - 0.25) * (0.125 - 0.004);
  EXPECT_NEAR(signed_volume(g, *find_mesh(g, "glass_panes")), 5.0 * pane, 1e-3);
  const Scene c = make_builtin_scene("cornell");
  const MeshRange* sphere = find_mesh(c, "glass_sphere");
  ASSERT_NE(sphere, nullptr);
  EXPECT_NEAR(signed_volume(c, *sphere), 4.0 / 3.0 * 3.14159265 * std::pow(0.36, 3), 2e-3);
  EXPECT_GT(signed_volume(c, *find_mesh(c, "mirror_block")), 0.0);
  // Vertex normals of the glass sphere point away from its centre.
  for (uint32_t t = sphere->first_triangle; t < sphere->first_triangle + sphere->triangle_count; ++t) {
    const uint32_t i = c.indices[3 * t];
    EXPECT_GT(dot(c.normals[i], c.positions[i] - Vec3{0.42f, 0.36f, 0.3f}), 0.0f);
  }
}

TEST(Builtin, PoolHasSeedCamerasAndWaterDielectric) {
  std::vector<std::string> warnings;
  const Scene s = make_builtin_scene("pool", quiet(&warnings));
  for (const char* cam : {"water", "bunny", "parallel"}) EXPECT_TRUE(s.find_camera(cam).has_value()) << cam;
  bool water = false;
  for (const Material& m : s.materials)
    if (m.name == "water") {
      water = true;
      EXPECT_TRUE(m.dielectric());
      EXPECT_FLOAT_EQ(m.ior, 1.33f);
      EXPECT_GT(max_component(m.absorption), 0.0f);
    }
  EXPECT_TRUE(water);
  const MeshRange* w = find_mesh(s, "water");
  ASSERT_NE(w, nullptr);
  // The water surface faces up so that rays from above enter the medium.
  const uint32_t t = w->first_triangle;
  const Vec3 a = s.positions[s.indices[3 * t]], b = s.positions[s.indices[3 * t + 1]],
             c = s.positions[s.indices[3 * t + 2]];
  EXPECT_GT(cross(b - a, c - a).y, 0.0f);
}

TEST(Builtin, PoolUsesTheRealBunnyWhenPresent) {
  SPECULA_REQUIRE_MESH(bunny, "stanford-bunny.obj");
  std::vector<std::string> warnings;
  LoadOptions o = quiet(&warnings);
  o.data.cli_dir = bunny.parent_path().string();
  const Scene s = make_builtin_scene("pool", o);
  EXPECT_TRUE(warnings.empty());
  const MeshRange* r = find_mesh(s, "bunny");
  ASSERT_NE(r, nullptr);
  EXPECT_EQ(r->triangle_count, 69451u);
  // Scaled to 1.5 m, standing on the pool floor (y = -1), half under the water (y = -0.22).
  Aabb b;
  for (uint32_t t = r->first_triangle; t < r->first_triangle + r->triangle_count; ++t)
    for (int k = 0; k < 3; ++k) b.grow(s.positions[s.indices[3 * t + static_cast<uint32_t>(k)]]);
  EXPECT_NEAR(b.min.y, -1.0f, 1e-4f);
  EXPECT_NEAR(b.max.y, 0.5f, 1e-4f);
}

TEST(Builtin, MissingBunnyGivesStandInAndOneWarning) {
  std::vector<std::string> warnings;
  LoadOptions o = quiet(&warnings);
  o.data.cli_dir = test::temp_dir("nobunny").string();
  const Scene s = builtin::make_pool_with_bunny(o, {});
  ASSERT_EQ(warnings.size(), 1u);
  EXPECT_NE(warnings[0].find("stanford-bunny.obj"), std::string::npos) << warnings[0];
  EXPECT_NE(warnings[0].find(o.data.describe()), std::string::npos) << warnings[0];
  const MeshRange* r = find_mesh(s, "bunny_stand_in");
  ASSERT_NE(r, nullptr);
  Aabb b;
  for (uint32_t t = r->first_triangle; t < r->first_triangle + r->triangle_count; ++t)
    for (int k = 0; k < 3; ++k) b.grow(s.positions[s.indices[3 * t + static_cast<uint32_t>(k)]]);
  EXPECT_NEAR(b.min.y, -1.0f, 0.05f);
  EXPECT_GT(b.extent().y, 1.0f);
  EXPECT_LT(b.extent().y, 2.0f);
  EXPECT_NO_THROW(s.validate());
}
