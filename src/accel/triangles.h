/// \file triangles.h
/// Validated, copied triangle data shared by the accelerators (internal to src/accel).
#pragma once

#include <cstdint>
#include <span>
#include <vector>

#include "specula/accel.h"
#include "specula/math.h"

namespace specula::accel {

/// The three vertices of one triangle, copied out of the indexed input.
struct TriangleVerts {
  Vec3 v0, v1, v2;
};

/// Checks \p input (index count multiple of 3, indices in range, finite vertices used by a
/// triangle, transmittance size 0 or one per triangle, finite and non-negative); throws
/// specula::Error naming the first problem.
void validate_input(const TriangleInput& input);

/// Gathers the vertices of every triangle in input order (input must be valid).
std::vector<TriangleVerts> gather_triangles(const TriangleInput& input);

/// True when the per-triangle transmittance is exactly zero (opaque, or no transmittance given).
inline bool is_opaque(const Vec3& tr) { return tr.x == 0.0f && tr.y == 0.0f && tr.z == 0.0f; }

}  // namespace specula::accel
