// specula: command-line renderer, tracer and benchmark.
//
//   specula render SCENE [-o out.png] [--camera NAME] [--width W --height H] ...
//   specula trace  SCENE --rays FILE [--stats] [--repeat N] [--threads N]
//   specula info   SCENE
//   specula bench  trace [--scene pool] [--mesh FILE]
//   specula bench  render [--scene pool] [--cameras a,b] [--sizes 640x480,1920x1200] [--frames N]
//   specula bench  svo [--depths 3,4,5,6,7,8] [--cameras water,bunny,parallel] [--sizes ...]
//   specula voxelize SCENE --depth D [--tests aabb,plane,sat] [--sat-at leaf|all] [--table] ...
//
// Argument parsing is CLI11; every subcommand throws specula::Error for user errors, which
// main prints as "specula: error: ..." with exit code 1 (2 for usage errors).
#include <pthread.h>
#include <signal.h>
#include <unistd.h>

#include <CLI/CLI.hpp>
#include <algorithm>
#include <cerrno>
#include <cstdio>
#include <cstring>
#include <cstdlib>
#include <filesystem>
#include <iostream>
#include <string>
#include <string_view>
#include <thread>

#include "commands.h"
#include "specula/error.h"
#include "specula/image.h"
#include "specula/load.h"

namespace {

using namespace specula;

/// Ctrl-C (SIGINT), SIGTERM and SIGHUP stop the program at once, wherever it is (loading,
/// building, rendering, writing), and leave every output either as it was or complete: the
/// signals are blocked in every thread but one, which waits for them, removes the temporary
/// files of atomic writes in progress (stop_atomic_writes), says so and exits with status
/// 128 + the signal number (130 for Ctrl-C). Call before any other thread exists.
void stop_cleanly_on_signals() {
  sigset_t set;
  sigemptyset(&set);
  for (int sig : {SIGINT, SIGTERM, SIGHUP}) sigaddset(&set, sig);
  if (pthread_sigmask(SIG_BLOCK, &set, nullptr) != 0) return;  // keep the default actions
  std::thread([set] {
    int sig = 0;
    while (sigwait(&set, &sig) != 0) {
    }
    stop_atomic_writes();
    const char* name = sig == SIGINT ? "SIGINT" : sig == SIGTERM ? "SIGTERM" : "SIGHUP";
    std::fprintf(stderr, "\nspecula: interrupted (%s): stopped; outputs are unchanged or complete\n", name);
    std::fflush(stderr);
    _exit(128 + sig);
  }).detach();
}

constexpr const char* kSceneHelp =
    "a built-in scene (pool, glassbox, cornell, city = a ~600k-triangle town, city:N = a town of about N "
    "triangles, 10000 <= N <= 20000000), a JSON scene (.json), a glTF file (.gltf/.glb) "
    "or a bare mesh (.obj/.ply; gets a framing camera, a light and a default material)";

/// An option taking a size in bytes ("8GiB", "512MiB", "1.5G"; parse_byte_size); a malformed
/// value is a usage error (exit 2) naming the option.
CLI::Option* add_size_option(CLI::App* app, const std::string& name, uint64_t& target, const std::string& help) {
  return app
      ->add_option_function<std::string>(
          name,
          [&target, name](const std::string& text) {
            try {
              target = parse_byte_size(text);
            } catch (const specula::Error& e) {
              throw CLI::ValidationError(name, e.what());
            }
          },
          help)
      ->type_name("SIZE")
      ->default_str(format_bytes(target));
}

/// --memory-limit of the commands that voxelize a scene (render and bench render with --accel
/// svo|grid, bench svo); `voxelize` has its own, with --no-memory-limit.
void add_memory_limit_option(CLI::App* app, uint64_t& target, const std::string& when) {
  add_size_option(app, "--memory-limit", target,
                  when + "refuse up front when the voxelizer's memory estimate exceeds this; units K, M, G, T "
                  "(powers of 1024); 0 = half the physical memory")
      ->default_str("0 = " + format_bytes(specula::default_voxelize_memory_limit()));
}

/// Input limits (docs/SECURITY.md, "Limits"): every command that loads a scene takes them.
void add_limit_options(CLI::App* app, LoadOptions& load) {
  add_size_option(app, "--max-file-size", load.limits.max_file_bytes,
                  "refuse input files (scene, mesh, MTL, glTF buffer, sky image, .svo) larger than this; units K, M, "
                  "G, T (powers of 1024), e.g. 8GiB");
  app->add_option_function<std::string>(
         "--max-elements",
         [&load](const std::string& text) {
           // At most 19 digits, so std::stoull cannot throw; the range is checked below.
           const bool digits = !text.empty() && text.size() <= 19 &&
                               std::all_of(text.begin(), text.end(), [](char c) { return c >= '0' && c <= '9'; });
           const unsigned long long v = digits ? std::stoull(text) : 0;
           if (!digits || v == 0 || v > kMaxElementsCeiling)
             throw CLI::ValidationError("--max-elements", "'" + text + "': expected a whole number from 1 to " +
                                                             std::to_string(kMaxElementsCeiling) +
                                                             " (vertex indices are 32-bit)");
           load.limits.max_elements = v;
         },
         "refuse scenes with more vertices, or more triangle indices (3 per triangle), than this")
      ->type_name("N")
      ->default_str(std::to_string(load.limits.max_elements));
  add_size_option(app, "--max-image-memory", load.limits.max_image_bytes,
                  "refuse sky images whose decoding would take more memory than this (estimated from the header "
                  "before decoding), e.g. 4GiB");
}

void add_data_option(CLI::App* app, LoadOptions& load) {
  app->add_option("--data", load.data.cli_dir,
                  "folder searched first for meshes of built-in scenes (then $SPECULA_DATA, then "
                  "../shared/data/meshes beside the source tree)")
      ->check(CLI::ExistingDirectory);
  add_limit_options(app, load);
}

void add_bvh_options(CLI::App* app, BvhOptions& bvh) {
  app->add_option("--bins", bvh.bins, "most SAH bins per axis for the BVH build (a node of n triangles uses 4 + n/20)")
      ->check(CLI::Range(2, 256))
      ->capture_default_str();
  app->add_option("--max-leaf", bvh.max_leaf_size, "largest BVH leaf (triangles)")
      ->check(CLI::Range(1, 255))
      ->capture_default_str();
  app->add_option_function<std::string>(
         "--bvh-kernel", [&bvh](const std::string& k) { bvh.kernel = parse_bvh_kernel(k); },
         "BVH traversal kernel: auto (the best this CPU runs), sse4 (4-wide nodes, SSE), avx2x8 (8-wide "
         "nodes, AVX2), avx512x8 (8-wide nodes, AVX-512VL registers) or avx512x16 (16-wide nodes, "
         "AVX-512); all give bit-identical results")
      ->check(CLI::IsMember({"auto", "sse4", "avx2x8", "avx512x8", "avx512x16"}))
      ->default_str("auto");
  app->add_option_function<std::string>(
         "--bvh-quality", [&bvh](const std::string& q) { bvh.quality = parse_bvh_quality(q); },
         "BVH build: fast (binned SAH) or high (binned SAH, then subtree reinsertion: lower SAH cost and "
         "faster rays for static scenes, a slower build); the same hits either way")
      ->check(CLI::IsMember({"fast", "high"}))
      ->default_str("fast");
}

/// Refuses options of one acceleration structure given with another, or with an .svo file,
/// which they would not change (render, bench render): given, not only at their defaults.
void refuse_unused_structure_options(const CLI::App* cmd, const std::string& scene, const std::string& accel) {
  const bool svo_file = cli::is_svo_file(scene);
  if (svo_file && cmd->count("--accel") > 0 && accel != "svo")
    throw specula::Error("--accel " + accel + ": " + scene + " holds voxels, not triangles; it is traced by its octree "
                         "(--accel svo, the default for .svo files)");
  for (const char* o : {"--bins", "--max-leaf", "--bvh-kernel", "--bvh-quality"}) {
    if (cmd->count(o) == 0) continue;
    if (svo_file) throw specula::Error(std::string(o) + ": " + scene + " is traced by its octree; BVH options apply to triangle scenes");
    if (accel != "bvh") throw specula::Error(std::string(o) + " applies to --accel bvh, not '" + accel + "'");
  }
  if (!svo_file && cmd->count("--voxel-mode") > 0 && accel != "svo" && accel != "grid")
    throw specula::Error("--voxel-mode applies to --accel svo|grid, not '" + accel + "'");
  if (!svo_file && cmd->count("--lod") > 0 && accel != "svo")
    throw specula::Error(accel == "grid" ? std::string("--lod needs --accel svo: the voxel grid has no coarser levels")
                                         : "--lod applies to --accel svo, not '" + accel + "'");
  for (const char* o : {"--depth", "--memory-limit", "--max-grid-memory"}) {
    if (cmd->count(o) == 0) continue;
    if (svo_file)
      throw specula::Error(std::string(o) + ": " + scene + " is voxelized already (its depth is the one voxelize gave it)");
    const bool grid_only = std::string(o) == "--max-grid-memory";
    if (grid_only ? accel != "grid" : accel != "svo" && accel != "grid")
      throw specula::Error(std::string(o) + " applies to --accel " + (grid_only ? "grid" : "svo|grid") + ", not '" +
                           accel + "'");
  }
}

/// --accel, --max-reflect, --max-refract, --threads: what every Whitted rendering command takes.
void add_integrator_options(CLI::App* app, std::string& accel, specula::RenderOptions& ro, SceneVoxelOptions& voxel) {
  app->add_option("--accel", accel,
                  "acceleration structure: bvh, brute (every triangle: the test oracle), svo (sparse voxel "
                  "octree) or grid (voxel grid, DDA); svo and grid voxelize the scene at --depth")
      ->check(CLI::IsMember({"bvh", "brute", "svo", "grid"}))
      ->capture_default_str();
  app->add_option("--depth", voxel.depth, "voxel depth for --accel svo|grid: 2^depth voxels along the scene's largest side")
      ->check(CLI::Range(1, kMaxVoxelDepth))
      ->capture_default_str();
  app->add_option_function<std::string>(
         "--voxel-mode", [&voxel](const std::string& m) { voxel.tracer.mode = parse_voxel_hit_mode(m); },
         "what a ray hits in a voxel: cubes, or contours (the slab between seed 000's two contour planes)")
      ->check(CLI::IsMember({"cubes", "contours"}))
      ->default_str("cubes");
  add_size_option(app, "--max-grid-memory", voxel.tracer.max_grid_bytes,
                  "--accel grid: refuse a voxel grid larger than this (its brick table alone takes 64 MiB at depth 11, 512 MiB at depth 12)");
  add_memory_limit_option(app, voxel.memory_limit, "--accel svo|grid: ");
  app->add_option("--lod", voxel.tracer.lod, "octree level of detail: trace nodes at this depth as leaves (0 = full depth)")
      ->check(CLI::Range(0, kMaxVoxelDepth))
      ->capture_default_str();
  app->add_option("--max-reflect", ro.max_reflect, "maximum mirror bounces per path")
      ->check(CLI::Range(0, 64))
      ->capture_default_str();
  app->add_option("--max-refract", ro.max_refract, "maximum refractions per path")
      ->check(CLI::Range(0, 64))
      ->capture_default_str();
  app->add_option("--threads", ro.threads, "worker threads (0 = all cores)")
      ->check(CLI::Range(0, 1024))
      ->capture_default_str();
  app->add_flag("!--no-shadows", ro.shadows,
                "trace no shadow rays: lights shade every hit as if unoccluded (seed 000's Whitted setup)");
}

}  // namespace

/// Prints "specula: error: MESSAGE" after what the command printed so far: the standard output
/// is flushed first, so a log of both streams (2>&1 into a file or a pipe, where the standard
/// output is buffered) shows the error after the lines that preceded it, not before them.
static void report_error(const char* message) {
  std::fflush(stdout);
  std::fprintf(stderr, "specula: error: %s\n", message);
}

/// The whole program but the signal set-up; main() catches what building the options may throw.
static int run(int argc, char** argv) {
  CLI::App app{
      "specula: real-time CPU ray tracing of reflections and refractions.\n"
      "Renders scenes with a Whitted ray tracer over a binned-SAH BVH, a sparse voxel octree or a\n"
      "voxel grid; voxelizes meshes; traces ray files; benchmarks tracing (against Embree when it\n"
      "is installed) and frame rates. Run 'specula COMMAND --help'."};
  app.require_subcommand(1);
  app.set_version_flag("--version", "specula 0.1.0");
  // Usage errors read like every other error ("specula: error: ...") and point at the help of
  // the command that was given. Set before the commands are added, which inherit it.
  app.failure_message([](const CLI::App* top, const CLI::Error& e) {
    std::string command = "specula";
    for (const CLI::App* a = top; !a->get_subcommands().empty();) {
      a = a->get_subcommands().front();
      command += " " + a->get_name();
    }
    return "specula: error: " + std::string(e.what()) + "\nRun '" + command + " --help' for the options.\n";
  });

  // render
  cli::RenderOptions render;
  CLI::App* render_cmd = app.add_subcommand(
      "render", "Render SCENE with the Whitted integrator and print load, build and render timings");
  render_cmd->add_option("scene", render.scene, kSceneHelp)->required();
  render_cmd->add_option("-o,--output", render.output, "output image: .png (sRGB) or .exr (linear)")
      ->capture_default_str();
  render_cmd->add_option("--camera", render.render.camera, "camera name (default: the scene's first)");
  render_cmd->add_option("--width", render.render.width, "image width in pixels")
      ->check(CLI::Range(1, 32768))
      ->capture_default_str();
  render_cmd->add_option("--height", render.render.height, "image height in pixels")
      ->check(CLI::Range(1, 32768))
      ->capture_default_str();
  add_integrator_options(render_cmd, render.accel, render.render, render.voxel);
  render_cmd->add_option("--aov", render.aovs,
                         "extra outputs written beside the image: depth,normal,prim,cost "
                         "(cost = BVH nodes visited per pixel, as a heat map)");
  render_cmd->add_option("--tonemap", render.tonemap, "PNG tone mapping: clamp or reinhard")
      ->check(CLI::IsMember({"clamp", "reinhard"}))
      ->capture_default_str();
  render_cmd->add_option("--frames", render.frames,
                         "render the frame N times and report the median (for fps figures)")
      ->check(CLI::Range(1, 1000))
      ->capture_default_str();
  add_data_option(render_cmd, render.load);
  add_bvh_options(render_cmd, render.bvh);

  // trace
  cli::TraceOptions trace;
  CLI::App* trace_cmd = app.add_subcommand(
      "trace",
      "Trace rays from a text file ('ox oy oz dx dy dz' per line; tmin 0, tmax infinity) and print "
      "'t prim_id' per hit (prim_id = triangle index in file order) or 'miss'");
  trace_cmd->add_option("scene", trace.scene, kSceneHelp)->required();
  trace_cmd->add_option("--rays", trace.rays, "ray file ('-' = standard input)")->required();
  trace_cmd->add_option("--accel", trace.accel, "acceleration structure: bvh or brute")
      ->check(CLI::IsMember({"bvh", "brute"}))
      ->capture_default_str();
  trace_cmd->add_flag("--stats", trace.stats,
                      "print load ms, build ms, trace ms and Mrays/s of the tracing alone to stderr");
  trace_cmd->add_option("--repeat", trace.repeat, "trace passes; the median time is printed")
      ->check(CLI::Range(1, 10000))
      ->capture_default_str();
  trace_cmd->add_option("--threads", trace.threads, "tracing threads (default 1)")
      ->check(CLI::Range(0, 1024))
      ->capture_default_str();
  add_data_option(trace_cmd, trace.load);
  add_bvh_options(trace_cmd, trace.bvh);

  // info
  cli::InfoOptions info;
  CLI::App* info_cmd = app.add_subcommand(
      "info", "Print what the loader saw: meshes, triangles, materials, lights, cameras, bounds; for an .svo octree "
              "file (voxelize -o): depth, bounds, voxels, nodes and memory");
  info_cmd->add_option("scene", info.scene, kSceneHelp)->required();
  add_data_option(info_cmd, info.load);

  // bench
  CLI::App* bench_cmd = app.add_subcommand("bench", "Benchmarks: 'specula bench trace' (ray tracing throughput, vs Embree), 'specula bench render' (frame rates) and 'specula bench svo' (seed 000's octree frame-rate table)");
  bench_cmd->require_subcommand(1);
  cli::BenchTraceOptions bench;
  CLI::App* bench_trace_cmd = bench_cmd->add_subcommand(
      "trace",
      "BVH build ms and Mrays/s for primary, shadow, reflection, refraction, diffuse bounce and random "
      "rays, one thread and all threads; the same rays through Embree side by side when it is compiled in, and "
      "the SAH cost of the tree Embree's binned SAH builder makes for the same objective");
  CLI::Option* trace_scene = bench_trace_cmd->add_option("--scene", bench.scene, kSceneHelp)->capture_default_str();
  bench_trace_cmd->add_option("--mesh", bench.mesh, "bench a bare mesh instead of --scene")->excludes(trace_scene);
  bench_trace_cmd->add_option("--width", bench.width, "ray grid width")
      ->check(CLI::Range(1, 16384))
      ->capture_default_str();
  bench_trace_cmd->add_option("--height", bench.height, "ray grid height")
      ->check(CLI::Range(1, 16384))
      ->capture_default_str();
  bench_trace_cmd->add_option("--threads", bench.threads, "threads for the all-threads column (0 = all)")
      ->check(CLI::Range(0, 1024))
      ->capture_default_str();
  bench_trace_cmd->add_option("--repeat", bench.repeat, "passes per measurement (median printed)")
      ->check(CLI::Range(1, 1000))
      ->capture_default_str();
  CLI::Option* no_embree = bench_trace_cmd->add_flag("!--no-embree", bench.embree, "do not run the Embree comparison");
  bench_trace_cmd->add_flag("--embree-robust", bench.embree_robust,
                            "build Embree's scene with RTC_SCENE_FLAG_ROBUST (robust traversal, no optimisations "
                            "that reduce accuracy: against rays slipping between neighbouring triangles), the "
                            "closest Embree comes to our watertight triangle test; by default it runs its faster, "
                            "non-watertight one")
      ->excludes(no_embree);
  bench_trace_cmd->add_flag("--json", bench.json,
                            "print the results as one JSON object (scene, BVH figures, per ray kind: Mrays/s "
                            "of specula and Embree on 1 and all threads, ratios) instead of the table");
  add_data_option(bench_trace_cmd, bench.load);
  add_bvh_options(bench_trace_cmd, bench.bvh);

  cli::BenchRenderOptions bench_render;
  CLI::App* bench_render_cmd = bench_cmd->add_subcommand(
      "render",
      "Whitted frame time, fps and Mrays/s per camera and image size (median of --frames); for the "
      "pool scene, seed 000's GPU frame rates beside ours");
  bench_render_cmd->add_option("--scene", bench_render.scene, kSceneHelp)->capture_default_str();
  bench_render_cmd->add_option("--cameras", bench_render.cameras,
                               "comma-separated camera names (default: every camera of the scene)");
  bench_render_cmd->add_option("--sizes", bench_render.sizes, "comma-separated image sizes WxH")
      ->capture_default_str();
  bench_render_cmd->add_option("--frames", bench_render.frames, "frames per cell (median printed)")
      ->check(CLI::Range(1, 1000))
      ->capture_default_str();
  add_integrator_options(bench_render_cmd, bench_render.accel, bench_render.render, bench_render.voxel);
  bench_render_cmd->add_flag("--json", bench_render.json,
                             "print the results as one JSON object (settings, load and build ms, per camera and "
                             "size: ms per frame, fps, rays by kind, Mrays/s, seed 000's fps) instead of the table; "
                             "the load lines go to stderr");
  add_data_option(bench_render_cmd, bench_render.load);
  add_bvh_options(bench_render_cmd, bench_render.bvh);

  cli::BenchSvoOptions bench_svo;
  CLI::App* bench_svo_cmd = bench_cmd->add_subcommand(
      "svo",
      "Seed 000's frame-rate table: the scene voxelized at each --depths, rendered through the sparse voxel "
      "octree (cubes and contours) per camera and size, ours beside the seed's GPU figures, plus the contour cost "
      "and the PSNR against the triangle render");
  bench_svo_cmd->add_option("--scene", bench_svo.scene, kSceneHelp)->capture_default_str();
  bench_svo_cmd->add_option("--cameras", bench_svo.cameras, "comma-separated camera names (default: all)");
  bench_svo_cmd->add_option("--sizes", bench_svo.sizes, "comma-separated image sizes WxH")->capture_default_str();
  bench_svo_cmd->add_option("--depths", bench_svo.depths, "comma-separated octree depths")->capture_default_str();
  bench_svo_cmd->add_option("--frames", bench_svo.frames, "frames per cell (median printed)")
      ->check(CLI::Range(1, 1000))
      ->capture_default_str();
  bench_svo_cmd->add_option("--threads", bench_svo.render.threads, "worker threads (0 = all cores)")
      ->check(CLI::Range(0, 1024))
      ->capture_default_str();
  add_memory_limit_option(bench_svo_cmd, bench_svo.memory_limit, "each depth: ");
  bench_svo_cmd->add_flag("--json", bench_svo.json,
                          "print the results as one JSON object (per depth: voxels, voxelize and octree ms, bytes; "
                          "per view, depth, setup and hit mode: fps, CPU ms, rays per pixel, PSNR, seed 000's fps) "
                          "instead of the tables; the progress lines go to stderr");
  add_data_option(bench_svo_cmd, bench_svo.load);

  // voxelize
  cli::VoxelizeCommandOptions voxelize;
  CLI::App* voxelize_cmd = cli::add_voxelize_command(app, voxelize);
  add_data_option(voxelize_cmd, voxelize.load);

  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    // No command at all ('specula', 'specula bench'): the help that lists the commands rather
    // than only "A subcommand is required"; still a usage error.
    if (dynamic_cast<const CLI::RequiredError*>(&e) != nullptr) {
      const CLI::App* bare = app.get_subcommands().empty()                                      ? &app
                             : bench_cmd->parsed() && bench_cmd->get_subcommands().empty() ? bench_cmd
                                                                                            : nullptr;
      if (bare != nullptr) {
        // A word where the command belongs ('specula frob', 'specula bench tarce') is named, with
        // the commands there are; nothing at all gets the help that lists them.
        int at = 1;
        if (bare != &app) {
          while (at < argc && std::string_view(argv[at]) != bare->get_name()) ++at;
          ++at;
        }
        if (at < argc && argv[at][0] != '-') {
          std::string names;
          for (const CLI::App* sub : bare->get_subcommands({}))
            names += (names.empty() ? "" : ", ") + sub->get_name();
          const std::string path = bare == &app ? "specula" : "specula " + bare->get_name();
          std::fprintf(stderr, "specula: error: '%s' is not a%s command (%s)\nRun '%s --help' for the options.\n",
                       argv[at], bare == &app ? "" : (" " + bare->get_name()).c_str(), names.c_str(), path.c_str());
          return 2;
        }
        std::fputs(bare->help(bare == &app ? "" : app.get_name()).c_str(), stderr);
        return 2;
      }
    }
    // --help and --version exit 0; every usage error exits 2 (CLI11's own codes are 100+).
    return app.exit(e) == 0 ? 0 : 2;
  }

  // A mistyped $SPECULA_DATA would otherwise be skipped without a word, and the meshes taken
  // from the next folder of the search path.
  if (const char* env = std::getenv("SPECULA_DATA"); env != nullptr && *env != '\0') {
    std::error_code ec;
    if (!std::filesystem::is_directory(env, ec))
      std::fprintf(stderr, "warning: SPECULA_DATA=%s is not a folder; it is not searched for meshes\n", env);
  }

  int rc = 0;
  try {
    if (render_cmd->parsed()) {
      refuse_unused_structure_options(render_cmd, render.scene, render.accel);
      rc = cli::render(render);
    }
    else if (trace_cmd->parsed()) rc = cli::trace(trace);
    else if (info_cmd->parsed()) rc = cli::info(info);
    else if (bench_trace_cmd->parsed()) rc = cli::bench_trace(bench);
    else if (bench_render_cmd->parsed()) {
      refuse_unused_structure_options(bench_render_cmd, bench_render.scene, bench_render.accel);
      rc = cli::bench_render(bench_render);
    }
    else if (bench_svo_cmd->parsed()) rc = cli::bench_svo(bench_svo);
    else if (voxelize_cmd->parsed()) rc = cli::voxelize(voxelize);
  } catch (const specula::Error& e) {
    report_error(e.what());
    rc = 1;
  } catch (const std::bad_alloc&) {
    report_error("out of memory");
    rc = 1;
  } catch (const std::exception& e) {
    report_error(e.what());
    rc = 1;
  }
  // Results go to the standard output (trace hits, voxelize --format xyz, bench --json): a write
  // that failed there (a full disk) must not end in success with a truncated result.
  errno = 0;
  const bool flushed = std::fflush(stdout) == 0;
  if (!flushed || std::ferror(stdout)) {
    const int err = errno;
    std::fprintf(stderr, "specula: error: writing the standard output failed%s%s\n", !flushed && err ? ": " : "",
                 !flushed && err ? std::strerror(err) : "");
    return 1;
  }
  return rc;
}

int main(int argc, char** argv) {
  stop_cleanly_on_signals();
  try {
    return run(argc, argv);
  } catch (const std::exception& e) {  // setting up the options allocates: nothing escapes main
    std::fprintf(stderr, "specula: error: %s\n", e.what());
  } catch (...) {
    std::fprintf(stderr, "specula: error: unknown exception\n");
  }
  return 1;
}
