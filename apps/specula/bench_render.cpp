// `specula bench render`: Whitted frame times per camera and image size, with seed 000's GPU
// frame rates for the pool scene beside ours (its table: AMD Radeon HD 6900, sparse voxel
// octree of depth 1-8; "-" where the seed gives no figure).
#include <algorithm>
#include <cmath>
#include <limits>
#include <cstdio>
#include <ctime>
#include <functional>
#include <optional>
#include <sstream>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>
#include <tbb/info.h>

#include "commands.h"
#include "core/format.h"
#include "specula/error.h"
#include "specula/svo.h"

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

/// Refuses a list entry given twice (it would be measured, and printed, twice): \p items
/// parsed from \p option's list, \p text of item i as the user wrote it.
template <class T, class Eq>
void refuse_repeats(const char* option, const std::vector<T>& items, const std::vector<std::string>& text, Eq eq) {
  for (size_t i = 1; i < items.size(); ++i)
    for (size_t j = 0; j < i; ++j)
      if (eq(items[i], items[j]))
        throw Error(std::string(option) + ": '" + text[i] + "' is listed twice" +
                    (text[i] == text[j] ? std::string() : " (as '" + text[j] + "')"));
}

/// The cameras of \p list, each named once.
std::vector<std::string> parse_cameras(const std::string& list) {
  std::vector<std::string> cameras = split_list(list);
  refuse_repeats("--cameras", cameras, cameras, std::equal_to<>());
  return cameras;
}

std::vector<Size> parse_sizes(const std::string& list) {
  std::vector<Size> sizes;
  const std::vector<std::string> text = split_list(list);
  for (const std::string& s : text) {
    Size size;
    char x = 0, extra = 0;
    std::istringstream in(s);
    if (!(in >> size.width >> x >> size.height) || x != 'x' || (in >> extra) || size.width < 1 ||
        size.height < 1 || size.width > 16384 || size.height > 16384)
      throw Error("--sizes: '" + s + "' is not WxH with 1 <= W, H <= 16384 (e.g. 640x480)");
    try {
      check_image_size(size.width, size.height);  // before the scene is loaded
    } catch (const Error& e) {
      throw Error(std::string("--sizes: ") + e.what());
    }
    sizes.push_back(size);
  }
  if (sizes.empty()) throw Error("--sizes: no image size given");
  refuse_repeats("--sizes", sizes, text,
                 [](const Size& a, const Size& b) { return a.width == b.width && a.height == b.height; });
  return sizes;
}

/// Seed 000's frame rates (fps) for octree depths 1..8; negative = no figure.
struct SeedRow {
  const char* camera;
  int width, height;
  double fps[8];
};
constexpr SeedRow kSeed000[] = {
    {"water", 640, 480, {-1, -1, 25, 17, 13, 9.5, 7.4, 6}},
    {"water", 1920, 1200, {-1, -1, 4, 2.7, 2.0, 1.5, 1.21, 1.18}},
    {"bunny", 640, 480, {105, 105, 65, 60, 50, 45, 40, 35}},
    {"bunny", 1920, 1200, {18, 17, 14, 11, 9.8, 7.9, 7.2, 6.0}},
    {"parallel", 640, 480, {-1, -1, 52, 47, 32, 23, 15, 10}},
    {"parallel", 1920, 1200, {-1, -1, 11, 8, 5.5, 3.8, 2.61, 1.94}},
};

std::optional<SeedRow> seed_row(const std::string& scene, const std::string& camera, const Size& size) {
  if (scene != "pool") return std::nullopt;
  for (const SeedRow& r : kSeed000)
    if (camera == r.camera && size.width == r.width && size.height == r.height) return r;
  return std::nullopt;
}

/// The seed's fps at octree depth \p depth in \p row; negative when it gives none.
double seed_fps_at(const std::optional<SeedRow>& row, int depth) {
  return row && depth >= 1 && depth <= 8 ? row->fps[depth - 1] : -1.0;
}

std::string seed_cells(const SeedRow& r) {
  std::string s;
  char buf[16];
  for (const double f : r.fps) {
    if (f < 0) std::snprintf(buf, sizeof buf, "%6s", "-");
    else std::snprintf(buf, sizeof buf, "%6.3g", f);
    s += buf;
  }
  return s;
}

/// Seed 000's frame rates of \p row for depths 1..8 as JSON: null where the seed gives none.
nlohmann::ordered_json seed_json(const SeedRow& row) {
  nlohmann::ordered_json a = nlohmann::ordered_json::array();
  for (const double f : row.fps) a.push_back(f < 0 ? nlohmann::ordered_json() : nlohmann::ordered_json(f));
  return a;
}

/// A measured figure as JSON: null when it is not finite (a PSNR of identical images).
nlohmann::ordered_json number_or_null(double v) {
  return std::isfinite(v) ? nlohmann::ordered_json(v) : nlohmann::ordered_json();
}

/// Process CPU time (all threads) in ms.
double process_cpu_ms() {
  timespec ts{};
  clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &ts);
  return static_cast<double>(ts.tv_sec) * 1e3 + static_cast<double>(ts.tv_nsec) * 1e-6;
}

/// Renders \p frames times; returns the median ms and the last film and stats, and the median
/// CPU time of a frame over all threads in \p cpu_ms when given.
double timed_render(const Scene& scene, const Tracer& tracer, const specula::RenderOptions& ro, int frames, Film& film,
                    RenderStats& stats, double* cpu_ms = nullptr) {
  std::vector<double> ms, cpu;
  for (int f = 0; f < frames; ++f) {
    stats = {};
    const double c0 = process_cpu_ms();
    render_whitted(scene, tracer, ro, film, &stats);  // one film for every frame, as a viewer would
    cpu.push_back(process_cpu_ms() - c0);
    ms.push_back(stats.render_ms);
  }
  if (cpu_ms) *cpu_ms = median(cpu);
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

/// The note after a table with measurements whose camera sits in an occupied voxel (\p list
/// names them; nothing when empty): those time the secondary rays from that voxel, not a view.
void print_camera_in_voxel_note(const std::string& list) {
  if (list.empty()) return;
  std::printf("\ncamera inside an occupied voxel (every primary ray hits it at t = 0 with cubes, and with\n"
              "contours when the camera is inside its slab; such a measurement times the secondary rays\n"
              "from that voxel, not the view): %s\n",
              list.c_str());
}

std::vector<int> parse_depths(const std::string& list) {
  std::vector<int> depths;
  const std::vector<std::string> text = split_list(list);
  for (const std::string& s : text) {
    int d = 0;
    std::istringstream in(s);
    char extra = 0;
    if (!(in >> d) || (in >> extra) || d < 1 || d > 12)
      throw Error("--depths: '" + s + "' is not a depth 1..12 (e.g. 3,4,5,6,7,8)");
    depths.push_back(d);
  }
  if (depths.empty()) throw Error("--depths: no depth given");
  refuse_repeats("--depths", depths, text, std::equal_to<>());
  return depths;
}

}  // namespace

int bench_svo(const BenchSvoOptions& options) {
  refuse_octree_input(options.scene, "bench svo");  // it voxelizes the triangles at each depth
  const std::vector<Size> sizes = parse_sizes(options.sizes);
  const std::vector<int> depths = parse_depths(options.depths);
  specula::RenderOptions ro = options.render;
  const int threads = ro.threads > 0 ? ro.threads : tbb::info::default_concurrency();
  SceneVoxelOptions none;
  std::vector<std::string> cameras = parse_cameras(options.cameras);
  const bool json = options.json;
  std::FILE* const log = json ? stderr : stdout;  // with --json, stdout carries the JSON only
  const PreparedScene prepared = prepare_scene(options.scene, options.load, "bvh", BvhOptions{}, none, ro.threads,
                                               cameras.empty() ? std::vector<std::string>{""} : cameras, log);
  const Scene& scene = prepared.scene;
  if (cameras.empty())
    for (const Camera& c : scene.cameras) cameras.push_back(c.name);

  // Two setups: seed 000's (Whitted without shadow rays, its section 1.7.2), the one compared
  // with its table, and our full Whitted (a shadow ray to every light sample at every hit).
  enum Setup { kSeed = 0, kFull = 1 };
  const auto setup_options = [&](Setup setup) {
    specula::RenderOptions o = ro;
    o.shadows = setup == kFull;
    return o;
  };

  // The reference: the triangles through the BVH, once per view and setup.
  struct View {
    std::string camera;
    Size size;
    Film bvh[2];
  };
  std::vector<View> views;
  for (const std::string& camera : cameras)
    for (const Size& size : sizes) {
      View v{camera, size, {}};
      for (const Setup setup : {kSeed, kFull}) {
        specula::RenderOptions o = setup_options(setup);
        o.camera = camera;
        o.width = size.width;
        o.height = size.height;
        RenderStats st;
        (void)timed_render(scene, *prepared.tracer, o, 1, v.bvh[setup], st);
      }
      views.push_back(std::move(v));
    }

  struct Cell {
    double fps[2][2] = {};   ///< [setup][0 = cubes, 1 = contours]
    double psnr[2][2] = {};
    double rays_per_pixel[2][2] = {};
    double cpu_ms[2][2] = {};  ///< CPU time of a frame, all threads
    bool camera_in_voxel = false;  ///< the camera sits in an occupied voxel (camera_in_voxel, cubes)
  };
  std::vector<std::vector<Cell>> cells(views.size(), std::vector<Cell>(depths.size()));
  const CpuInfo cpu = cpu_info();
  std::fprintf(log, "\nbench svo: %s, %d thread%s, max reflect %d / refract %d, median of %d frame%s per cell\n%s\n",
               options.scene.c_str(), threads, threads == 1 ? "" : "s", ro.max_reflect, ro.max_refract,
               options.frames, options.frames == 1 ? "" : "s", cpu_line(cpu).c_str());
  std::fprintf(log, "  seed 000's setup: Whitted without shadow rays (every light shades every hit unoccluded;\n"
                    "    reflections and refractions traced), as the seed's section 1.7.2 describes its renderer\n"
                    "  full Whitted: the same plus a shadow ray to every light (sample) at every hit\n");
  nlohmann::ordered_json depth_rows = nlohmann::ordered_json::array();
  for (size_t di = 0; di < depths.size(); ++di) {
    SceneVoxelOptions vo;
    vo.kind = "svo";
    vo.depth = depths[di];
    vo.threads = ro.threads;
    vo.memory_limit = options.memory_limit;
    SceneVoxelInfo info;
    const auto svo = voxelize_scene(scene, vo, &info);
    std::fprintf(log, "depth %d: %s voxels, voxelize %.1f ms, octree %.1f ms, %.2f MiB (%.1f bytes/voxel)\n",
                 depths[di], with_thousands(info.voxels).c_str(), info.voxelize_ms, info.build_ms,
                 static_cast<double>(info.bytes) / 1048576.0,
                 info.voxels ? static_cast<double>(info.bytes) / static_cast<double>(info.voxels) : 0.0);
    std::fflush(log);
    depth_rows.push_back({{"depth", depths[di]},
                          {"voxels", info.voxels},
                          {"voxelize_ms", info.voxelize_ms},
                          {"octree_ms", info.build_ms},
                          {"bytes", info.bytes}});
    for (size_t vi = 0; vi < views.size(); ++vi) {
      svo->set_hit_mode(VoxelHitMode::Cubes);
      cells[vi][di].camera_in_voxel = camera_in_voxel(*svo, select_camera(scene, views[vi].camera));
      for (const Setup setup : {kSeed, kFull}) {
        specula::RenderOptions o = setup_options(setup);
        o.camera = views[vi].camera;
        o.width = views[vi].size.width;
        o.height = views[vi].size.height;
        const double pixels = static_cast<double>(o.width) * static_cast<double>(o.height);
        for (const int m : {0, 1}) {
          Film film;
          RenderStats st;
          svo->set_hit_mode(m == 0 ? VoxelHitMode::Cubes : VoxelHitMode::Contours);
          Cell& c = cells[vi][di];
          c.fps[setup][m] =
              1000.0 / std::max(timed_render(scene, *svo, o, options.frames, film, st, &c.cpu_ms[setup][m]), 1e-9);
          c.psnr[setup][m] = psnr(film, views[vi].bvh[setup]);
          c.rays_per_pixel[setup][m] = static_cast<double>(st.total_rays()) / pixels;
        }
      }
    }
  }

  // The score against seed 000's table: cells with a seed figure where ours is faster, in all
  // and outside the camera-inside cells (which time something else than the view).
  struct Score {
    int cells[2] = {}, faster[2] = {};  ///< [0 = cubes, 1 = contours]
    int outside_cells = 0, outside_faster = 0;
  } score;
  for (size_t vi = 0; vi < views.size(); ++vi) {
    const auto row = seed_row(options.scene, views[vi].camera, views[vi].size);
    for (size_t di = 0; di < depths.size(); ++di) {
      const double seed = seed_fps_at(row, depths[di]);
      if (!(seed > 0)) continue;
      for (const int m : {0, 1}) {
        const bool faster = cells[vi][di].fps[kSeed][m] > seed;
        ++score.cells[m];
        score.faster[m] += faster ? 1 : 0;
        if (!cells[vi][di].camera_in_voxel) {
          ++score.outside_cells;
          score.outside_faster += faster ? 1 : 0;
        }
      }
    }
  }

  if (json) {
    nlohmann::ordered_json out = nlohmann::ordered_json::array();
    for (size_t vi = 0; vi < views.size(); ++vi) {
      const auto row = seed_row(options.scene, views[vi].camera, views[vi].size);
      for (size_t di = 0; di < depths.size(); ++di)
        for (const Setup setup : {kSeed, kFull})
          for (const int m : {0, 1}) {
            const Cell& c = cells[vi][di];
            nlohmann::ordered_json r;
            r["camera"] = views[vi].camera;
            r["width"] = views[vi].size.width;
            r["height"] = views[vi].size.height;
            r["depth"] = depths[di];
            r["setup"] = setup == kSeed ? "seed000" : "full_whitted";
            r["hits"] = m == 0 ? "cubes" : "contours";
            r["fps"] = c.fps[setup][m];
            r["cpu_ms_per_frame"] = c.cpu_ms[setup][m];
            r["rays_per_pixel"] = c.rays_per_pixel[setup][m];
            r["psnr_db_vs_bvh"] = number_or_null(c.psnr[setup][m]);
            r["camera_in_voxel"] = c.camera_in_voxel;
            const double seed = seed_fps_at(row, depths[di]);
            if (setup == kSeed && seed > 0) {
              r["seed000_gpu_fps"] = seed;
              r["ratio_seed000"] = c.fps[setup][m] / seed;
            }
            out.push_back(std::move(r));
          }
    }
    nlohmann::ordered_json j;
    j["scene"] = options.scene;
    j["threads"] = threads;
    j["cpu"] = cpu_json(cpu);
    j["frames"] = options.frames;
    j["max_reflect"] = ro.max_reflect;
    j["max_refract"] = ro.max_refract;
    j["setups"] = {{"seed000", "Whitted without shadow rays (seed 000's section 1.7.2)"},
                   {"full_whitted", "the same plus a shadow ray to every light sample at every hit"}};
    j["depths"] = std::move(depth_rows);
    j["cells"] = std::move(out);
    j["seed000_score"] = {{"cells", score.cells[0] + score.cells[1]},
                          {"faster", score.faster[0] + score.faster[1]},
                          {"cubes_cells", score.cells[0]},
                          {"cubes_faster", score.faster[0]},
                          {"contours_cells", score.cells[1]},
                          {"contours_faster", score.faster[1]},
                          {"camera_outside_voxels_cells", score.outside_cells},
                          {"camera_outside_voxels_faster", score.outside_faster}};
    std::printf("%s\n", j.dump(2).c_str());
    return 0;
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
          const double seed = seed_fps_at(row, depths[di]);
          char sb[16];
          if (seed > 0) std::snprintf(sb, sizeof sb, "%.3g", seed);
          else std::snprintf(sb, sizeof sb, "-");
          std::printf("  %7s/%-5s", buf, sb);
        } else {
          std::printf("  %7s", buf);
        }
      }
      std::printf("\n");
    }
  };
  print_table("fps, voxel cubes, seed 000's setup (no shadow rays): ours / seed 000's GPU (AMD Radeon HD 6900); "
              "columns: octree depth",
              [](const Cell& c) { return c.fps[kSeed][0]; }, "%.2f", true);
  print_table("fps, contours, seed 000's setup (no shadow rays): ours / seed 000's GPU",
              [](const Cell& c) { return c.fps[kSeed][1]; }, "%.2f", true);
  print_table("fps, voxel cubes, full Whitted (with shadow rays; the seed traced none)",
              [](const Cell& c) { return c.fps[kFull][0]; }, "%.2f", false);
  print_table("fps, contours, full Whitted (with shadow rays; the seed traced none)",
              [](const Cell& c) { return c.fps[kFull][1]; }, "%.2f", false);
  {  // Cells whose camera sits in an occupied voxel measure something else than a view.
    std::string list;
    std::vector<std::string> seen;
    for (size_t vi = 0; vi < views.size(); ++vi) {
      if (std::find(seen.begin(), seen.end(), views[vi].camera) != seen.end()) continue;
      seen.push_back(views[vi].camera);
      std::string ds;
      int n = 0;
      for (size_t di = 0; di < depths.size(); ++di)
        if (cells[vi][di].camera_in_voxel) ds += (n++ == 0 ? "" : ", ") + std::to_string(depths[di]);
      if (n > 0) list += (list.empty() ? "" : "; ") + views[vi].camera + (n == 1 ? " at depth " : " at depths ") + ds;
    }
    print_camera_in_voxel_note(list);
  }
  if (score.cells[0] + score.cells[1] > 0)
    std::printf("\nfaster than seed 000's GPU in %d of %d cells (cubes %d of %d, contours %d of %d); "
                "with the camera outside the voxels, %d of %d\n",
                score.faster[0] + score.faster[1], score.cells[0] + score.cells[1], score.faster[0], score.cells[0],
                score.faster[1], score.cells[1], score.outside_faster, score.outside_cells);
  print_table("CPU ms per frame (all threads), seed 000's setup, voxel cubes: the work behind the fps above, which "
              "on a shared machine also depends on the other load",
              [](const Cell& c) { return c.cpu_ms[kSeed][0]; }, "%.1f", false);
  print_table("rays per pixel, seed 000's setup, cubes (primary + reflection + refraction)",
              [](const Cell& c) { return c.rays_per_pixel[kSeed][0]; }, "%.2f", false);
  print_table("rays per pixel, full Whitted, cubes (primary + reflection + refraction + shadow)",
              [](const Cell& c) { return c.rays_per_pixel[kFull][0]; }, "%.2f", false);
  print_table("contour cost, seed 000's setup: cube fps / contour fps",
              [](const Cell& c) { return c.fps[kSeed][0] / c.fps[kSeed][1]; }, "%.2fx", false);
  print_table("PSNR (dB) of the cube render against the triangle (BVH) render, seed 000's setup",
              [](const Cell& c) { return c.psnr[kSeed][0]; }, "%.1f", false);
  print_table("PSNR (dB) of the contour render against the triangle (BVH) render, seed 000's setup",
              [](const Cell& c) { return c.psnr[kSeed][1]; }, "%.1f", false);
  print_table("PSNR (dB) of the cube render against the triangle (BVH) render, full Whitted",
              [](const Cell& c) { return c.psnr[kFull][0]; }, "%.1f", false);
  print_table("PSNR (dB) of the contour render against the triangle (BVH) render, full Whitted",
              [](const Cell& c) { return c.psnr[kFull][1]; }, "%.1f", false);
  return 0;
}

int bench_render(const BenchRenderOptions& options) {
  const std::vector<Size> sizes = parse_sizes(options.sizes);
  specula::RenderOptions ro = options.render;
  const int threads = ro.threads > 0 ? ro.threads : tbb::info::default_concurrency();
  // Every camera named is looked up before the build ("": the scene must have one).
  std::vector<std::string> cameras = parse_cameras(options.cameras);
  const bool json = options.json;
  const PreparedScene prepared =
      prepare_scene(options.scene, options.load, options.accel, options.bvh, options.voxel, ro.threads,
                    cameras.empty() ? std::vector<std::string>{""} : cameras, json ? stderr : stdout);
  const Scene& scene = prepared.scene;
  const auto& tracer = prepared.tracer;
  if (cameras.empty())
    for (const Camera& c : scene.cameras) cameras.push_back(c.name);
  const bool voxels = options.accel == "svo" || options.accel == "grid";
  const auto* file_svo = dynamic_cast<const SparseVoxelOctree*>(tracer.get());
  const bool traced_voxels = dynamic_cast<const VoxelTracer*>(tracer.get()) != nullptr;  // --accel or an .svo file
  const std::string accel =
      is_svo_file(options.scene) && file_svo != nullptr
          ? "svo depth " + std::to_string(file_svo->grid().depth) + " " + to_string(file_svo->hit_mode()) + " (file)"
      : voxels ? options.accel + " depth " + std::to_string(options.voxel.depth) + " " + to_string(options.voxel.tracer.mode)
               : options.accel;
  const bool pool = options.scene == "pool";
  const CpuInfo cpu = cpu_info();
  if (!json) {
    std::printf("\nbench render: %s, %s, %d thread%s, max reflect %d / refract %d, median of %d frame%s\n%s\n\n",
                options.scene.c_str(), accel.c_str(), threads, threads == 1 ? "" : "s", ro.max_reflect,
                ro.max_refract, options.frames, options.frames == 1 ? "" : "s", cpu_line(cpu).c_str());
    std::printf("%-10s %-10s %10s %8s %11s %9s", "camera", "size", "ms/frame", "fps", "Mrays/frm", "Mrays/s");
    if (pool) std::printf(" | seed 000 GPU fps, octree depth 1..8               | ours/seed d3  d8");
    std::printf("\n");
  }
  nlohmann::ordered_json results = nlohmann::ordered_json::array();
  std::string inside;  // cameras in an occupied voxel (voxel tracers at coarse depths)

  for (const std::string& camera : cameras) {
    const bool in_voxel = camera_in_voxel(*tracer, select_camera(scene, camera));
    if (in_voxel) inside += (inside.empty() ? "" : ", ") + camera;
    for (const Size& size : sizes) {
      ro.camera = camera;
      ro.width = size.width;
      ro.height = size.height;
      Film film;
      RenderStats stats;
      const double t = timed_render(scene, *tracer, ro, options.frames, film, stats);
      const double fps = 1000.0 / std::max(t, 1e-9);
      const double rays = static_cast<double>(stats.total_rays());
      const auto row = seed_row(options.scene, camera, size);
      // Ours against the seed's depth-3 and depth-8 figures (the table's d3 and d8 columns).
      const double ratio_d3 = row ? fps / row->fps[2] : 0.0;
      const double ratio_d8 = row ? fps / row->fps[7] : 0.0;
      if (json) {
        nlohmann::ordered_json r;
        r["camera"] = camera;
        r["width"] = size.width;
        r["height"] = size.height;
        r["ms_per_frame"] = t;
        r["fps"] = fps;
        r["primary_rays"] = stats.primary_rays;
        r["secondary_rays"] = stats.secondary_rays;
        r["shadow_rays"] = stats.shadow_rays;
        r["mrays_per_s"] = rays / (t * 1e3);
        if (traced_voxels) r["camera_in_voxel"] = in_voxel;
        if (row) {
          r["seed000_gpu_fps"] = seed_json(*row);
          r["ratio_seed000_d3"] = ratio_d3;
          r["ratio_seed000_d8"] = ratio_d8;
        }
        results.push_back(std::move(r));
        continue;
      }
      const std::string size_str = std::to_string(size.width) + "x" + std::to_string(size.height);
      std::printf("%-10s %-10s %10.1f %8.2f %11.2f %9.2f", camera.c_str(), size_str.c_str(), t, fps, rays / 1e6,
                  rays / (t * 1e3));
      if (row) {
        std::printf(" | %s | %8.2fx %6.2fx", seed_cells(*row).c_str(), ratio_d3, ratio_d8);
      }
      std::printf("\n");
      std::fflush(stdout);
    }
  }
  if (json) {
    nlohmann::ordered_json j;
    j["scene"] = options.scene;
    j["accel"] = accel;
    j["threads"] = threads;
    j["cpu"] = cpu_json(cpu);
    j["frames"] = options.frames;
    j["shadows"] = ro.shadows;
    j["max_reflect"] = ro.max_reflect;
    j["max_refract"] = ro.max_refract;
    j["load_ms"] = prepared.load_ms;
    j["build_ms"] = prepared.build_ms;
    j["structure_bytes"] = prepared.bytes;
    if (pool)
      j["seed000"] = "AMD Radeon HD 6900, sparse voxel octree; seed000_gpu_fps lists its fps at depths 1-8 (null: none)";
    j["results"] = std::move(results);
    std::printf("%s\n", j.dump(2).c_str());
    return 0;
  }
  print_camera_in_voxel_note(inside);
  if (pool)
    std::printf("\n(seed 000: AMD Radeon HD 6900, its sparse voxel octree at depths 1-8; ours traces %s. ratio > "
                "1: we are faster)\n",
                traced_voxels ? accel.c_str() : "the full-resolution triangles");
  return 0;
}

}  // namespace specula::cli
