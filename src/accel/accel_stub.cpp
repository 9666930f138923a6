// Placeholder until the BVH lands; owner: accel. Delete when implementing.
#include "specula/accel.h"
#include "specula/error.h"

namespace specula {
AccelKind parse_accel_kind(const std::string& name) {
  if (name == "bvh") return AccelKind::Bvh;
  if (name == "brute") return AccelKind::Brute;
  throw Error("unknown accelerator '" + name + "' (valid: bvh, brute)");
}
std::unique_ptr<Tracer> build_tracer(AccelKind, const TriangleInput&, const BvhOptions&, BuildInfo*) {
  throw Error("build_tracer: not implemented");
}
}  // namespace specula
