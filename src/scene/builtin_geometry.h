/// \file builtin_geometry.h
/// Procedural triangle meshes for the built-in scenes (internal to src/scene/builtin*.cpp).
/// Every closed mesh is wound counter-clockwise seen from outside, so geometric normals point
/// out of the solid: the Whitted integrator decides entering/leaving a medium from them.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "specula/math.h"
#include "specula/scene.h"

namespace specula::builtin {

/// Indexed triangles with per-vertex normals, appended to a Scene in one add_mesh call.
struct MeshBuilder {
  std::vector<Vec3> positions;
  std::vector<Vec3> normals;
  std::vector<uint32_t> indices;

  /// Flat quad a-b-c-d, counter-clockwise seen from the side its normal points to.
  void quad(const Vec3& a, const Vec3& b, const Vec3& c, const Vec3& d);
  /// Flat quad centred at \p c spanned by half-extent vectors \p u, \p v; faces cross(u, v).
  void quad_uv(const Vec3& c, const Vec3& u, const Vec3& v);
  /// Axis-aligned box with outward faces (24 vertices, flat normals).
  void box(const Aabb& b);
  /// Square slab with a square hole in the xy plane: |x|,|y| in [inner, outer], |z| <= half_t.
  void square_ring(float outer, float inner, float half_t);
  /// Applies an affine transform to what was added so far (normals by the inverse transpose).
  void transform(const Mat4& xf);
  /// Appends another builder.
  void append(const MeshBuilder& other);

  void add_to(Scene& scene, const std::string& name, uint32_t material) const;
};


/// Geodesic sphere: an icosahedron subdivided \p levels times (20 * 4^levels triangles),
/// with exact radial normals.
MeshBuilder icosphere(const Vec3& centre, float radius, int levels);

/// Affine map sending local x, y, z to (u, v, n) of the cube face with outward normal
/// sign * axis, then translating by \p offset along n. Exact (entries 0/+-1) and
/// orientation-preserving, so winding stays outward.
Mat4 face_frame(int axis, float sign, float offset);

/// Checkerboard of flat quads on an axis-aligned rectangle: the rectangle is centred at
/// \p c, spans 2|u| x 2|v|, faces cross(u, v) and is cut into nu x nv tiles; tiles with even
/// (i + j) go to \p even, the others to \p odd.
void checker_quads(MeshBuilder& even, MeshBuilder& odd, const Vec3& c, const Vec3& u,
                   const Vec3& v, int nu, int nv);

/// Appends a named pinhole camera at \p position looking at \p target with vertical field of
/// view \p vfov_degrees to \p scene (the first one added is the scene's default).
void add_camera(Scene& scene, const char* name, const Vec3& position, const Vec3& target, float vfov_degrees);

}  // namespace specula::builtin
