// Small helpers shared by the tracer tests (BVH, voxel grid, octree): building rays, tracing one
// ray through the batched Tracer interface, describing a ray in a failure message.
#pragma once

#include <cstdint>
#include <span>
#include <sstream>
#include <string>

#include "specula/ray.h"
#include "specula/tracer.h"

namespace specula::test {

inline Ray make_ray(Vec3 org, Vec3 dir, float tmin = 0.0f, float tmax = kInf) {
  Ray r;
  r.org = org;
  r.dir = dir;
  r.tmin = tmin;
  r.tmax = tmax;
  return r;
}

/// A hit record no tracer returns (t -1, prim \p prim, a "hit"): outputs that start as two
/// different ones show every ray a tracer left unwritten as a difference (Tracer::intersect
/// writes every hit, a miss too).
inline Hit unwritten_hit(uint32_t prim) {
  Hit h;
  h.t = -1.0f;
  h.prim = prim;
  return h;
}

inline Hit trace1(const Tracer& t, const Ray& r) {
  Hit h;
  t.intersect(std::span<const Ray>(&r, 1), std::span<Hit>(&h, 1));
  return h;
}

inline Vec3 transmit1(const Tracer& t, const Ray& r) {
  Vec3 v;
  t.transmittance(std::span<const Ray>(&r, 1), std::span<Vec3>(&v, 1));
  return v;
}

inline std::string describe(const Ray& r) {
  std::ostringstream os;
  os.precision(9);
  os << "org (" << r.org.x << ", " << r.org.y << ", " << r.org.z << ") dir (" << r.dir.x << ", " << r.dir.y << ", "
     << r.dir.z << ") t [" << r.tmin << ", " << r.tmax << "]";
  return os.str();
}

}  // namespace specula::test
