// Google Benchmark: BVH build and tracing on the Stanford bunny (owner: accel).
//   build/release/specula_bench --benchmark_filter=Bvh
// Each benchmark skips with an error when the shared mesh is absent.
#include <benchmark/benchmark.h>

#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "specula/accel.h"
#include "specula/bvh.h"
#include "specula/load.h"
#include "specula/render.h"

namespace {

using namespace specula;

/// The bunny scene (with its default camera), loaded once; nullopt when the mesh is absent.
const std::optional<Scene>& bunny() {
  static const std::optional<Scene> scene = []() -> std::optional<Scene> {
    std::filesystem::path dir;
    if (const char* env = std::getenv("SPECULA_DATA"); env && *env) dir = env;
    else dir = std::filesystem::path(SPECULA_SOURCE_DIR) / ".." / "shared" / "data" / "meshes";
    const auto path = dir / "stanford-bunny.obj";
    if (!std::filesystem::exists(path)) return std::nullopt;
    return load_scene(path.string());
  }();
  return scene;
}

bool require_bunny(benchmark::State& state) {
  if (bunny()) return true;
  state.SkipWithError("stanford-bunny.obj not found (set SPECULA_DATA or place ../shared/data/meshes beside the source tree)");
  return false;
}

TriangleInput bunny_input() { return {bunny()->positions, bunny()->indices, {}}; }

/// Arg 0: threads (0 = all); arg 1: BvhQuality (0 = fast, 1 = high).
void BM_BvhBuild(benchmark::State& state) {
  if (!require_bunny(state)) return;
  BvhOptions o;
  o.threads = static_cast<int>(state.range(0));
  o.quality = state.range(1) != 0 ? BvhQuality::High : BvhQuality::Fast;
  BuildInfo info;
  for (auto _ : state) {
    Bvh bvh = Bvh::build(bunny_input(), o, &info);
    benchmark::DoNotOptimize(bvh);
  }
  state.counters["nodes"] = static_cast<double>(info.nodes);
  state.counters["sah"] = info.sah_cost;
  state.counters["MB"] = static_cast<double>(info.bytes) / 1048576.0;
  state.counters["tris/s"] = benchmark::Counter(static_cast<double>(bunny()->triangle_count()), benchmark::Counter::kIsIterationInvariantRate);
}
BENCHMARK(BM_BvhBuild)
    ->Args({1, 0})
    ->Args({0, 0})
    ->Args({1, 1})
    ->Args({0, 1})
    ->ArgNames({"threads", "high"})
    ->Unit(benchmark::kMillisecond);

/// Primary rays (640 x 480 from the scene camera) and cosine-distributed bounces from their hits.
struct RaySets {
  std::vector<Ray> primary, diffuse;
};

const RaySets& ray_sets(const Bvh& bvh) {
  static const RaySets sets = [&bvh] {
    RaySets s;
    const PinholeCamera cam(bunny()->cameras.front(), 640, 480);
    for (int y = 0; y < 480; ++y)
      for (int x = 0; x < 640; ++x) s.primary.push_back(cam.generate(static_cast<float>(x) + 0.5f, static_cast<float>(y) + 0.5f));
    std::vector<Hit> hits(s.primary.size());
    bvh.intersect(s.primary, hits);
    uint32_t state = 12345u;
    const auto rnd = [&state] {
      state = state * 1664525u + 1013904223u;
      return static_cast<float>(state >> 8) * (1.0f / 16777216.0f);
    };
    for (size_t i = 0; i < hits.size(); ++i) {
      if (!hits[i].hit()) continue;
      const Ray& r = s.primary[i];
      const Vec3 n = dot(r.dir, hits[i].ng) < 0.0f ? hits[i].ng : -hits[i].ng;
      Vec3 t, b;
      orthonormal_basis(n, t, b);
      const float u1 = rnd(), u2 = rnd(), rad = std::sqrt(u1), phi = 2.0f * kPi * u2;
      Ray d;
      d.org = offset_ray_origin(r.org + r.dir * hits[i].t, n);
      d.dir = normalize(t * (rad * std::cos(phi)) + b * (rad * std::sin(phi)) + n * std::sqrt(1.0f - u1));
      s.diffuse.push_back(d);
    }
    return s;
  }();
  return sets;
}

/// The bunny's BVH, single rays only (packets off: the single-ray kernels are measured).
const Bvh& bunny_bvh() {
  static const Bvh bvh = [] {
    BvhOptions o;
    o.packets = false;
    return Bvh::build(bunny_input(), o);
  }();
  return bvh;
}

/// The same tree tracing coherent groups of 16 rays as packets.
const Bvh& bunny_bvh_packets() {
  static const Bvh bvh = Bvh::build(bunny_input());
  return bvh;
}

/// The primary rays of ray_sets() in 4x4 pixel blocks (16 consecutive rays = one block).
const std::vector<Ray>& primary_blocks() {
  static const std::vector<Ray> rays = [] {
    const std::vector<Ray>& primary = ray_sets(bunny_bvh()).primary;
    std::vector<Ray> out;
    for (int by = 0; by < 480; by += 4)
      for (int bx = 0; bx < 640; bx += 4)
        for (int y = by; y < by + 4; ++y)
          for (int x = bx; x < bx + 4; ++x) out.push_back(primary[static_cast<size_t>(y) * 640 + static_cast<size_t>(x)]);
    return out;
  }();
  return rays;
}

void trace(benchmark::State& state, const std::vector<Ray>& rays, const Bvh& bvh = bunny_bvh()) {
  std::vector<Hit> hits(rays.size());
  for (auto _ : state) {
    bvh.intersect(rays, hits);
    benchmark::DoNotOptimize(hits.data());
  }
  state.counters["Mrays"] =
      benchmark::Counter(static_cast<double>(rays.size()) * 1e-6, benchmark::Counter::kIsIterationInvariantRate);
  TraceStats stats;  // work per ray (load-independent), from one extra pass outside the timing
  bvh.intersect(rays, hits, &stats);
  // With packets, a packet's node visit and leaf triangles count once for all its rays.
  state.counters["nodes/ray"] = static_cast<double>(stats.nodes_visited) / static_cast<double>(stats.rays);
  state.counters["tris/ray"] = static_cast<double>(stats.triangles_tested) / static_cast<double>(stats.rays);
  if (stats.packets > 0)
    state.counters["in packets"] = static_cast<double>(stats.packet_rays) / static_cast<double>(stats.rays);
}

void BM_BvhTracePrimary(benchmark::State& state) {
  if (!require_bunny(state)) return;
  trace(state, ray_sets(bunny_bvh()).primary);
}
BENCHMARK(BM_BvhTracePrimary)->Unit(benchmark::kMillisecond);

/// The same primary rays in 4x4 pixel blocks, traced as 16-ray packets.
void BM_BvhTracePrimaryPackets(benchmark::State& state) {
  if (!require_bunny(state)) return;
  trace(state, primary_blocks(), bunny_bvh_packets());
}
BENCHMARK(BM_BvhTracePrimaryPackets)->Unit(benchmark::kMillisecond);

void BM_BvhTraceDiffuse(benchmark::State& state) {
  if (!require_bunny(state)) return;
  trace(state, ray_sets(bunny_bvh()).diffuse);
}
BENCHMARK(BM_BvhTraceDiffuse)->Unit(benchmark::kMillisecond);

void BM_BvhOccludedDiffuse(benchmark::State& state) {
  if (!require_bunny(state)) return;
  const std::vector<Ray>& rays = ray_sets(bunny_bvh()).diffuse;
  std::vector<Vec3> out(rays.size());
  for (auto _ : state) {
    bunny_bvh().transmittance(rays, out);
    benchmark::DoNotOptimize(out.data());
  }
  state.counters["Mrays"] =
      benchmark::Counter(static_cast<double>(rays.size()) * 1e-6, benchmark::Counter::kIsIterationInvariantRate);
}
BENCHMARK(BM_BvhOccludedDiffuse)->Unit(benchmark::kMillisecond);

}  // namespace

BENCHMARK_MAIN();
