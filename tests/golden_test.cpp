// Image regression: small renders of the built-in scenes against reviewed golden PNGs.
//
// Tolerance: mean absolute error below 2/255 and fewer than 0.5 % of the pixels off by more
// than 8/255 in any channel (8-bit sRGB). On failure the actual image and a diff image are
// written to the temp folder and their paths printed.
//
// To regenerate after an intended change: SPECULA_UPDATE_GOLDEN=1 ./specula_tests
// --gtest_filter='Golden.*', then LOOK at tests/golden/*.png before committing them.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <string>
#include <vector>

#include "io/image_util.h"
#include "specula/accel.h"
#include "specula/image.h"
#include "specula/load.h"
#include "specula/render.h"
#include "specula/voxel_scene.h"
#include "test_util.h"

using namespace specula;
namespace fs = std::filesystem;

namespace {

constexpr int kWidth = 128, kHeight = 96;

fs::path golden_dir() { return fs::path(SPECULA_SOURCE_DIR) / "tests" / "golden"; }

bool updating() {
  const char* e = std::getenv("SPECULA_UPDATE_GOLDEN");
  return e && *e && std::string(e) != "0";
}

Film render_builtin(const Scene& s, const std::string& camera) {
  const std::vector<Vec3> tr = shadow_transmittance(s);
  const auto tracer = build_tracer(AccelKind::Bvh, TriangleInput{s.positions, s.indices, tr});
  RenderOptions o;
  o.width = kWidth;
  o.height = kHeight;
  o.camera = camera;
  o.threads = 2;
  return render_whitted(s, *tracer, o);
}

void compare_with_golden(const Film& film, const std::string& name) {
  const fs::path golden = golden_dir() / (name + ".png");
  if (updating()) {
    fs::create_directories(golden_dir());
    write_png(golden.string(), film.width, film.height, film.color);
    std::cout << "[golden] wrote " << golden.string() << " (look at it before committing)\n";
    return;
  }
  if (!fs::exists(golden))
    FAIL() << "missing golden " << golden << "; run with SPECULA_UPDATE_GOLDEN=1 to create it";
  int gw = 0, gh = 0;
  const std::vector<Vec3> expected_linear = read_image(golden.string(), gw, gh);
  ASSERT_EQ(gw, film.width) << golden;
  ASSERT_EQ(gh, film.height) << golden;
  const std::vector<uint8_t> expected = to_srgb8(expected_linear, Tonemap::Clamp);
  const std::vector<uint8_t> actual = to_srgb8(film.color, Tonemap::Clamp);
  ASSERT_EQ(expected.size(), actual.size());

  double sum_abs = 0.0;
  size_t bad_pixels = 0;
  std::vector<uint8_t> diff(actual.size());
  const size_t pixels = actual.size() / 3;
  for (size_t i = 0; i < pixels; ++i) {
    int worst = 0;
    for (size_t c = 0; c < 3; ++c) {
      const int d = std::abs(static_cast<int>(actual[3 * i + c]) - static_cast<int>(expected[3 * i + c]));
      sum_abs += d;
      worst = std::max(worst, d);
    }
    if (worst > 8) ++bad_pixels;
    // Diff image: grey for small differences, red for pixels over the threshold.
    const auto v = static_cast<uint8_t>(std::min(255, worst * 16));
    diff[3 * i] = worst > 8 ? 255 : v;
    diff[3 * i + 1] = worst > 8 ? 0 : v;
    diff[3 * i + 2] = worst > 8 ? 0 : v;
  }
  const double mean_abs = sum_abs / static_cast<double>(actual.size());
  const double bad_fraction = static_cast<double>(bad_pixels) / static_cast<double>(pixels);
  const bool ok = mean_abs < 2.0 && bad_fraction < 0.005;
  if (!ok) {
    const fs::path out = fs::temp_directory_path() / "specula-golden";
    fs::create_directories(out);
    const fs::path actual_path = out / (name + ".actual.png"), diff_path = out / (name + ".diff.png");
    write_png(actual_path.string(), film.width, film.height, film.color);
    write_file_atomic(diff_path.string(), encode_png_srgb8(film.width, film.height, diff));
    ADD_FAILURE() << name << ": mean abs error " << mean_abs << "/255 (limit 2), " << 100.0 * bad_fraction
                  << "% pixels off by > 8/255 (limit 0.5%)\n  golden: " << golden.string()
                  << "\n  actual: " << actual_path.string() << "\n  diff:   " << diff_path.string();
  }
}

}  // namespace

TEST(Golden, Cornell) {
  const Scene s = make_builtin_scene("cornell");
  compare_with_golden(render_builtin(s, ""), "cornell");
}

TEST(Golden, Glassbox) {
  const Scene s = make_builtin_scene("glassbox");
  compare_with_golden(render_builtin(s, "front"), "glassbox");
  compare_with_golden(render_builtin(s, "inside"), "glassbox_inside");
}

TEST(Golden, PoolWithTheRealBunny) {
  SPECULA_REQUIRE_MESH(bunny, "stanford-bunny.obj");
  LoadOptions o;
  o.data.cli_dir = bunny.parent_path().string();
  const Scene s = make_builtin_scene("pool", o);
  for (const char* cam : {"overview", "water", "bunny", "parallel"})
    compare_with_golden(render_builtin(s, cam), std::string("pool_") + cam);
}

// The pool traced as voxels (seed 000's views): the octree and the grid return the same hits
// bit for bit, so their films must be identical; the octree's film is compared with a golden.
TEST(Golden, PoolAsVoxels) {
  SPECULA_REQUIRE_MESH(bunny, "stanford-bunny.obj");
  LoadOptions o;
  o.data.cli_dir = bunny.parent_path().string();
  const Scene s = make_builtin_scene("pool", o);
  struct View {
    const char* camera;
    VoxelHitMode mode;
  };
  for (const View v : {View{"water", VoxelHitMode::Cubes}, View{"bunny", VoxelHitMode::Cubes},
                       View{"parallel", VoxelHitMode::Contours}}) {
    SceneVoxelOptions vo;
    vo.depth = 7;
    vo.tracer.mode = v.mode;
    RenderOptions ro;
    ro.width = kWidth;
    ro.height = kHeight;
    ro.camera = v.camera;
    ro.threads = 2;
    vo.kind = "svo";
    const Film svo = render_whitted(s, *voxelize_scene(s, vo), ro);
    vo.kind = "grid";
    const Film grid = render_whitted(s, *voxelize_scene(s, vo), ro);
    ASSERT_EQ(svo.color.size(), grid.color.size());
    size_t differ = 0;
    for (size_t i = 0; i < svo.color.size(); ++i) differ += !(svo.color[i] == grid.color[i]);
    EXPECT_EQ(differ, 0u) << v.camera << ": svo and grid films differ in " << differ << " pixels";
    compare_with_golden(svo, std::string("pool_svo_") + v.camera);
  }
}
