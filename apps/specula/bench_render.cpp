// `specula bench render`: Whitted frame times per camera and image size, with seed 000's GPU
// frame rates for the pool scene beside ours (its table: AMD Radeon HD 6900, sparse voxel
// octree of depth 1-8; "-" where the seed gives no figure).
#include <algorithm>
#include <cstdio>
#include <optional>
#include <sstream>
#include <string>
#include <vector>

#include <tbb/info.h>

#include "commands.h"
#include "core/format.h"
#include "specula/error.h"

namespace specula::cli {

namespace {

struct Size {
  int width = 0, height = 0;
};

std::vector<std::string> split_list(const std::string& list) {
  std::vector<std::string> out;
  std::stringstream ss(list);
  std::string item;
  while (std::getline(ss, item, ','))
    if (!item.empty()) out.push_back(item);
  return out;
}

std::vector<Size> parse_sizes(const std::string& list) {
  std::vector<Size> sizes;
  for (const std::string& s : split_list(list)) {
    Size size;
    char x = 0, extra = 0;
    std::istringstream in(s);
    if (!(in >> size.width >> x >> size.height) || x != 'x' || (in >> extra) || size.width < 1 ||
        size.height < 1 || size.width > 16384 || size.height > 16384)
      throw Error("--sizes: '" + s + "' is not WxH with 1 <= W, H <= 16384 (e.g. 640x480)");
    sizes.push_back(size);
  }
  if (sizes.empty()) throw Error("--sizes: no image size given");
  return sizes;
}

/// Seed 000's frame rates (fps) for octree depths 1..8; negative = no figure.
struct SeedRow {
  const char* camera;
  int width, height;
  float fps[8];
};
constexpr SeedRow kSeed000[] = {
    {"water", 640, 480, {-1, -1, 25, 17, 13, 9.5f, 7.4f, 6}},
    {"water", 1920, 1200, {-1, -1, 4, 2.7f, 2.0f, 1.5f, 1.21f, 1.18f}},
    {"bunny", 640, 480, {105, 105, 65, 60, 50, 45, 40, 35}},
    {"bunny", 1920, 1200, {18, 17, 14, 11, 9.8f, 7.9f, 7.2f, 6.0f}},
    {"parallel", 640, 480, {-1, -1, 52, 47, 32, 23, 15, 10}},
    {"parallel", 1920, 1200, {-1, -1, 11, 8, 5.5f, 3.8f, 2.61f, 1.94f}},
};

std::optional<SeedRow> seed_row(const std::string& scene, const std::string& camera, const Size& size) {
  if (scene != "pool") return std::nullopt;
  for (const SeedRow& r : kSeed000)
    if (camera == r.camera && size.width == r.width && size.height == r.height) return r;
  return std::nullopt;
}

std::string seed_cells(const SeedRow& r) {
  std::string s;
  char buf[16];
  for (const float f : r.fps) {
    if (f < 0) std::snprintf(buf, sizeof buf, "%6s", "-");
    else std::snprintf(buf, sizeof buf, "%6.3g", static_cast<double>(f));
    s += buf;
  }
  return s;
}

}  // namespace

int bench_render(const BenchRenderOptions& options) {
  const std::vector<Size> sizes = parse_sizes(options.sizes);
  specula::RenderOptions ro = options.render;
  const int threads = ro.threads > 0 ? ro.threads : tbb::info::default_concurrency();
  const PreparedScene prepared =
      prepare_scene(options.scene, options.load, options.accel, options.bvh, options.voxel, ro.threads);
  const Scene& scene = prepared.scene;
  const auto& tracer = prepared.tracer;
  if (scene.cameras.empty()) throw Error(options.scene + ": the scene has no camera");
  std::vector<std::string> cameras = split_list(options.cameras);
  if (cameras.empty())
    for (const Camera& c : scene.cameras) cameras.push_back(c.name);
  const bool voxels = options.accel == "svo" || options.accel == "grid";
  std::printf("\nbench render: %s, %s, %d thread%s, max reflect %d / refract %d, median of %d frame%s\n\n",
              options.scene.c_str(),
              voxels ? (options.accel + " depth " + std::to_string(options.voxel.depth) + " " +
                        to_string(options.voxel.tracer.mode))
                           .c_str()
                     : options.accel.c_str(),
              threads, threads == 1 ? "" : "s", ro.max_reflect, ro.max_refract, options.frames,
              options.frames == 1 ? "" : "s");
  const bool pool = options.scene == "pool";
  std::printf("%-10s %-10s %10s %8s %11s %9s", "camera", "size", "ms/frame", "fps", "Mrays/frm", "Mrays/s");
  if (pool) std::printf(" | seed 000 GPU fps, octree depth 1..8               | ours/seed d3  d8");
  std::printf("\n");

  for (const std::string& camera : cameras) {
    for (const Size& size : sizes) {
      ro.camera = camera;
      ro.width = size.width;
      ro.height = size.height;
      std::vector<double> ms;
      RenderStats stats;
      for (int f = 0; f < options.frames; ++f) {
        stats = {};
        (void)render_whitted(scene, *tracer, ro, &stats);
        ms.push_back(stats.render_ms);
      }
      const double t = median(ms);
      const double fps = 1000.0 / std::max(t, 1e-9);
      const double rays = static_cast<double>(stats.total_rays());
      const std::string size_str = std::to_string(size.width) + "x" + std::to_string(size.height);
      std::printf("%-10s %-10s %10.1f %8.2f %11.2f %9.2f", camera.c_str(), size_str.c_str(), t, fps, rays / 1e6,
                  rays / (t * 1e3));
      if (const auto row = seed_row(options.scene, camera, size)) {
        std::printf(" | %s | %8.2fx %6.2fx", seed_cells(*row).c_str(), fps / static_cast<double>(row->fps[2]),
                    fps / static_cast<double>(row->fps[7]));
      }
      std::printf("\n");
      std::fflush(stdout);
    }
  }
  if (pool)
    std::printf("\n(seed 000: AMD Radeon HD 6900, its sparse voxel octree at depths 1-8; ours traces the full-"
                "resolution triangles. ratio > 1: we are faster)\n");
  return 0;
}

}  // namespace specula::cli
