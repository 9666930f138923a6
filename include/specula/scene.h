/// \file scene.h
/// The scene is plain data: flat world-space triangle arrays, materials, lights, cameras and
/// a sky. Loaders produce it, acceleration structures read its triangles, integrators read
/// everything. Nothing here knows about files or acceleration structures.
#pragma once

#include <cstdint>
#include <optional>
#include <span>
#include <string>
#include <vector>

#include "specula/math.h"

namespace specula {

/// Surface description for the Whitted integrator (Blinn-Phong + perfect mirror + dielectric).
/// Energy split at a hit: `reflectivity` goes to the mirror ray, `transparency` to the
/// refracted ray (Fresnel-weighted when ior != 1), the rest is shaded locally.
struct Material {
  std::string name = "default";
  Vec3 diffuse{0.8f, 0.8f, 0.8f};
  Vec3 specular{0.0f, 0.0f, 0.0f};
  float phong_exponent = 32.0f;
  float reflectivity = 0.0f;   ///< [0,1] mirror reflection weight
  float transparency = 0.0f;   ///< [0,1] transmission weight
  float ior = 1.0f;            ///< index of refraction of the medium behind the surface
  /// Beer-Lambert attenuation coefficient per metre (per scene unit) inside the medium:
  /// transmittance over distance d is exp(-absorption * d). Zero = clear.
  Vec3 absorption{0.0f, 0.0f, 0.0f};
  Vec3 emission{0.0f, 0.0f, 0.0f};
  /// True when the material separates two media (transparency > 0 and the mesh is closed):
  /// set by loaders for glass/water; the integrator then tracks entering/leaving.
  bool dielectric() const { return transparency > 0.0f; }
};

enum class LightType : uint8_t { Point, Directional, Sphere };

struct Light {
  LightType type = LightType::Point;
  std::string name;
  Vec3 color{1, 1, 1};
  float intensity = 1.0f;  ///< radiant intensity (W/sr) for point/sphere, irradiance for directional
  Vec3 position{0, 0, 0};  ///< point / sphere
  Vec3 direction{0, -1, 0};  ///< directional: direction the light travels (unit)
  float radius = 0.0f;     ///< sphere lights only
  int samples = 1;         ///< shadow samples for sphere lights (deterministic sequence)
};

struct Camera {
  std::string name = "default";
  Vec3 position{0, 0, 5};
  Vec3 target{0, 0, 0};
  Vec3 up{0, 1, 0};
  float vfov_degrees = 45.0f;  ///< vertical field of view
};

enum class SkyType : uint8_t { Constant, Gradient, Image };

struct Sky {
  SkyType type = SkyType::Gradient;
  Vec3 color{0.6f, 0.7f, 0.9f};     ///< constant colour, or the gradient's zenith colour
  Vec3 horizon{0.9f, 0.9f, 0.95f};  ///< gradient's horizon colour (below the horizon too)
  std::string image_path;           ///< equirectangular HDR (Radiance .hdr / .exr / any stb format)
  float intensity = 1.0f;
  /// Decoded equirectangular image (linear RGB, row-major, top row = +y); filled by load_sky_image.
  int image_width = 0, image_height = 0;
  std::vector<Vec3> image;
};

/// A named range of triangles (one mesh or one glTF primitive) inside Scene's flat arrays.
struct MeshRange {
  std::string name;
  uint32_t first_triangle = 0;
  uint32_t triangle_count = 0;
};

/// Plain-data scene. All geometry is in world space; triangle i uses
/// positions[indices[3i+0..2]], material materials[material_ids[i]]. Triangle order is
/// file order (polygons fan-triangulated in order), so trace prim ids match the file.
struct Scene {
  std::string name;
  std::vector<Vec3> positions;
  std::vector<Vec3> normals;  ///< per vertex; same size as positions (computed when absent)
  std::vector<uint32_t> indices;
  std::vector<uint32_t> material_ids;  ///< per triangle
  std::vector<Material> materials;
  std::vector<MeshRange> meshes;
  std::vector<Light> lights;
  std::vector<Camera> cameras;
  Sky sky;
  Vec3 ambient{0.05f, 0.05f, 0.05f};  ///< ambient term of the Whitted shading

  size_t triangle_count() const { return indices.size() / 3; }
  Aabb bounds() const;

  /// Appends a mesh. Positions are transformed by \p xf; when \p normals is empty (or its
  /// size differs from positions) area-weighted vertex normals are computed. Returns the range.
  MeshRange& add_mesh(std::string mesh_name, std::span<const Vec3> positions,
                      std::span<const uint32_t> indices, uint32_t material_id,
                      std::span<const Vec3> normals = {}, const Mat4& xf = Mat4::identity());
  /// Appends a material and returns its id.
  uint32_t add_material(Material m);
  /// Index of the camera named \p name, or nullopt.
  std::optional<size_t> find_camera(const std::string& camera_name) const;
  /// Throws specula::Error naming the problem if any index, material id or vertex is invalid, or
  /// if two cameras share a name (cameras are selected by name).
  void validate() const;
};

/// Area-weighted vertex normals for one indexed triangle list; degenerate triangles
/// contribute nothing and vertices without a valid normal get (0, 1, 0), never NaN.
std::vector<Vec3> compute_vertex_normals(std::span<const Vec3> positions,
                                         std::span<const uint32_t> indices);

/// Adds a camera that frames the whole scene (looking down -z from +z, slightly above), a
/// default point light near the camera and a default material if none; used for bare meshes.
void add_default_camera_and_light(Scene& scene);

}  // namespace specula
