/// \file tracer.h
/// The one interface integrators trace through. Acceleration structures (BVH, brute force,
/// later grid/SVO/wide BVH/GPU) implement it; they know triangles, never shading.
///
/// Queries are batched (a span of rays per call) so the virtual dispatch happens once per
/// batch, not per ray, and so later implementations can use packets or streams internally.
#pragma once

#include <memory>
#include <span>
#include <string>

#include "specula/ray.h"

namespace specula {

struct Scene;

class Tracer {
 public:
  virtual ~Tracer() = default;

  /// Short name ("bvh", "brute", ...).
  virtual std::string name() const = 0;

  /// Closest hit for each ray in [tmin, tmax]; hits[i].prim == kNoHit on a miss.
  /// When \p stats is non-null, node visits and triangle tests are added to it.
  virtual void intersect(std::span<const Ray> rays, std::span<Hit> hits,
                         TraceStats* stats = nullptr) const = 0;

  /// Shadow query: for each ray, the product of the per-triangle transmittance of every
  /// triangle it crosses in (tmin, tmax). 0 as soon as an opaque triangle is met (any-hit,
  /// early exit); exactly 1 when nothing is crossed. Transmittance per triangle is given at
  /// build time (see TracerOptions::transmittance), so the structure never sees materials.
  virtual void transmittance(std::span<const Ray> rays, std::span<Vec3> out,
                             TraceStats* stats = nullptr) const = 0;

  /// Bytes used by the structure (nodes + triangle data).
  virtual size_t memory_bytes() const = 0;
};

}  // namespace specula
