// `specula bench render`: Whitted frame times per camera and image size, with seed 000's GPU
// frame rates for the pool scene beside ours (its table: AMD Radeon HD 6900, sparse voxel
// octree of depth 1-8; "-" where the seed gives no figure).
#include <algorithm>
#include <cmath>
#include <limits>
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

/// Renders \p frames times; returns the median ms and the last film and stats.
double timed_render(const Scene& scene, const Tracer& tracer, const specula::RenderOptions& ro, int frames, Film& film,
                    RenderStats& stats) {
  std::vector<double> ms;
  for (int f = 0; f < frames; ++f) {
    stats = {};
    film = render_whitted(scene, tracer, ro, &stats);
    ms.push_back(stats.render_ms);
  }
  return median(ms);
}

/// PSNR (dB) of \p a against \p b, colours clamped to [0, 1] (what a PNG shows); inf if equal.
double psnr(const Film& a, const Film& b) {
  double se = 0.0;
  for (size_t i = 0; i < a.color.size(); ++i)
    for (int c = 0; c < 3; ++c) {
      const double d = std::clamp(static_cast<double>(a.color[i][c]), 0.0, 1.0) -
                       std::clamp(static_cast<double>(b.color[i][c]), 0.0, 1.0);
      se += d * d;
    }
  const double mse = se / (3.0 * static_cast<double>(std::max<size_t>(a.color.size(), 1)));
  return mse > 0.0 ? 10.0 * std::log10(1.0 / mse) : std::numeric_limits<double>::infinity();
}

std::vector<int> parse_depths(const std::string& list) {
  std::vector<int> depths;
  for (const std::string& s : split_list(list)) {
    int d = 0;
    std::istringstream in(s);
    char extra = 0;
    if (!(in >> d) || (in >> extra) || d < 1 || d > 12)
      throw Error("--depths: '" + s + "' is not a depth 1..12 (e.g. 3,4,5,6,7,8)");
    depths.push_back(d);
  }
  if (depths.empty()) throw Error("--depths: no depth given");
  return depths;
}

}  // namespace

int bench_svo(const BenchSvoOptions& options) {
  const std::vector<Size> sizes = parse_sizes(options.sizes);
  const std::vector<int> depths = parse_depths(options.depths);
  specula::RenderOptions ro = options.render;
  const int threads = ro.threads > 0 ? ro.threads : tbb::info::default_concurrency();
  SceneVoxelOptions none;
  const PreparedScene prepared = prepare_scene(options.scene, options.load, "bvh", BvhOptions{}, none, ro.threads);
  const Scene& scene = prepared.scene;
  std::vector<std::string> cameras = split_list(options.cameras);
  if (cameras.empty())
    for (const Camera& c : scene.cameras) cameras.push_back(c.name);

  // The reference: the triangles through the BVH, once per view.
  struct View {
    std::string camera;
    Size size;
    Film bvh;
  };
  std::vector<View> views;
  for (const std::string& camera : cameras)
    for (const Size& size : sizes) {
      ro.camera = camera;
      ro.width = size.width;
      ro.height = size.height;
      View v{camera, size, {}};
      RenderStats st;
      (void)timed_render(scene, *prepared.tracer, ro, 1, v.bvh, st);
      views.push_back(std::move(v));
    }

  struct Cell {
    double cube_fps = 0, contour_fps = 0, cube_psnr = 0, contour_psnr = 0;
  };
  std::vector<std::vector<Cell>> cells(views.size(), std::vector<Cell>(depths.size()));
  std::printf("\nbench svo: %s, %d thread%s, max reflect %d / refract %d, median of %d frame%s per cell\n",
              options.scene.c_str(), threads, threads == 1 ? "" : "s", ro.max_reflect, ro.max_refract, options.frames,
              options.frames == 1 ? "" : "s");
  for (size_t di = 0; di < depths.size(); ++di) {
    SceneVoxelOptions vo;
    vo.kind = "svo";
    vo.depth = depths[di];
    vo.threads = ro.threads;
    SceneVoxelInfo info;
    const auto svo = voxelize_scene(scene, vo, &info);
    std::printf("depth %d: %s voxels, voxelize %.1f ms, octree %.1f ms, %.2f MiB (%.1f bytes/voxel)\n", depths[di],
                with_thousands(info.voxels).c_str(), info.voxelize_ms, info.build_ms,
                static_cast<double>(info.bytes) / 1048576.0,
                info.voxels ? static_cast<double>(info.bytes) / static_cast<double>(info.voxels) : 0.0);
    std::fflush(stdout);
    for (size_t vi = 0; vi < views.size(); ++vi) {
      ro.camera = views[vi].camera;
      ro.width = views[vi].size.width;
      ro.height = views[vi].size.height;
      Film film;
      RenderStats st;
      svo->set_hit_mode(VoxelHitMode::Cubes);
      cells[vi][di].cube_fps = 1000.0 / std::max(timed_render(scene, *svo, ro, options.frames, film, st), 1e-9);
      cells[vi][di].cube_psnr = psnr(film, views[vi].bvh);
      svo->set_hit_mode(VoxelHitMode::Contours);
      cells[vi][di].contour_fps = 1000.0 / std::max(timed_render(scene, *svo, ro, options.frames, film, st), 1e-9);
      cells[vi][di].contour_psnr = psnr(film, views[vi].bvh);
    }
  }

  const auto print_table = [&](const char* title, auto value, const char* fmt, bool with_seed) {
    std::printf("\n%s\n%-22s", title, "view");
    for (const int d : depths) std::printf(with_seed ? "  %13d" : "  %7d", d);
    std::printf("\n");
    for (size_t vi = 0; vi < views.size(); ++vi) {
      const std::string label =
          views[vi].camera + " (" + std::to_string(views[vi].size.width) + "x" + std::to_string(views[vi].size.height) + ")";
      std::printf("%-22s", label.c_str());
      const auto row = seed_row(options.scene, views[vi].camera, views[vi].size);
      for (size_t di = 0; di < depths.size(); ++di) {
        char buf[48];
        std::snprintf(buf, sizeof buf, fmt, value(cells[vi][di]));
        if (with_seed) {
          const float seed = row && depths[di] <= 8 ? row->fps[depths[di] - 1] : -1.0f;
          char sb[16];
          if (seed > 0) std::snprintf(sb, sizeof sb, "%.3g", static_cast<double>(seed));
          else std::snprintf(sb, sizeof sb, "-");
          std::printf("  %7s/%-5s", buf, sb);
        } else {
          std::printf("  %7s", buf);
        }
      }
      std::printf("\n");
    }
  };
  print_table("fps, voxel cubes (ours / seed 000's GPU, AMD Radeon HD 6900; columns: octree depth)",
              [](const Cell& c) { return c.cube_fps; }, "%.2f", true);
  print_table("fps, contours (ours / seed 000's GPU)", [](const Cell& c) { return c.contour_fps; }, "%.2f", true);
  print_table("contour cost: cube fps / contour fps", [](const Cell& c) { return c.cube_fps / c.contour_fps; }, "%.2fx",
              false);
  print_table("PSNR (dB) of the cube render against the triangle (BVH) render",
              [](const Cell& c) { return c.cube_psnr; }, "%.1f", false);
  print_table("PSNR (dB) of the contour render against the triangle (BVH) render",
              [](const Cell& c) { return c.contour_psnr; }, "%.1f", false);
  return 0;
}

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
