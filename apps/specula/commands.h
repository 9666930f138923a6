// Subcommands of the specula CLI. main.cpp parses arguments (CLI11) and calls these; each
// returns the process exit code and throws specula::Error for user errors.
#pragma once

#include <cstdio>
#include <functional>
#include <memory>
#include <mutex>
#include <string>
#include <vector>

#include <nlohmann/json_fwd.hpp>

#include "specula/accel.h"
#include "specula/load.h"
#include "specula/render.h"
#include "specula/timer.h"
#include "specula/voxel_scene.h"
#include "specula/voxelize.h"

namespace CLI {
class App;
}

namespace specula::cli {

/// A progress line on stderr ("LABEL  42%  (3.1 s)"), shown only when stderr is a terminal and
/// the work has run for more than a second; finish() (or the destructor) clears it. update()
/// may be called from any thread.
class ProgressLine {
 public:
  explicit ProgressLine(std::string label);
  ~ProgressLine();
  ProgressLine(const ProgressLine&) = delete;
  ProgressLine& operator=(const ProgressLine&) = delete;
  void update(double fraction);
  void finish();
  /// update() as the callback the library's progress options take (RenderOptions::progress,
  /// VoxelizeOptions::progress); valid while this line lives.
  std::function<void(double)> callback() {
    return [this](double fraction) { update(fraction); };
  }

 private:
  std::string label_;
  bool tty_;
  bool shown_ = false;
  int last_ = -1;
  Timer timer_;
  std::mutex mutex_;
};

struct BenchTraceOptions {
  std::string scene = "pool";  ///< SCENE spec (built-in, json, gltf, mesh)
  std::string mesh;            ///< --mesh FILE: bench a bare mesh instead (overrides scene)
  int width = 640, height = 480;
  int threads = 0;             ///< 0 = all hardware threads for the "all threads" column
  int repeat = 3;              ///< passes per measurement; the median is printed
  BvhOptions bvh;
  LoadOptions load;
  bool embree = true;          ///< compare against Embree when compiled in
  bool embree_robust = false;  ///< --embree-robust: Embree with RTC_SCENE_FLAG_ROBUST
  bool json = false;           ///< --json: print the results as JSON instead of a table
};

struct RenderOptions {
  std::string scene;
  std::string output = "specula.png";
  std::string accel = "bvh";
  std::string aovs;              ///< comma-separated AOV names
  std::string tonemap = "clamp";
  int frames = 1;
  specula::RenderOptions render;
  BvhOptions bvh;
  SceneVoxelOptions voxel;       ///< --accel svo|grid: --depth, --voxel-mode, --lod
  LoadOptions load;
};

struct TraceOptions {
  std::string scene;
  std::string rays;              ///< ray file, "-" = stdin
  std::string accel = "bvh";
  bool stats = false;
  int repeat = 1;
  int threads = 1;
  BvhOptions bvh;
  LoadOptions load;
};

struct InfoOptions {
  std::string scene;
  LoadOptions load;
};

/// `specula voxelize` (apps/specula/voxelize_command.cpp).
struct VoxelizeCommandOptions {
  std::string scene;
  int depth = 0;                   ///< required unless --table
  std::string tests = "aabb,plane,sat";
  std::string sat_at = "leaf";
  std::string traversal;           ///< "octree" | "range"; empty = range (octree for --sat-at all)
  bool vertex_shortcut = true;
  bool clip_shortcut = true;
  bool attributes = true;
  int threads = 0;
  uint64_t memory_limit = 0;       ///< 0 = default (half the physical memory)
  bool no_memory_limit = false;
  bool table = false;              ///< seed 000's build-time table, depths 1..(depth or 8)
  int repeat = 1;                  ///< runs per measurement; the best time is printed
  std::string format;              ///< "" | "xyz"
  std::string output;              ///< -o FILE (.xyz)
  LoadOptions load;
};

/// `specula voxelize`: voxelize a scene, print counts, times, bytes; optionally write the
/// voxels (.xyz) or print seed 000's build-time table.
int voxelize(const VoxelizeCommandOptions& options);
/// Registers the `voxelize` subcommand (its options and --help text) on \p app.
CLI::App* add_voxelize_command(CLI::App& app, VoxelizeCommandOptions& options);

/// `specula render`: load, build, render, write the image (+ AOVs), print timings.
int render(const RenderOptions& options);
/// `specula trace`: trace a ray file, print "t prim" or "miss" per ray.
int trace(const TraceOptions& options);
/// `specula info`: describe a scene.
int info(const InfoOptions& options);

/// `specula bench trace`: build ms; Mrays/s for primary, shadow, secondary (reflection /
/// refraction) and diffuse bounce rays, one thread and all threads; Embree side by side.
int bench_trace(const BenchTraceOptions& options);

/// Options of `specula bench render`.
struct BenchRenderOptions {
  std::string scene = "pool";
  std::string cameras;                        ///< comma-separated; empty = every camera of the scene
  std::string sizes = "640x480,1920x1200";    ///< comma-separated WxH
  std::string accel = "bvh";
  int frames = 5;                             ///< frames per cell; the median is printed
  specula::RenderOptions render;              ///< threads, max reflect / refract
  BvhOptions bvh;
  SceneVoxelOptions voxel;
  LoadOptions load;
  bool json = false;  ///< --json: one JSON object on stdout instead of the table (the load lines go to stderr)
};

/// `specula bench render`: Whitted frame time, fps and Mrays/s per camera and image size; for
/// the pool scene, seed 000's GPU frame rates beside ours.
int bench_render(const BenchRenderOptions& options);

/// Options of `specula bench svo`.
struct BenchSvoOptions {
  std::string scene = "pool";
  std::string cameras;                      ///< empty = every camera of the scene
  std::string sizes = "640x480,1920x1200";
  std::string depths = "3,4,5,6,7,8";
  int frames = 1;
  specula::RenderOptions render;
  LoadOptions load;
  uint64_t memory_limit = 0;  ///< the voxelizer's (SceneVoxelOptions::memory_limit)
  bool json = false;          ///< --json: one JSON object on stdout instead of the tables
};

/// `specula bench svo`: seed 000's frame-rate table (octree depths x views) with ours beside the
/// seed's, cubes and contours, the contour cost, and the PSNR of each voxel render against the
/// triangle render of the same view.
int bench_svo(const BenchSvoOptions& options);

// Helpers shared by the subcommands (commands.cpp).

/// A scene with the structure a rendering command traces it with.
struct PreparedScene {
  Scene scene;
  std::unique_ptr<Tracer> tracer;
  double load_ms = 0.0;
  double build_ms = 0.0;  ///< structure build (voxelization included for voxel structures)
  size_t bytes = 0;
};
/// Loads SCENE (a bare .svo file becomes a stand-in scene traced by its octree) and builds the
/// structure \p accel names (bvh, brute, svo, grid), printing a load and a build line. The
/// \p cameras to be rendered (select_camera's names; "" = the first one) are looked up between
/// the two, so a mistyped name fails before the build. The lines go to \p log (stderr when the
/// standard output carries JSON).
PreparedScene prepare_scene(const std::string& spec, const LoadOptions& load, const std::string& accel,
                            const BvhOptions& bvh, const SceneVoxelOptions& voxel, int threads,
                            const std::vector<std::string>& cameras, std::FILE* log = stdout);
double median(std::vector<double> v);
void print_build(const char* accel, const BuildInfo& b, std::FILE* log = stdout);
Scene load_timed(const std::string& spec, const LoadOptions& load, double& ms);
/// Whether SCENE names an octree file (.svo), which rendering commands trace as it is.
bool is_svo_file(const std::string& spec);
/// Throws for an .svo file given to \p command, which needs triangles, naming the commands
/// that read octree files (render, info).
void refuse_octree_input(const std::string& spec, const std::string& command);
/// The processor the bench commands ran on, which their figures depend on (the project's
/// machines have changed from AMD Zen 5 to Intel Xeon cores; ratios against Embree and the
/// kernels' relative speeds differ between the two).
struct CpuInfo {
  std::string name;  ///< the CPUID brand string, e.g. "Intel(R) Xeon(R) Processor", or "unknown CPU"
  int logical = 0;   ///< logical CPUs (hardware threads) the system reports
  std::string isa;   ///< the widest vector extension the kernels use here: avx512, avx2 or sse
};
CpuInfo cpu_info();
/// "cpu: NAME, N logical CPUs, ISA" for the bench headers.
std::string cpu_line(const CpuInfo& cpu);
/// The bench JSON's "cpu" object: name, logical_cpus, isa.
nlohmann::ordered_json cpu_json(const CpuInfo& cpu);

/// Whether \p camera sits in an occupied voxel of \p tracer (a voxel tracer; false for any
/// other) so that every primary ray hits that voxel at t = 0, as at coarse depths: a ray that
/// starts inside a voxel hits it there (in contour mode when the camera is inside its slab,
/// and then every ray does), and the image shows little but that voxel.
bool camera_in_voxel(const Tracer& tracer, const Camera& camera);

}  // namespace specula::cli
