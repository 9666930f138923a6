// Google Benchmark: sparse voxel octree vs dense voxel grid traversal, one thread, on a
// synthetic sphere shell and on seed 000's pool scene (owner: voxel tracers).
//   build/release/specula_bench --benchmark_filter='Svo|VoxelGrid'
// Rays: 640 x 480 primary rays of a pinhole camera looking at the shell (coherent, in 8 x 8
// tiles), and random rays through the grid (incoherent). Pool: the built-in scene voxelized at
// depth 8 as `specula bench svo` does, 640 x 480 primary rays of the water / bunny / parallel
// cameras in the integrator's 16 x 16 tiles, and shadow rays towards the sun from their hits.
// Pool bunny view with contours at 1920x1200 (issue 3's slowest cells outside the voxels): its
// primary rays made and traced tile by tile as the integrator does, at depths 5 and 7.
#include <benchmark/benchmark.h>

#include <cmath>
#include <map>
#include <memory>
#include <random>
#include <string>
#include <vector>

#include "specula/load.h"
#include "specula/render.h"
#include "specula/svo.h"
#include "specula/voxel_scene.h"
#include "specula/voxel_grid.h"
#include "specula/voxel_tracer.h"
#include "voxel/voxel_brute.h"  // the packet kernel selection

namespace {

using namespace specula;

const VoxelSet& shell(int depth) {
  static std::map<int, VoxelSet> sets;
  auto it = sets.find(depth);
  if (it == sets.end())
    it = sets.emplace(depth, make_sphere_shell_set(VoxelGrid{Vec3(-1.0f), 2.0f, depth}, Vec3(0.0f), 0.9f)).first;
  return it->second;
}

std::vector<Ray> primary_rays() {
  std::vector<Ray> rays;
  const int w = 640, h = 480;
  const Vec3 eye(0.3f, 0.4f, 3.0f);
  const float fov = 0.9f, aspect = static_cast<float>(w) / static_cast<float>(h);
  for (int ty = 0; ty < h; ty += 8)
    for (int tx = 0; tx < w; tx += 8)
      for (int y = ty; y < ty + 8; ++y)
        for (int x = tx; x < tx + 8; ++x) {
          const float px = (2.0f * (static_cast<float>(x) + 0.5f) / static_cast<float>(w) - 1.0f) * std::tan(fov / 2) * aspect;
          const float py = (1.0f - 2.0f * (static_cast<float>(y) + 0.5f) / static_cast<float>(h)) * std::tan(fov / 2);
          Ray r;
          r.org = eye;
          r.dir = normalize(Vec3(px, py, -1.0f) + Vec3(-0.1f, -0.13f, 0.0f));
          rays.push_back(r);
        }
  return rays;
}

std::vector<Ray> random_rays(size_t n) {
  std::mt19937 rng(1);
  std::uniform_real_distribution<float> u(-1.0f, 1.0f);
  std::vector<Ray> rays;
  for (size_t i = 0; i < n; ++i) {
    Ray r;
    r.org = Vec3(u(rng), u(rng), u(rng)) * 0.95f;
    r.dir = normalize(Vec3(u(rng), u(rng), u(rng)));
    rays.push_back(r);
  }
  return rays;
}

template <class Build>
void run(benchmark::State& state, const std::vector<Ray>& rays, Build&& build) {
  const int depth = static_cast<int>(state.range(0));
  VoxelTracerOptions o;
  o.mode = state.range(1) ? VoxelHitMode::Contours : VoxelHitMode::Cubes;
  const std::unique_ptr<VoxelTracer> t = build(shell(depth), o);
  std::vector<Hit> hits(rays.size());
  for (auto _ : state) {
    t->intersect(rays, hits);
    benchmark::DoNotOptimize(hits.data());
  }
  TraceStats stats;
  t->intersect(rays, hits, &stats);
  size_t hit = 0;
  for (const Hit& h : hits) hit += h.hit() ? 1 : 0;
  state.counters["Mrays/s"] = benchmark::Counter(static_cast<double>(rays.size()) / 1e6, benchmark::Counter::kIsIterationInvariantRate);
  state.counters["hit%"] = 100.0 * static_cast<double>(hit) / static_cast<double>(rays.size());
  state.counters["nodes/ray"] = static_cast<double>(stats.nodes_visited) / static_cast<double>(rays.size());
  state.counters["voxels"] = static_cast<double>(t->voxel_count());
  state.counters["tests/ray"] = static_cast<double>(stats.triangles_tested) / static_cast<double>(rays.size());
  state.counters["MB"] = static_cast<double>(t->memory_bytes()) / 1048576.0;
}

const auto svo_builder = [](const VoxelSet& s, const VoxelTracerOptions& o) -> std::unique_ptr<VoxelTracer> {
  return std::make_unique<SparseVoxelOctree>(SparseVoxelOctree::build(s, o));
};
const auto grid_builder = [](const VoxelSet& s, const VoxelTracerOptions& o) -> std::unique_ptr<VoxelTracer> {
  return std::make_unique<VoxelGridTracer>(VoxelGridTracer::build(s, o));
};

void BM_SvoPrimary(benchmark::State& state) {
  static const std::vector<Ray> rays = primary_rays();
  run(state, rays, svo_builder);
}
void BM_VoxelGridPrimary(benchmark::State& state) {
  static const std::vector<Ray> rays = primary_rays();
  run(state, rays, grid_builder);
}
void BM_SvoRandom(benchmark::State& state) {
  static const std::vector<Ray> rays = random_rays(200000);
  run(state, rays, svo_builder);
}
void BM_VoxelGridRandom(benchmark::State& state) {
  static const std::vector<Ray> rays = random_rays(200000);
  run(state, rays, grid_builder);
}

void BM_SvoBuild(benchmark::State& state) {
  const VoxelSet& s = shell(static_cast<int>(state.range(0)));
  VoxelTracerOptions o;
  o.threads = 1;
  SvoInfo info;
  for (auto _ : state) {
    SparseVoxelOctree svo = SparseVoxelOctree::build(s, o, &info);
    benchmark::DoNotOptimize(svo);
  }
  state.counters["voxels"] = static_cast<double>(info.voxels);
  state.counters["node B/voxel"] = info.node_bytes_per_voxel;
  state.counters["B/voxel"] = info.bytes_per_voxel;
}

/// The pool voxelized at depth 8 and, per camera, its primary rays and sun shadow rays.
struct PoolRays {
  std::unique_ptr<VoxelTracer> svo;
  std::vector<Ray> primary[3], shadow[3];
  bool stand_in = false;
};

const PoolRays& pool() {
  static const PoolRays p = [] {
    PoolRays r;
    LoadOptions lo;
    lo.warn = [&r](const std::string&) { r.stand_in = true; };
    const Scene scene = load_scene("pool", lo);
    SceneVoxelOptions vo;
    vo.depth = 8;
    vo.threads = 1;
    r.svo = voxelize_scene(scene, vo);
    const char* cams[3] = {"water", "bunny", "parallel"};
    Vec3 sun = Vec3(0.0f, 1.0f, 0.0f);
    for (const Light& l : scene.lights)
      if (l.type == LightType::Directional) sun = normalize(-l.direction);
    for (int c = 0; c < 3; ++c) {
      const PinholeCamera cam(scene.cameras[*scene.find_camera(cams[c])], 640, 480);
      for (int ty = 0; ty < 480; ty += 16)
        for (int tx = 0; tx < 640; tx += 16)
          for (int y = ty; y < ty + 16; ++y)
            for (int x = tx; x < tx + 16; ++x)
              r.primary[c].push_back(cam.generate(static_cast<float>(x) + 0.5f, static_cast<float>(y) + 0.5f));
      std::vector<Hit> hits(r.primary[c].size());
      r.svo->intersect(r.primary[c], hits);
      for (size_t i = 0; i < hits.size(); ++i) {
        if (!hits[i].hit()) continue;
        Ray s;
        s.org = offset_ray_origin(r.primary[c][i].org + r.primary[c][i].dir * hits[i].t, hits[i].ng);
        s.dir = sun;
        r.shadow[c].push_back(s);
      }
    }
    return r;
  }();
  return p;
}

void pool_counters(benchmark::State& state, const VoxelTracer& t, size_t n, const TraceStats& stats) {
  state.counters["Mrays/s"] = benchmark::Counter(static_cast<double>(n) / 1e6, benchmark::Counter::kIsIterationInvariantRate);
  state.counters["nodes/ray"] = static_cast<double>(stats.nodes_visited) / static_cast<double>(n);
  state.counters["voxels"] = static_cast<double>(t.voxel_count());
  if (pool().stand_in) state.SetLabel("bunny stand-in (stanford-bunny.obj not found)");
}

// Arg: camera (0 = water, 1 = bunny, 2 = parallel).
void BM_SvoPoolPrimary(benchmark::State& state) {
  const PoolRays& p = pool();
  const std::vector<Ray>& rays = p.primary[state.range(0)];
  std::vector<Hit> hits(rays.size());
  for (auto _ : state) {
    p.svo->intersect(rays, hits);
    benchmark::DoNotOptimize(hits.data());
  }
  TraceStats stats;
  p.svo->intersect(rays, hits, &stats);
  pool_counters(state, *p.svo, rays.size(), stats);
}
void BM_SvoPoolShadow(benchmark::State& state) {
  const PoolRays& p = pool();
  const std::vector<Ray>& rays = p.shadow[state.range(0)];
  std::vector<Vec3> out(rays.size());
  for (auto _ : state) {
    p.svo->transmittance(rays, out);
    benchmark::DoNotOptimize(out.data());
  }
  TraceStats stats;
  p.svo->transmittance(rays, out, &stats);
  pool_counters(state, *p.svo, rays.size(), stats);
}
/// The bunny view at 1920x1200 with contours (issue 3's slowest cells), depth from the argument:
/// primary rays as the integrator makes and traces them, one batch per 16 x 16 tile in 4 x 4
/// pixel blocks, generated just before they are traced (so they are in the cache, as the
/// integrator's are; a frame's 2.3 M rays read back from memory would cost more than tracing).
struct PoolHd {
  std::unique_ptr<VoxelTracer> svo;
  Camera camera;
};

const PoolHd& pool_hd(int depth) {
  static std::map<int, PoolHd> cache;
  auto it = cache.find(depth);
  if (it != cache.end()) return it->second;
  PoolHd r;
  const Scene scene = load_scene("pool", LoadOptions{});
  SceneVoxelOptions vo;
  vo.depth = depth;
  vo.threads = 1;
  vo.tracer.mode = VoxelHitMode::Contours;
  r.svo = voxelize_scene(scene, vo);
  r.camera = scene.cameras[*scene.find_camera("bunny")];
  return cache.emplace(depth, std::move(r)).first->second;
}

// Args: octree depth; packet kernel (0: this CPU's default, 1: AVX-512 16 lanes, 2: AVX2 16
// lanes as two vectors, 3: AVX2 8 lanes; a kernel this CPU lacks is skipped).
void BM_SvoPoolBunnyContoursHd(benchmark::State& state) {
  constexpr voxel::SvoPacketKernel kKernels[] = {{32, true}, {16, true}, {16, false}, {8, false}};
  const voxel::SvoPacketKernel want = kKernels[state.range(1)];
  voxel::set_svo_packet_width_limit(want.width, want.avx512);
  const voxel::SvoPacketKernel got = voxel::svo_packet_kernel();
  if (state.range(1) != 0 && (got.width != want.width || got.avx512 != want.avx512)) {
    voxel::set_svo_packet_width_limit(32, true);
    state.SkipWithError("this CPU does not run that packet kernel");
    return;
  }
  state.SetLabel(std::to_string(got.width) + (got.avx512 ? " lanes avx512" : got.width > 1 ? " lanes avx2" : " (single rays)"));
  const PoolHd& p = pool_hd(static_cast<int>(state.range(0)));
  const int w = 1920, h = 1200;
  const PinholeCamera cam(p.camera, w, h);
  std::vector<Ray> rays(256);
  std::vector<Hit> hits(256);
  const auto frame = [&](TraceStats* stats) {
    size_t hit = 0;
    for (int ty = 0; ty < h; ty += 16)
      for (int tx = 0; tx < w; tx += 16) {
        size_t k = 0;
        for (int by = ty; by < ty + 16; by += 4)
          for (int bx = tx; bx < tx + 16; bx += 4)
            for (int y = by; y < by + 4; ++y)
              for (int x = bx; x < bx + 4; ++x)
                rays[k++] = cam.generate(static_cast<float>(x) + 0.5f, static_cast<float>(y) + 0.5f);
        p.svo->intersect(rays, hits, stats);
        for (const Hit& hh : hits) hit += hh.hit() ? 1 : 0;
      }
    return hit;
  };
  for (auto _ : state) benchmark::DoNotOptimize(frame(nullptr));
  TraceStats stats;
  const size_t hit = frame(&stats);
  const size_t n = static_cast<size_t>(w) * static_cast<size_t>(h);
  pool_counters(state, *p.svo, n, stats);
  state.counters["tests/ray"] = static_cast<double>(stats.triangles_tested) / static_cast<double>(n);
  state.counters["hit%"] = 100.0 * static_cast<double>(hit) / static_cast<double>(n);
  voxel::set_svo_packet_width_limit(32, true);
}

BENCHMARK(BM_SvoPoolBunnyContoursHd)
    ->ArgsProduct({{5, 7}, {0, 1, 2, 3}})
    ->ArgNames({"depth", "kernel"})
    ->Unit(benchmark::kMillisecond);
BENCHMARK(BM_SvoPoolPrimary)->Arg(0)->Arg(1)->Arg(2)->ArgName("camera")->Unit(benchmark::kMillisecond);
BENCHMARK(BM_SvoPoolShadow)->Arg(0)->Arg(1)->Arg(2)->ArgName("camera")->Unit(benchmark::kMillisecond);

// Args: depth, contours (0 = cubes).
BENCHMARK(BM_SvoPrimary)->Args({8, 0})->Args({8, 1})->Args({10, 0})->Args({10, 1})->ArgNames({"depth", "contours"})->Unit(benchmark::kMillisecond);
BENCHMARK(BM_VoxelGridPrimary)->Args({8, 0})->Args({10, 0})->ArgNames({"depth", "contours"})->Unit(benchmark::kMillisecond);
BENCHMARK(BM_SvoRandom)->Args({8, 0})->Args({10, 0})->ArgNames({"depth", "contours"})->Unit(benchmark::kMillisecond);
BENCHMARK(BM_VoxelGridRandom)->Args({8, 0})->Args({10, 0})->ArgNames({"depth", "contours"})->Unit(benchmark::kMillisecond);
BENCHMARK(BM_SvoBuild)->Arg(8)->Arg(10)->ArgName("depth")->Unit(benchmark::kMillisecond);

}  // namespace
