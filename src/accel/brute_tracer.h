/// \file brute_tracer.h
/// Brute-force tracer: tests every triangle for every ray. The oracle for the BVH tests and a
/// baseline for tiny scenes. Uses the same watertight triangle test as the BVH.
#pragma once

#include <vector>

#include "accel/triangles.h"
#include "specula/accel.h"
#include "specula/tracer.h"

namespace specula::accel {

class BruteTracer final : public Tracer {
 public:
  /// \p input must have been validated (see validate_input).
  explicit BruteTracer(const TriangleInput& input);

  std::string name() const override { return "brute"; }
  void intersect(std::span<const Ray> rays, std::span<Hit> hits,
                 TraceStats* stats = nullptr) const override;
  void transmittance(std::span<const Ray> rays, std::span<Vec3> out,
                     TraceStats* stats = nullptr) const override;
  size_t memory_bytes() const override;

 private:
  /// The non-degenerate triangles in input order, in blocks of 4 (index = scene index).
  std::vector<BvhTriangle4, detail::AlignedAllocator<BvhTriangle4>> groups_;
  uint32_t count_ = 0;               ///< non-degenerate triangles in groups_
  std::vector<Vec3> transmittance_;  ///< per scene triangle; empty = all opaque
};

}  // namespace specula::accel
