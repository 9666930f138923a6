// An image sky named in a JSON scene is decoded by load_scene and lights the render.
#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <vector>

#include "specula/accel.h"
#include "specula/error.h"
#include "specula/image.h"
#include "specula/load.h"
#include "specula/render.h"
#include "test_util.h"

using namespace specula;
namespace fs = std::filesystem;

namespace {

fs::path write_scene(const fs::path& dir, const std::string& sky_image) {
  const fs::path p = dir / "sky.json";
  std::ofstream(p) << R"({"meshes": [{"builtin": "plane", "transform": {"translate": [0, -1, 0], "scale": [0.1, 0.1, 0.1]}}],
    "cameras": [{"name": "up", "position": [0, 0, 0], "target": [0, 1, 0], "up": [0, 0, -1], "fov": 10}],
    "sky": {"type": "image", "image": ")" << sky_image << R"("}})";
  return p;
}

}  // namespace

TEST(SkyImage, JsonSceneSkyIsDecodedAndSeenByCameraRays) {
  const fs::path dir = test::temp_dir("sky");
  // 8x4 equirectangular image: top half (looking up) green, bottom half red.
  const int w = 8, h = 4;
  std::vector<Vec3> px(static_cast<size_t>(w * h));
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x) px[static_cast<size_t>(y * w + x)] = y < h / 2 ? Vec3{0, 2, 0} : Vec3{2, 0, 0};
  write_exr((dir / "sky.exr").string(), w, h, px);

  const Scene scene = load_scene(write_scene(dir, "sky.exr").string());
  ASSERT_EQ(scene.sky.type, SkyType::Image);
  ASSERT_EQ(scene.sky.image_width, w);
  ASSERT_EQ(scene.sky.image_height, h);

  const auto tracer = build_tracer(AccelKind::Bvh, {scene.positions, scene.indices, {}});
  RenderOptions ro;
  ro.width = 4;
  ro.height = 4;
  ro.threads = 1;
  const Film film = render_whitted(scene, *tracer, ro);
  // Looking straight up: the green half of the sky, at its HDR value (half floats are exact here).
  EXPECT_NEAR(film.color[5].y, 2.0f, 1e-3f);
  EXPECT_NEAR(film.color[5].x, 0.0f, 1e-3f);
  fs::remove_all(dir);
}

TEST(SkyImage, MissingOrCorruptSkyImageIsAnErrorNamingTheScene) {
  const fs::path dir = test::temp_dir("skybad");
  EXPECT_THROW(load_scene(write_scene(dir, "nope.exr").string()), Error);
  std::ofstream(dir / "bad.exr") << "not an exr";
  try {
    load_scene(write_scene(dir, "bad.exr").string());
    ADD_FAILURE() << "corrupt sky image accepted";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("sky.json"), std::string::npos) << e.what();
  }
  fs::remove_all(dir);
}
