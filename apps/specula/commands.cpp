// render, trace and info subcommands.
#include "commands.h"

#include <tbb/parallel_for.h>
#include <tbb/task_arena.h>
#include <unistd.h>

#include <nlohmann/json.hpp>

#if defined(__x86_64__) || defined(__i386__)
#include <cpuid.h>
#endif

#include <algorithm>
#include <charconv>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <mutex>
#include <string>
#include <thread>
#include <vector>

#include "core/format.h"
#include "specula/error.h"
#include "specula/image.h"
#include "specula/svo.h"
#include "specula/voxel_grid.h"
#include "specula/timer.h"

namespace specula::cli {

double median(std::vector<double> v) {
  std::sort(v.begin(), v.end());
  const size_t n = v.size();
  return n == 0 ? 0.0 : (n % 2 ? v[n / 2] : 0.5 * (v[n / 2 - 1] + v[n / 2]));
}

void print_build(const char* accel, const BuildInfo& b, std::FILE* log) {
  std::fprintf(log, "build    %9.2f ms  (%s: %s nodes, %s leaves, depth %u, SAH cost %.2f, %.2f MiB)\n",
              b.build_ms, accel, with_thousands(b.nodes).c_str(), with_thousands(b.leaves).c_str(),
              b.max_depth, b.sah_cost, static_cast<double>(b.bytes) / (1024.0 * 1024.0));
  if (b.optimize_ms > 0.0)
    std::fprintf(log, "         --bvh-quality high: SAH cost %.2f -> %.2f by %s reinsertions in %.2f ms of the build\n",
                b.sah_cost_binned, b.sah_cost, with_thousands(b.reinsertions).c_str(), b.optimize_ms);
}

bool is_svo_file(const std::string& spec) {
  const std::string ext = std::filesystem::path(spec).extension().string();
  return ext == ".svo" || ext == ".SVO";
}

bool camera_in_voxel(const Tracer& tracer, const Camera& camera) {
  if (dynamic_cast<const VoxelTracer*>(&tracer) == nullptr) return false;
  // The ray towards the target stands for all primary rays: their origin is the camera, and
  // whether a ray starting there hits at t = 0 does not depend on its direction.
  const Ray ray{camera.position, 0.0f, camera.target - camera.position, kInf};
  Hit hit;
  tracer.intersect(std::span<const Ray>(&ray, 1), std::span<Hit>(&hit, 1));
  return hit.hit() && hit.t == 0.0f;
}

namespace {

/// Files the loaders do not read themselves (.svo octrees, ray files) get the same size limit.
void check_input_size(const std::string& path, const InputLimits& limits) {
  std::error_code ec;
  const uintmax_t size = std::filesystem::file_size(path, ec);
  if (!ec && size > limits.max_file_bytes)
    throw file_error(path, file_size_refusal(size, limits));
}
}  // namespace

PreparedScene prepare_scene(const std::string& spec, const LoadOptions& load, const std::string& accel,
                            const BvhOptions& bvh_options, const SceneVoxelOptions& voxel_options, int threads,
                            const std::vector<std::string>& cameras, std::FILE* log) {
  PreparedScene out;
  if (is_svo_file(spec)) {
    if (accel != "svo" && accel != "bvh")
      throw Error(spec + ": a .svo file is traced by its octree (--accel svo), not '" + accel + "'");
    check_input_size(spec, load.limits);
    const Timer timer;
    VoxelTracerOptions t = voxel_options.tracer;
    t.threads = threads;
    auto svo = std::make_unique<SparseVoxelOctree>(read_svo(spec, t));
    if (t.lod > svo->grid().depth)
      throw Error("--lod " + std::to_string(t.lod) + ": " + spec + " has depth " + std::to_string(svo->grid().depth) +
                  " (use 1.." + std::to_string(svo->grid().depth) + ", or 0 for full depth)");
    out.load_ms = timer.ms();
    out.scene = svo_scene(*svo, std::filesystem::path(spec).filename().string());
    for (const std::string& c : cameras) select_camera(out.scene, c);
    out.bytes = svo->memory_bytes();
    std::fprintf(log, "scene    %s: %s voxels at depth %d (%s hits)\n", spec.c_str(), with_thousands(svo->voxel_count()).c_str(),
                svo->grid().depth, to_string(svo->hit_mode()));
    std::fprintf(log, "load     %9.2f ms  (%.2f MiB)\n", out.load_ms, static_cast<double>(out.bytes) / (1024.0 * 1024.0));
    out.tracer = std::move(svo);
    return out;
  }
  // The options first: a contradiction fails before the scene is loaded.
  if (accel == "svo" && voxel_options.tracer.lod > voxel_options.depth)
    throw Error("--lod " + std::to_string(voxel_options.tracer.lod) + " is deeper than the octree (--depth " +
                std::to_string(voxel_options.depth) + "): use 1.." + std::to_string(voxel_options.depth) +
                ", or 0 for full depth");
  if (accel == "grid" && VoxelGridTracer::table_bytes(voxel_options.depth) > voxel_options.tracer.max_grid_bytes)
    throw Error("--accel grid --depth " + std::to_string(voxel_options.depth) + ": the voxel grid's brick table needs " +
                format_bytes(VoxelGridTracer::table_bytes(voxel_options.depth)) + ", over the limit of " +
                format_bytes(voxel_options.tracer.max_grid_bytes, true) +
                " (--max-grid-memory raises it; --accel svo stores only the occupied voxels)");
  out.scene = load_timed(spec, load, out.load_ms);
  const Scene& scene = out.scene;
  std::fprintf(log, "scene    %s: %s triangles, %zu materials, %zu lights, %zu cameras\n",
              scene.name.empty() ? spec.c_str() : scene.name.c_str(), with_thousands(scene.triangle_count()).c_str(),
              scene.materials.size(), scene.lights.size(), scene.cameras.size());
  std::fprintf(log, "load     %9.2f ms\n", out.load_ms);
  for (const std::string& c : cameras) select_camera(scene, c);
  if (accel == "svo" || accel == "grid") {
    SceneVoxelOptions v = voxel_options;
    v.kind = accel;
    v.threads = threads;
    SceneVoxelInfo info;
    ProgressLine progress("voxelizing");
    v.progress = progress.callback();
    out.tracer = voxelize_scene(scene, v, &info);
    progress.finish();
    out.build_ms = info.voxelize_ms + info.build_ms;
    out.bytes = info.bytes;
    std::fprintf(log, "voxelize %9.2f ms  (depth %d, %s voxels)\n", info.voxelize_ms, v.depth, with_thousands(info.voxels).c_str());
    std::fprintf(log, "build    %9.2f ms  (%s, %s hits, %.2f MiB, %.1f bytes/voxel)\n", info.build_ms, accel.c_str(),
                to_string(v.tracer.mode), static_cast<double>(info.bytes) / (1024.0 * 1024.0),
                info.voxels ? static_cast<double>(info.bytes) / static_cast<double>(info.voxels) : 0.0);
    return out;
  }
  const std::vector<Vec3> transmittance = shadow_transmittance(scene);
  BuildInfo build;
  BvhOptions bvh = bvh_options;
  bvh.threads = threads;
  out.tracer = build_tracer(parse_accel_kind(accel), TriangleInput{scene.positions, scene.indices, transmittance}, bvh, &build);
  out.build_ms = build.build_ms;
  out.bytes = build.bytes;
  // Name the BVH's traversal kernel (what --bvh-kernel auto chose on this CPU).
  const std::string label = accel == "bvh" ? accel + " " + bvh_kernel_name(resolve_bvh_kernel(bvh.kernel)) : accel;
  print_build(label.c_str(), build, log);
  return out;
}

void refuse_octree_input(const std::string& spec, const std::string& command) {
  if (is_svo_file(spec))
    throw Error(spec + ": an .svo file holds voxels, not triangles; '" + command +
                "' needs a triangle scene ('specula render FILE.svo' renders it, 'specula info FILE.svo' "
                "describes it)");
}

CpuInfo cpu_info() {
  CpuInfo cpu;
  cpu.logical = static_cast<int>(std::thread::hardware_concurrency());
#if defined(__x86_64__) || defined(__i386__)
  unsigned a = 0, b = 0, c = 0, d = 0;
  if (__get_cpuid(0x80000000u, &a, &b, &c, &d) != 0 && a >= 0x80000004u) {
    char brand[49] = {};
    for (size_t leaf = 0; leaf < 3; ++leaf) {
      unsigned r[4] = {};
      __get_cpuid(0x80000002u + static_cast<unsigned>(leaf), &r[0], &r[1], &r[2], &r[3]);
      std::memcpy(brand + sizeof r * leaf, r, sizeof r);
    }
    cpu.name = brand;
  }
  cpu.isa = __builtin_cpu_supports("avx512f") ? "avx512" : __builtin_cpu_supports("avx2") ? "avx2" : "sse";
#else
  cpu.isa = "scalar";
#endif
  // The brand string is padded with spaces (leading on some Intel parts).
  const size_t first = cpu.name.find_first_not_of(' ');
  cpu.name = first == std::string::npos ? std::string() : cpu.name.substr(first, cpu.name.find_last_not_of(' ') - first + 1);
  if (cpu.name.empty()) cpu.name = "unknown CPU";
  return cpu;
}

std::string cpu_line(const CpuInfo& cpu) {
  return "cpu: " + cpu.name + ", " + std::to_string(cpu.logical) + " logical CPU" + (cpu.logical == 1 ? "" : "s") +
         ", " + cpu.isa;
}

nlohmann::ordered_json cpu_json(const CpuInfo& cpu) {
  return {{"name", cpu.name}, {"logical_cpus", cpu.logical}, {"isa", cpu.isa}};
}

ProgressLine::ProgressLine(std::string label) : label_(std::move(label)), tty_(isatty(STDERR_FILENO) != 0) {}

ProgressLine::~ProgressLine() { finish(); }

void ProgressLine::update(double fraction) {
  if (!tty_) return;
  std::lock_guard lock(mutex_);
  if (timer_.ms() < 1000.0) return;
  const int pct = static_cast<int>(std::clamp(fraction, 0.0, 1.0) * 100.0);
  if (pct == last_) return;
  last_ = pct;
  std::fprintf(stderr, "\r%s %3d%%  (%.1f s)", label_.c_str(), pct, timer_.ms() / 1000.0);
  std::fflush(stderr);
  shown_ = true;
}

void ProgressLine::finish() {
  std::lock_guard lock(mutex_);
  if (shown_) std::fprintf(stderr, "\r\033[K");
  shown_ = false;
}

Scene load_timed(const std::string& spec, const LoadOptions& load, double& ms) {
  Timer t;
  Scene scene = load_scene(spec, load);
  ms = t.ms();
  return scene;
}

namespace {

bool same_file(const std::filesystem::path& a, const std::filesystem::path& b) {
  std::error_code ec;
  return std::filesystem::exists(a, ec) && std::filesystem::exists(b, ec) &&
         std::filesystem::equivalent(a, b, ec);
}

/// Refuses to write any of \p outputs over one of \p inputs, however either is spelled (./x,
/// a/../x, a symlink or a hard link to the same file).
void refuse_overwriting_inputs(const std::vector<std::string>& outputs, const std::vector<std::string>& inputs) {
  for (const std::string& out : outputs)
    for (const std::string& in : inputs)
      if (!in.empty() && same_file(out, in))
        throw Error(out + ": refusing to overwrite the input " + (in == inputs.front() ? "scene" : "file") + " " + in);
}

}  // namespace

int render(const RenderOptions& options) {
  const std::string ext = std::filesystem::path(options.output).extension().string();
  if (ext != ".png" && ext != ".exr" && ext != ".PNG" && ext != ".EXR")
    throw Error(options.output + ": output must end in .png or .exr");
  if (options.tonemap != "clamp" && (ext == ".exr" || ext == ".EXR"))
    std::fprintf(stderr, "warning: --tonemap %s applies to PNG images; %s is written linear (HDR), untouched\n",
                 options.tonemap.c_str(), options.output.c_str());
  specula::RenderOptions ro = options.render;
  ro.aovs = parse_aovs(options.aovs);
  // Every output (image and AOVs) against every input (the scene file, then its sky image).
  std::vector<std::string> outputs{options.output};
  for (Aov a : ro.aovs) outputs.push_back(aov_path(options.output, a));
  refuse_overwriting_inputs(outputs, {options.scene});
  // An absurd image size or an output that cannot be written fails now, not after the scene is
  // loaded, its tracer built and the frame rendered.
  check_image_size(ro.width, ro.height, ro.aovs);
  for (const std::string& out : outputs) check_output_path(out);

  PreparedScene prepared =
      prepare_scene(options.scene, options.load, options.accel, options.bvh, options.voxel, options.render.threads,
                    {ro.camera});
  const Scene& scene = prepared.scene;
  const auto& tracer = prepared.tracer;
  if (scene.sky.type == SkyType::Image) refuse_overwriting_inputs(outputs, {options.scene, scene.sky.image_path});
  if (const Camera& camera = select_camera(scene, ro.camera); camera_in_voxel(*tracer, camera)) {
    const auto* svo = dynamic_cast<const SparseVoxelOctree*>(tracer.get());
    const int depth = svo != nullptr && svo->lod() > 0 ? svo->lod() : dynamic_cast<const VoxelTracer&>(*tracer).grid().depth;
    std::fprintf(stderr,
                 "warning: camera '%s' is inside an occupied voxel (depth %d): every primary ray hits it at t = 0 "
                 "and the image shows little else; a finer voxel depth or another camera shows the scene\n",
                 camera.name.c_str(), depth);
  }

  ProgressLine progress("rendering");
  ro.progress = progress.callback();
  std::vector<double> times;
  Film film;
  RenderStats stats;
  for (int frame = 0; frame < options.frames; ++frame) {
    stats = {};
    render_whitted(scene, *tracer, ro, film, &stats);  // one film for every frame, as a viewer would
    times.push_back(stats.render_ms);
  }
  progress.finish();
  const double ms = median(times);
  const uint64_t rays = stats.total_rays();
  std::printf("render   %9.2f ms  (%dx%d, %s%s, %.2f fps%s)\n", ms, ro.width, ro.height,
              options.frames > 1 ? "median of " : "",
              options.frames > 1 ? (std::to_string(options.frames) + " frames").c_str() : "1 frame",
              1000.0 / std::max(ms, 1e-9), ro.shadows ? "" : ", no shadow rays");
  std::printf("rays     %s  (%s primary, %s secondary, %s shadow)\n", with_thousands(rays).c_str(),
              with_thousands(stats.primary_rays).c_str(), with_thousands(stats.secondary_rays).c_str(),
              with_thousands(stats.shadow_rays).c_str());
  std::printf("speed    %9.2f Mrays/s\n", static_cast<double>(rays) / (ms * 1e3));

  const Tonemap tm = options.tonemap == "reinhard" ? Tonemap::Reinhard : Tonemap::Clamp;
  write_image(options.output, film.width, film.height, film.color, tm);
  std::printf("wrote    %s\n", options.output.c_str());
  for (const std::string& path : write_aovs(options.output, film)) std::printf("wrote    %s\n", path.c_str());
  return 0;
}

namespace {

/// Parses the ray file: one ray per non-empty line, "ox oy oz dx dy dz"; '#' starts a comment.
std::vector<Ray> read_rays(const std::string& path) {
  std::ifstream file;
  std::istream* in = &std::cin;
  if (path != "-") {
    file.open(path, std::ios::binary);
    if (!file) throw Error(path + ": cannot open ray file");
    in = &file;
  }
  std::vector<Ray> rays;
  std::string line;
  uint64_t line_no = 0;
  while (std::getline(*in, line)) {
    ++line_no;
    const size_t hash = line.find('#');
    if (hash != std::string::npos) line.resize(hash);
    const char* p = line.data();
    const char* end = p + line.size();
    auto skip_ws = [&] {
      while (p < end && (*p == ' ' || *p == '\t' || *p == '\r' || *p == ',')) ++p;
    };
    skip_ws();
    if (p == end) continue;
    float v[6];
    for (int i = 0; i < 6; ++i) {
      skip_ws();
      if (*p == '+') ++p;  // from_chars does not accept a leading '+'
      const auto [next, ec] = std::from_chars(p, end, v[i]);
      if (ec != std::errc() || !std::isfinite(v[i]))
        throw Error(path + ": line " + std::to_string(line_no) + ": expected 6 finite numbers 'ox oy oz dx dy dz'" +
                    (ec == std::errc() ? " (value " + std::to_string(i + 1) + " is not finite)" : ""));
      p = next;
    }
    skip_ws();
    if (p != end) throw Error(path + ": line " + std::to_string(line_no) + ": more than 6 numbers");
    Ray r;
    r.org = {v[0], v[1], v[2]};
    r.dir = {v[3], v[4], v[5]};
    if (r.dir == Vec3{})
      throw Error(path + ": line " + std::to_string(line_no) + ": zero direction");
    r.tmin = 0.0f;
    r.tmax = kInf;
    rays.push_back(r);
  }
  if (in->bad()) throw Error(path + ": read error");
  return rays;
}

}  // namespace

int trace(const TraceOptions& options) {
  refuse_octree_input(options.scene, "trace");
  double load_ms = 0;
  Scene scene = load_timed(options.scene, options.load, load_ms);
  if (options.rays != "-") check_input_size(options.rays, options.load.limits);
  const std::vector<Ray> rays = read_rays(options.rays);

  const int threads = options.threads <= 0 ? tbb::info::default_concurrency() : options.threads;
  tbb::task_arena arena(threads);
  BuildInfo build;
  BvhOptions bvh = options.bvh;
  bvh.threads = threads;
  const auto tracer =
      build_tracer(parse_accel_kind(options.accel), TriangleInput{scene.positions, scene.indices, {}}, bvh, &build);

  std::vector<Hit> hits(rays.size());
  std::vector<double> times;
  for (int pass = 0; pass < options.repeat; ++pass) {
    Timer t;
    constexpr size_t kChunk = 1024;
    const size_t chunks = (rays.size() + kChunk - 1) / kChunk;
    if (threads == 1) {
      tracer->intersect(rays, hits);
    } else {
      arena.execute([&] {
        tbb::parallel_for(size_t{0}, chunks, [&](size_t c) {
          const size_t b = c * kChunk, n = std::min(kChunk, rays.size() - b);
          tracer->intersect(std::span(rays).subspan(b, n), std::span(hits).subspan(b, n));
        });
      });
    }
    times.push_back(t.ms());
  }

  // Output: one line per ray; large outputs go through one buffered stream.
  std::string out;
  out.reserve(rays.size() * 20);
  char buf[64];
  for (const Hit& h : hits) {
    if (h.hit()) {
      const int n = std::snprintf(buf, sizeof buf, "%.9g %u\n", static_cast<double>(h.t), h.prim);
      out.append(buf, static_cast<size_t>(n));
    } else {
      out += "miss\n";
    }
  }
  std::fwrite(out.data(), 1, out.size(), stdout);
  std::fflush(stdout);

  if (options.stats) {
    const double ms = median(times);
    std::fprintf(stderr, "load     %9.2f ms  (%s triangles)\n", load_ms,
                 with_thousands(scene.triangle_count()).c_str());
    print_build(options.accel.c_str(), build, stderr);  // the build line render prints
    std::fprintf(stderr, "trace    %9.3f ms  (%s ray%s, %d thread%s, median of %d pass%s)\n", ms,
                 with_thousands(rays.size()).c_str(), rays.size() == 1 ? "" : "s", threads, threads == 1 ? "" : "s",
                 options.repeat, options.repeat == 1 ? "" : "es");
    std::fprintf(stderr, "speed    %9.2f Mrays/s\n", static_cast<double>(rays.size()) / (std::max(ms, 1e-9) * 1e3));
  }
  return 0;
}

int info(const InfoOptions& options) {
  if (is_svo_file(options.scene)) {  // an octree file (voxelize -o): its header and sizes
    check_input_size(options.scene, options.load.limits);
    const Timer timer;
    const SparseVoxelOctree svo = read_svo(options.scene);
    const double ms = timer.ms();
    const SvoInfo i = svo.info();
    const VoxelGrid& g = svo.grid();
    const Aabb b = g.bounds();
    std::printf("octree     %s  (read and checked in %.2f ms)\n", options.scene.c_str(), ms);
    std::printf("depth      %d  (%u^3 voxels of side %g)\n", g.depth, g.resolution(), static_cast<double>(g.voxel_size()));
    std::printf("bounds     [%g %g %g] - [%g %g %g]  (cube side %g)\n", b.min.x, b.min.y, b.min.z, b.max.x, b.max.y,
                b.max.z, static_cast<double>(g.side));
    std::printf("voxels     %s\n", with_thousands(i.voxels).c_str());
    std::printf("nodes      %s\n", with_thousands(i.nodes).c_str());
    std::printf("memory     %s bytes  (%.2f MiB, %.1f bytes/voxel, %.2f of them nodes)\n",
                with_thousands(i.bytes).c_str(), static_cast<double>(i.bytes) / 1048576.0, i.bytes_per_voxel,
                i.node_bytes_per_voxel);
    return 0;
  }
  double load_ms = 0;
  const Scene scene = load_timed(options.scene, options.load, load_ms);
  const Aabb b = scene.bounds();
  std::printf("scene      %s  (loaded in %.2f ms)\n", scene.name.empty() ? options.scene.c_str() : scene.name.c_str(),
              load_ms);
  std::printf("triangles  %s\n", with_thousands(scene.triangle_count()).c_str());
  std::printf("vertices   %s\n", with_thousands(scene.positions.size()).c_str());
  if (b.empty())
    std::printf("bounds     empty\n");
  else
    std::printf("bounds     [%g %g %g] - [%g %g %g]  (extent %g x %g x %g)\n", b.min.x, b.min.y, b.min.z, b.max.x,
                b.max.y, b.max.z, b.extent().x, b.extent().y, b.extent().z);
  std::printf("meshes     %zu\n", scene.meshes.size());
  for (const MeshRange& m : scene.meshes)
    std::printf("  %-28s %10s triangles (first %u)\n", m.name.c_str(), with_thousands(m.triangle_count).c_str(),
                m.first_triangle);
  std::printf("materials  %zu\n", scene.materials.size());
  for (const Material& m : scene.materials)
    std::printf(
        "  %-28s diffuse (%.3g %.3g %.3g) specular (%.3g %.3g %.3g)^%g reflect %.3g transparent %.3g ior %.3g "
        "absorb (%.3g %.3g %.3g) emit (%.3g %.3g %.3g)\n",
        m.name.c_str(), m.diffuse.x, m.diffuse.y, m.diffuse.z, m.specular.x, m.specular.y, m.specular.z,
        m.phong_exponent, m.reflectivity, m.transparency, m.ior, m.absorption.x, m.absorption.y, m.absorption.z,
        m.emission.x, m.emission.y, m.emission.z);
  std::printf("lights     %zu\n", scene.lights.size());
  for (const Light& l : scene.lights) {
    const char* type = l.type == LightType::Point ? "point" : l.type == LightType::Directional ? "directional" : "sphere";
    if (l.type == LightType::Directional)
      std::printf("  %-28s %s dir (%g %g %g) color (%g %g %g) x %g\n", l.name.c_str(), type, l.direction.x,
                  l.direction.y, l.direction.z, l.color.x, l.color.y, l.color.z, l.intensity);
    else
      std::printf("  %-28s %s at (%g %g %g) color (%g %g %g) x %g%s\n", l.name.c_str(), type, l.position.x,
                  l.position.y, l.position.z, l.color.x, l.color.y, l.color.z, l.intensity,
                  l.type == LightType::Sphere
                      ? (" radius " + std::to_string(l.radius) + ", " + std::to_string(l.samples) + " samples").c_str()
                      : "");
  }
  std::printf("cameras    %zu\n", scene.cameras.size());
  for (const Camera& c : scene.cameras)
    std::printf("  %-28s at (%g %g %g) looking at (%g %g %g), vfov %g deg\n", c.name.c_str(), c.position.x,
                c.position.y, c.position.z, c.target.x, c.target.y, c.target.z, c.vfov_degrees);
  const char* sky = scene.sky.type == SkyType::Constant ? "constant" : scene.sky.type == SkyType::Gradient ? "gradient" : "image";
  std::printf("sky        %s%s\n", sky, scene.sky.type == SkyType::Image ? (" " + scene.sky.image_path).c_str() : "");
  return 0;
}

}  // namespace specula::cli
