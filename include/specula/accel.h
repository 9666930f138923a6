/// \file accel.h
/// Building acceleration structures over a scene's triangles. The structures see only
/// positions, indices and (for shadow rays) a per-triangle transmittance.
#pragma once

#include <cstdint>
#include <memory>
#include <span>
#include <string>

#include "specula/math.h"
#include "specula/tracer.h"

namespace specula {

enum class AccelKind { Bvh, Brute };

/// Parses "bvh" / "brute"; throws specula::Error listing the valid names otherwise.
AccelKind parse_accel_kind(const std::string& name);

/// What a structure is built over. Spans must outlive the build call only (data is copied
/// or precomputed into the structure).
struct TriangleInput {
  std::span<const Vec3> positions;
  std::span<const uint32_t> indices;  ///< 3 per triangle
  /// Per-triangle RGB transmittance for shadow rays (0 = opaque). Empty = all opaque.
  std::span<const Vec3> transmittance;
};

/// The traversal layout and kernels of a BVH (Bvh::build collapses the binary SAH tree into
/// it). Auto picks the best the CPU runs (checked at run time, one binary for every x86-64):
/// avx512x16, else avx2x8, else sse4.
enum class BvhKernel {
  Auto,
  Sse4,    ///< 4-wide nodes, SSE slab test (x86-64 baseline)
  Avx2x8,  ///< 8-wide nodes, AVX2 slab test
  Avx512x8,  ///< the same 8-wide nodes, code compiled for AVX-512VL (32 vector registers: no spills)
  Avx512x16,  ///< 16-wide nodes, AVX-512 slab test
};

/// Parses "auto" / "sse4" / "avx2x8" / "avx512x8" / "avx512x16"; throws specula::Error listing the valid names otherwise.
BvhKernel parse_bvh_kernel(const std::string& name);
/// "auto", "sse4", "avx2x8", "avx512x8" or "avx512x16".
const char* bvh_kernel_name(BvhKernel kernel);
/// Whether this CPU runs \p kernel (Auto: always).
bool bvh_kernel_supported(BvhKernel kernel);
/// Whether \p kernel walks 8-wide nodes (BvhWideNode8).
inline bool bvh_kernel_is_8_wide(BvhKernel kernel) {
  return kernel == BvhKernel::Avx2x8 || kernel == BvhKernel::Avx512x8;
}
/// \p kernel with Auto replaced by the best kernel this CPU runs.
BvhKernel resolve_bvh_kernel(BvhKernel kernel);
/// Rays per packet of \p kernel (BvhOptions::packets): groups of this many consecutive rays
/// are traced together when coherent (32 for every kernel).
int bvh_packet_rays(BvhKernel kernel);

/// How hard the build works on the tree. Fast: the binned-SAH tree with SAH-terminated leaves
/// (the default; what dynamic scenes and comparisons with other builders use). High, for static
/// scenes: the binned-SAH tree built down to single triangles, improved by subtree reinsertion
/// (Bittner et al. 2013; serial, until a round gains less than 0.1% of the cost), its leaves
/// then chosen by the collapse into wide nodes (any subtree of at most max_leaf_size
/// triangles, by SAH): a lower SAH cost and fewer traversal steps per ray for a build several
/// times slower. Hits are identical either way (every kernel returns the closest hit and
/// decides ties as brute force does).
enum class BvhQuality { Fast, High };

/// Parses "fast" / "high"; throws specula::Error listing the valid names otherwise.
BvhQuality parse_bvh_quality(const std::string& name);
/// "fast" or "high".
const char* bvh_quality_name(BvhQuality quality);

struct BvhOptions {
  int bins = 32;              ///< most SAH bins per axis (2..256); a node of n triangles uses 4 + n / 20
  /// Hard cap on a leaf's triangles; below it leaves are made by SAH termination. 8: with 16
  /// the SAH keeps leaves of 9-16 façade triangles in `city` that rays cross without hitting
  /// most of them (16-wide kernel: 12 triangle tests per shadow ray instead of 6, shadow rays
  /// ~18% slower); the bunny and the pool are no slower with 8.
  int max_leaf_size = 8;
  float traversal_cost = 1.0f;  ///< SAH cost of visiting a node, relative to one triangle test
  int threads = 0;            ///< 0 = all hardware threads
  BvhKernel kernel = BvhKernel::Auto;  ///< traversal layout; an unsupported one throws at build
  BvhQuality quality = BvhQuality::Fast;  ///< High: reinsertion optimisation after the build
  /// Trace coherent rays as packets: each group of bvh_packet_rays() consecutive rays of a batch
  /// (from the start of the span) whose rays share direction signs and dominant axis goes
  /// through the tree together (frustum culling, early-in), the others one by one. Results are
  /// bit-identical either way; only speed differs. Integrators help by putting neighbouring
  /// pixels' rays next to each other (4x4 blocks).
  bool packets = true;
};

/// Figures every build reports.
struct BuildInfo {
  double build_ms = 0.0;
  size_t nodes = 0;
  size_t leaves = 0;
  uint32_t max_depth = 0;
  double sah_cost = 0.0;  ///< SAH cost of the tree (root area normalised)
  /// BvhQuality::High: the binned-SAH tree's cost before the optimisation, the optimisation's
  /// share of build_ms, and the subtrees it moved (0 for Fast builds).
  double sah_cost_binned = 0.0;
  double optimize_ms = 0.0;
  uint64_t reinsertions = 0;
  size_t bytes = 0;
};

/// Builds the requested structure. Throws specula::Error on invalid input (index out of
/// range, non-finite vertex).
std::unique_ptr<Tracer> build_tracer(AccelKind kind, const TriangleInput& input,
                                     const BvhOptions& options = {}, BuildInfo* info = nullptr);

}  // namespace specula
