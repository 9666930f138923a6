/// \file triangles.h
/// Validated, copied triangle data shared by the accelerators (internal to src/accel).
#pragma once

#include <cstdint>
#include <span>
#include <vector>

#include "specula/accel.h"
#include "specula/bvh.h"
#include "specula/math.h"

namespace specula::accel {


/// Checks \p input (index count multiple of 3, indices in range, finite vertices used by a
/// triangle, transmittance size 0 or one per triangle, finite and non-negative); throws
/// specula::Error naming the first problem.
void validate_input(const TriangleInput& input);

/// Gathers the vertices (as BvhTriangle: the one triangle layout of the module) of every triangle in input order (input must be valid).
std::vector<BvhTriangle> gather_triangles(const TriangleInput& input);

/// True for triangles without a surface: zero (or non-finite) cross product of the edges, as
/// computed in float. They are left out of every structure: the watertight test could still
/// report a hit on them through rounding in its sheared space, and their normal is undefined.
/// Same predicate as the hit normal's normalize(), so every reported hit has a unit normal.
inline bool is_degenerate(const Vec3& v0, const Vec3& v1, const Vec3& v2) {
  const Vec3 c = cross(v1 - v0, v2 - v0);
  const float d = dot(c, c);
  return !(d > 0.0f && d < kInf);
}

/// True when the per-triangle transmittance is exactly zero (opaque, or no transmittance given).
inline bool is_opaque(const Vec3& tr) { return tr.x == 0.0f && tr.y == 0.0f && tr.z == 0.0f; }

}  // namespace specula::accel
