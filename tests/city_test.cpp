// The built-in "city" scene: size control (city:N), zones, materials, cameras that see a town,
// determinism, size errors, and the CLI accepting city:N. Small sizes keep it fast.
#include <gtest/gtest.h>

#include <algorithm>
#include <cstring>
#include <set>
#include <string>
#include <vector>

#include "cli_test_util.h"
#include "scene/builtin_scenes.h"
#include "specula/accel.h"
#include "specula/error.h"
#include "specula/load.h"
#include "specula/render.h"
#include "test_util.h"

using namespace specula;

namespace {

const Material* find_material(const Scene& s, const std::string& name) {
  for (const Material& m : s.materials)
    if (m.name == name) return &m;
  return nullptr;
}

bool has_mesh(const Scene& s, const std::string& name) {
  return std::any_of(s.meshes.begin(), s.meshes.end(), [&](const MeshRange& m) { return m.name == name; });
}

}  // namespace

TEST(City, DefaultHasAboutSixHundredThousandTrianglesInNamedZones) {
  const Scene s = make_builtin_scene("city");
  EXPECT_EQ(s.name, "city");
  EXPECT_GE(s.triangle_count(), 500000u);
  EXPECT_LE(s.triangle_count(), 700000u);
  EXPECT_NO_THROW(s.validate());
  // Zones: one named mesh each, more than 50, covering every triangle in order, names unique.
  EXPECT_GT(s.meshes.size(), 50u);
  std::set<std::string> names;
  uint32_t next = 0;
  size_t blocks = 0;
  for (const MeshRange& m : s.meshes) {
    EXPECT_FALSE(m.name.empty());
    EXPECT_TRUE(names.insert(m.name).second) << "duplicate zone " << m.name;
    EXPECT_EQ(m.first_triangle, next) << m.name;
    EXPECT_GT(m.triangle_count, 0u) << m.name;
    next = m.first_triangle + m.triangle_count;
    if (m.name.rfind("zone_", 0) == 0) ++blocks;
  }
  EXPECT_EQ(next, s.triangle_count());
  EXPECT_GT(blocks, 40u);
  for (const char* zone : {"bridge", "underpass", "plaza", "zone_00_00"}) EXPECT_TRUE(has_mesh(s, zone)) << zone;
}

TEST(City, SizeFollowsN) {
  for (uint64_t n : {10000u, 20000u, 50000u, 150000u}) {
    const Scene s = make_builtin_scene("city:" + std::to_string(n));
    EXPECT_EQ(s.name, "city:" + std::to_string(n));
    const double ratio = static_cast<double>(s.triangle_count()) / static_cast<double>(n);
    EXPECT_GT(ratio, 0.7) << n << ": " << s.triangle_count() << " triangles";
    EXPECT_LT(ratio, 1.3) << n << ": " << s.triangle_count() << " triangles";
    EXPECT_TRUE(has_mesh(s, "bridge") && has_mesh(s, "underpass") && has_mesh(s, "plaza")) << n;
  }
  // load_scene takes the same names.
  EXPECT_EQ(load_scene("city:12000").name, "city:12000");
}

TEST(City, MaterialsLightsCamerasAndSky) {
  const Scene s = make_builtin_scene("city:20000");
  EXPECT_NO_THROW(s.validate());
  for (const Vec3& n : s.normals) ASSERT_NEAR(length(n), 1.0f, 1e-3f);
  const Material* glass = find_material(s, "shop_glass");
  ASSERT_NE(glass, nullptr);
  EXPECT_TRUE(glass->dielectric());
  EXPECT_FLOAT_EQ(glass->ior, 1.5f);
  EXPECT_GT(max_component(glass->absorption), 0.0f);
  const Material* road = find_material(s, "wet_road");
  ASSERT_NE(road, nullptr);
  EXPECT_GE(road->reflectivity, 0.5f);
  EXPECT_LT(max_component(road->diffuse), 0.1f);
  const Material* water = find_material(s, "canal_water");
  ASSERT_NE(water, nullptr);
  EXPECT_TRUE(water->dielectric());
  EXPECT_FLOAT_EQ(water->ior, 1.33f);
  for (const char* m : {"concrete", "grass", "window_glass"}) EXPECT_NE(find_material(s, m), nullptr) << m;
  int walls = 0;
  for (const Material& m : s.materials) walls += m.name.rfind("wall_", 0) == 0;
  EXPECT_GE(walls, 4);
  // Every material is used by some triangle except none: all ids in range (validate) and the
  // glass and road are really on triangles.
  std::vector<int> used(s.materials.size(), 0);
  for (uint32_t id : s.material_ids) used[id] = 1;
  for (const char* m : {"shop_glass", "wet_road", "canal_water", "window_glass", "grass"}) {
    const auto it = std::find_if(s.materials.begin(), s.materials.end(), [&](const Material& x) { return x.name == m; });
    EXPECT_TRUE(used[static_cast<size_t>(it - s.materials.begin())]) << m;
  }
  // A sun and a few street lamps; a gradient sky.
  int suns = 0, points = 0;
  for (const Light& l : s.lights) {
    suns += l.type == LightType::Directional;
    points += l.type == LightType::Point;
  }
  EXPECT_EQ(suns, 1);
  EXPECT_GE(points, 3);
  EXPECT_EQ(s.sky.type, SkyType::Gradient);
  ASSERT_EQ(s.cameras.size(), 4u);
  EXPECT_EQ(s.cameras[0].name, "street");  // the default camera
  for (const char* cam : {"street", "underpass", "bridge", "plaza"}) EXPECT_TRUE(s.find_camera(cam)) << cam;
}

TEST(City, ShopGlassIsClosedAndWoundOutwards) {
  const Scene s = make_builtin_scene("city:20000");
  const Material* glass = find_material(s, "shop_glass");
  ASSERT_NE(glass, nullptr);
  const auto id = static_cast<uint32_t>(glass - s.materials.data());
  double volume = 0.0;
  size_t tris = 0;
  for (size_t t = 0; t < s.triangle_count(); ++t) {
    if (s.material_ids[t] != id) continue;
    const Vec3 a = s.positions[s.indices[3 * t]], b = s.positions[s.indices[3 * t + 1]], c = s.positions[s.indices[3 * t + 2]];
    volume += static_cast<double>(dot(a, cross(b, c))) / 6.0;
    ++tris;
  }
  ASSERT_GT(tris, 0u);
  EXPECT_EQ(tris % 12, 0u) << "every pane is a closed box";
  EXPECT_GT(volume, 0.0);
}

TEST(City, EveryCameraSeesSkyAndTown) {
  const Scene s = make_builtin_scene("city:20000");
  const std::vector<Vec3> tr = shadow_transmittance(s);
  const auto tracer = build_tracer(AccelKind::Bvh, TriangleInput{s.positions, s.indices, tr}, BvhOptions{});
  for (const Camera& cam : s.cameras) {
    RenderOptions o;
    o.width = 32;
    o.height = 24;
    o.camera = cam.name;
    o.aovs = {Aov::PrimId};
    const Film f = render_whitted(s, *tracer, o);
    size_t sky = 0, hits = 0;
    for (uint32_t p : f.prim_id) (p == kNoHit ? sky : hits)++;
    EXPECT_GT(sky, 0u) << cam.name << ": no sky";
    EXPECT_GT(hits, f.prim_id.size() / 3) << cam.name << ": hardly any geometry";
    float lo = 1e30f, hi = -1e30f;
    for (const Vec3& c : f.color) {
      lo = std::min(lo, luminance(c));
      hi = std::max(hi, luminance(c));
    }
    EXPECT_GT(hi - lo, 0.1f) << cam.name << ": flat image";
    // Many different triangles: a town, not one wall.
    std::set<uint32_t> distinct(f.prim_id.begin(), f.prim_id.end());
    EXPECT_GT(distinct.size(), 40u) << cam.name;
  }
}

TEST(City, DeterministicArrays) {
  const Scene a = make_builtin_scene("city:30000");
  (void)make_builtin_scene("city:11000");  // nothing carries over between builds
  const Scene b = make_builtin_scene("city:30000");
  ASSERT_EQ(a.positions.size(), b.positions.size());
  ASSERT_EQ(a.indices.size(), b.indices.size());
  EXPECT_EQ(std::memcmp(a.positions.data(), b.positions.data(), a.positions.size() * sizeof(Vec3)), 0);
  EXPECT_EQ(std::memcmp(a.normals.data(), b.normals.data(), a.normals.size() * sizeof(Vec3)), 0);
  EXPECT_EQ(a.indices, b.indices);
  EXPECT_EQ(a.material_ids, b.material_ids);
  ASSERT_EQ(a.meshes.size(), b.meshes.size());
  for (size_t i = 0; i < a.meshes.size(); ++i) {
    EXPECT_EQ(a.meshes[i].name, b.meshes[i].name);
    EXPECT_EQ(a.meshes[i].first_triangle, b.meshes[i].first_triangle);
  }
  ASSERT_EQ(a.cameras.size(), b.cameras.size());
  for (size_t i = 0; i < a.cameras.size(); ++i) EXPECT_EQ(a.cameras[i].position, b.cameras[i].position);
  ASSERT_EQ(a.lights.size(), b.lights.size());
  for (size_t i = 0; i < a.lights.size(); ++i) EXPECT_EQ(a.lights[i].position, b.lights[i].position);
}

TEST(City, BadSizesGiveClearErrors) {
  EXPECT_TRUE(is_builtin_scene("city"));
  EXPECT_TRUE(is_builtin_scene("city:50000"));
  EXPECT_FALSE(is_builtin_scene("cityscape"));
  EXPECT_FALSE(is_builtin_scene("City"));
  for (const std::string bad : {"city:abc", "city:5", "city:-3", "city:1e99", "city:", "city:20000001",
                                "city:99999999999999999999999", "city: 50000", "city:+50000"}) {
    EXPECT_TRUE(is_builtin_scene(bad)) << bad << ": the city should explain the size";
    for (int via_load = 0; via_load < 2; ++via_load) {
      try {
        (void)(via_load ? load_scene(bad) : make_builtin_scene(bad));
        ADD_FAILURE() << bad << ": expected specula::Error";
      } catch (const Error& e) {
        const std::string msg = e.what();
        EXPECT_NE(msg.find(bad), std::string::npos) << msg;
        EXPECT_NE(msg.find("10000"), std::string::npos) << msg;
        EXPECT_NE(msg.find("20000000"), std::string::npos) << msg;
      }
    }
  }
  EXPECT_THROW(builtin::make_city_with_triangles(9999), Error);
  EXPECT_THROW(builtin::make_city_with_triangles(20000001), Error);
}

TEST(City, CliRendersSizedCityAndListsItInHelp) {
  if (std::string(SPECULA_CLI_PATH).empty()) GTEST_SKIP() << "specula CLI not built";
  const auto dir = test::temp_dir("city-cli");
  const auto png = dir / "c.png";
  test::RunResult r = test::run_cli("render city:20000 --camera bridge --width 32 --height 24 -o '" + png.string() + "'", dir);
  EXPECT_EQ(r.exit_code, 0) << r.err;
  EXPECT_TRUE(std::filesystem::exists(png));
  EXPECT_NE(r.out.find("city:20000"), std::string::npos) << r.out;
  r = test::run_cli("render city:abc", dir);
  EXPECT_NE(r.exit_code, 0);
  EXPECT_NE(r.err.find("city:abc"), std::string::npos) << r.err;
  r = test::run_cli("render --help", dir);
  EXPECT_NE(r.out.find("city:N"), std::string::npos) << r.out;
  std::filesystem::remove_all(dir);
}
