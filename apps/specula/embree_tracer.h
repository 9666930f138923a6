// Embree 3 behind specula's Tracer interface, for `specula bench trace` comparisons only
// (owner: accel). Compiled only when CMake found libembree-dev (SPECULA_HAVE_EMBREE).
#pragma once

#ifdef SPECULA_HAVE_EMBREE

#include <cstddef>
#include <cstdint>
#include <memory>
#include <span>
#include <string>

#include "specula/accel.h"
#include "specula/tracer.h"

namespace specula::cli {

/// Triangle scene in Embree (RTC_BUILD_QUALITY_MEDIUM, one geometry; with \p robust,
/// RTC_SCENE_FLAG_ROBUST: robust traversal and no accuracy-reducing optimisations, Embree's
/// answer to rays slipping between neighbouring triangles). Queries use
/// rtcIntersect1 / rtcOccluded1 per ray, like our single-ray traversal, or, after
/// use_packets(true), rtcIntersect16 / rtcOccluded16 on each group of 16 consecutive rays with a
/// coherent-rays context (Embree's best on coherent packets). transmittance() is a plain
/// occlusion query (0 or 1): Embree sees every triangle as opaque here.
class EmbreeTracer final : public Tracer {
 public:
  /// \p threads: 0 = Embree's default (all hardware threads), else "threads=N" and the build
  /// run in a TBB arena of N threads.
  /// \p build_ms receives the rtcCommitScene time.
  EmbreeTracer(const TriangleInput& input, int threads, double* build_ms = nullptr, bool robust = false);
  ~EmbreeTracer() override;
  EmbreeTracer(const EmbreeTracer&) = delete;
  EmbreeTracer& operator=(const EmbreeTracer&) = delete;

  std::string name() const override { return "embree"; }
  void intersect(std::span<const Ray> rays, std::span<Hit> hits, TraceStats* stats = nullptr) const override;
  void transmittance(std::span<const Ray> rays, std::span<Vec3> out, TraceStats* stats = nullptr) const override;
  size_t memory_bytes() const override { return 0; }

  /// Trace groups of 16 consecutive rays with rtcIntersect16 / rtcOccluded16 (from the start of
  /// each span; a short last group runs with the missing lanes invalid).
  void use_packets(bool on) { packets_ = on; }

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
  bool packets_ = false;
};

/// Embree's own binned SAH builder on the triangles our BVH holds, scored with our cost.
struct EmbreeSahTree {
  double sah_cost = 0.0;  ///< BuildInfo::sah_cost's formula on Embree's tree
  size_t nodes = 0;       ///< inner nodes and leaves, as BuildInfo::nodes counts them
  size_t leaves = 0;
  uint32_t depth = 0;     ///< levels below the root
  double build_ms = 0.0;  ///< rtcBuildBVH, one thread
  int max_leaf = 0;       ///< the leaf limit Embree got (its builder takes at most 32)
};

/// Builds a binary tree over the non-degenerate triangles of \p input (the ones every specula
/// structure holds) with rtcBuildBVH at RTC_BUILD_QUALITY_MEDIUM, the binned SAH builder behind
/// Embree's medium scene build, given our builder's objective: two children per node, leaves of
/// at most \p max_leaf triangles decided by the SAH, charged per block of four triangles (as our
/// builder and Embree's Triangle4 scene build charge them), node cost \p traversal_cost.
/// Returns the tree's SAH cost as BuildInfo::sah_cost computes it (node half areas times
/// \p traversal_cost, leaves' times their triangles, over the root's), so the two builders'
/// trees compare directly. Embree's scene BVH itself is not exposed by its API.
EmbreeSahTree embree_binary_sah(const TriangleInput& input, int max_leaf, float traversal_cost);

}  // namespace specula::cli

#endif  // SPECULA_HAVE_EMBREE
