// Entry points of the acceleration-structure module: name parsing, input validation and the
// build_tracer factory. Owner: accel.
#include "specula/accel.h"

#include <cmath>
#include <string>

#include "accel/brute_tracer.h"
#include "specula/bvh.h"
#include "specula/error.h"
#include "specula/timer.h"
#include "accel/triangles.h"

namespace specula {

AccelKind parse_accel_kind(const std::string& name) {
  if (name == "bvh") return AccelKind::Bvh;
  if (name == "brute") return AccelKind::Brute;
  throw Error("unknown accelerator '" + name + "' (valid: bvh, brute)");
}

BvhKernel parse_bvh_kernel(const std::string& name) {
  if (name == "auto") return BvhKernel::Auto;
  if (name == "sse4") return BvhKernel::Sse4;
  if (name == "avx2x8") return BvhKernel::Avx2x8;
  if (name == "avx512x8") return BvhKernel::Avx512x8;
  if (name == "avx512x16") return BvhKernel::Avx512x16;
  throw Error("unknown BVH kernel '" + name + "' (valid: auto, sse4, avx2x8, avx512x8, avx512x16)");
}

const char* bvh_kernel_name(BvhKernel kernel) {
  switch (kernel) {
    case BvhKernel::Auto: return "auto";
    case BvhKernel::Sse4: return "sse4";
    case BvhKernel::Avx2x8: return "avx2x8";
    case BvhKernel::Avx512x8: return "avx512x8";
    case BvhKernel::Avx512x16: return "avx512x16";
  }
  return "?";
}

BvhQuality parse_bvh_quality(const std::string& name) {
  if (name == "fast") return BvhQuality::Fast;
  if (name == "high") return BvhQuality::High;
  throw Error("unknown BVH quality '" + name + "' (valid: fast, high)");
}

const char* bvh_quality_name(BvhQuality quality) { return quality == BvhQuality::High ? "high" : "fast"; }

bool bvh_kernel_supported(BvhKernel kernel) {
  switch (kernel) {
    case BvhKernel::Auto:
    case BvhKernel::Sse4: return true;
    case BvhKernel::Avx2x8: return __builtin_cpu_supports("avx2");
    case BvhKernel::Avx512x8:
    case BvhKernel::Avx512x16:
      return __builtin_cpu_supports("avx2") && __builtin_cpu_supports("avx512f") && __builtin_cpu_supports("avx512vl");
  }
  return false;
}

BvhKernel resolve_bvh_kernel(BvhKernel kernel) {
  if (kernel != BvhKernel::Auto) return kernel;
  // Measured on the bunny and city (BENCHMARKS.md): 16-wide nodes beat 8-wide ones on most ray
  // kinds where AVX-512 exists; avx512x8 stays selectable.
  if (bvh_kernel_supported(BvhKernel::Avx512x16)) return BvhKernel::Avx512x16;
  return bvh_kernel_supported(BvhKernel::Avx2x8) ? BvhKernel::Avx2x8 : BvhKernel::Sse4;
}

namespace accel {

namespace {
std::string vec_str(const Vec3& v) {
  return "(" + std::to_string(v.x) + ", " + std::to_string(v.y) + ", " + std::to_string(v.z) + ")";
}
}  // namespace

void validate_input(const TriangleInput& input) {
  if (input.indices.size() % 3 != 0)
    throw Error("triangle input: index count " + std::to_string(input.indices.size()) +
                " is not a multiple of 3");
  const size_t tri_count = input.indices.size() / 3;
  if (tri_count > 0xFFFFFFF0u)
    throw Error("triangle input: too many triangles (" + std::to_string(tri_count) + ")");
  const size_t vcount = input.positions.size();
  for (size_t i = 0; i < input.indices.size(); ++i) {
    const uint32_t idx = input.indices[i];
    if (idx >= vcount)
      throw Error("triangle input: triangle " + std::to_string(i / 3) + " uses vertex index " +
                  std::to_string(idx) + " but there are only " + std::to_string(vcount) +
                  " vertices");
    if (!is_finite(input.positions[idx]))
      throw Error("triangle input: triangle " + std::to_string(i / 3) + " uses vertex " +
                  std::to_string(idx) + " with non-finite position " +
                  vec_str(input.positions[idx]));
  }
  if (!input.transmittance.empty()) {
    if (input.transmittance.size() != tri_count)
      throw Error("triangle input: " + std::to_string(input.transmittance.size()) +
                  " transmittance values for " + std::to_string(tri_count) + " triangles");
    for (size_t i = 0; i < tri_count; ++i) {
      const Vec3& t = input.transmittance[i];
      if (!is_finite(t) || t.x < 0.0f || t.y < 0.0f || t.z < 0.0f)
        throw Error("triangle input: triangle " + std::to_string(i) +
                    " has invalid transmittance " + vec_str(t) + " (must be finite and >= 0)");
    }
  }
}

std::vector<BvhTriangle> gather_triangles(const TriangleInput& input) {
  const size_t n = input.indices.size() / 3;
  std::vector<BvhTriangle> tris(n);
  for (size_t i = 0; i < n; ++i) {
    for (int k = 0; k < 3; ++k) {
      const Vec3& p = input.positions[input.indices[3 * i + k]];
      tris[i].v[3 * k] = p.x;
      tris[i].v[3 * k + 1] = p.y;
      tris[i].v[3 * k + 2] = p.z;
    }
  }
  return tris;
}

}  // namespace accel

std::unique_ptr<Tracer> build_tracer(AccelKind kind, const TriangleInput& input,
                                     const BvhOptions& options, BuildInfo* info) {
  switch (kind) {
    case AccelKind::Brute: {
      const Timer timer;
      accel::validate_input(input);
      auto tracer = std::make_unique<accel::BruteTracer>(input);
      if (info) {
        *info = {};
        info->build_ms = timer.ms();
        info->leaves = 1;
        info->nodes = 1;
        info->sah_cost = static_cast<double>(input.indices.size() / 3);
        info->bytes = tracer->memory_bytes();
      }
      return tracer;
    }
    case AccelKind::Bvh:
      return std::make_unique<Bvh>(Bvh::build(input, options, info));
  }
  throw Error("build_tracer: unknown accelerator kind");
}

}  // namespace specula
