// Scene model helpers: mesh appending, normals, validation, default camera for bare meshes.
#include <cmath>
#include <string>

#include "specula/error.h"
#include "specula/scene.h"

namespace specula {

Aabb Scene::bounds() const {
  Aabb b;
  for (const Vec3& p : positions) b.grow(p);
  return b;
}

std::vector<Vec3> compute_vertex_normals(std::span<const Vec3> positions,
                                         std::span<const uint32_t> indices) {
  std::vector<Vec3> acc(positions.size());
  for (size_t i = 0; i + 2 < indices.size(); i += 3) {
    const uint32_t a = indices[i], b = indices[i + 1], c = indices[i + 2];
    if (a >= positions.size() || b >= positions.size() || c >= positions.size()) continue;
    // The un-normalised cross product weights each face by its area.
    const Vec3 n = cross(positions[b] - positions[a], positions[c] - positions[a]);
    if (!is_finite(n)) continue;
    acc[a] += n;
    acc[b] += n;
    acc[c] += n;
  }
  for (Vec3& n : acc) {
    const Vec3 u = normalize(n);
    n = (u == Vec3{}) ? Vec3{0, 1, 0} : u;
  }
  return acc;
}

MeshRange& Scene::add_mesh(std::string mesh_name, std::span<const Vec3> mesh_positions,
                           std::span<const uint32_t> mesh_indices, uint32_t material_id,
                           std::span<const Vec3> mesh_normals, const Mat4& xf) {
  if (mesh_indices.size() % 3 != 0)
    throw Error(mesh_name + ": index count " + std::to_string(mesh_indices.size()) +
                " is not a multiple of 3");
  const size_t base = positions.size();
  if (base + mesh_positions.size() > 0xFFFFFFF0u) throw Error(mesh_name + ": too many vertices");
  for (uint32_t idx : mesh_indices)
    if (idx >= mesh_positions.size())
      throw Error(mesh_name + ": vertex index " + std::to_string(idx) + " out of range (" +
                  std::to_string(mesh_positions.size()) + " vertices)");

  positions.reserve(base + mesh_positions.size());
  for (const Vec3& p : mesh_positions) positions.push_back(xf.transform_point(p));
  const std::span<const Vec3> world(positions.data() + base, mesh_positions.size());

  normals.resize(base);  // keep normals parallel to positions even if a caller broke it
  if (mesh_normals.size() == mesh_positions.size()) {
    for (const Vec3& n : mesh_normals) {
      Vec3 w = normalize(xf.transform_normal(n));
      normals.push_back(w == Vec3{} ? Vec3{0, 1, 0} : w);
    }
  } else {
    const std::vector<Vec3> computed = compute_vertex_normals(world, mesh_indices);
    normals.insert(normals.end(), computed.begin(), computed.end());
  }

  MeshRange range;
  range.name = std::move(mesh_name);
  range.first_triangle = static_cast<uint32_t>(triangle_count());
  range.triangle_count = static_cast<uint32_t>(mesh_indices.size() / 3);
  indices.reserve(indices.size() + mesh_indices.size());
  for (uint32_t idx : mesh_indices) indices.push_back(static_cast<uint32_t>(base + idx));
  material_ids.insert(material_ids.end(), range.triangle_count, material_id);
  meshes.push_back(std::move(range));
  return meshes.back();
}

uint32_t Scene::add_material(Material m) {
  materials.push_back(std::move(m));
  return static_cast<uint32_t>(materials.size() - 1);
}

std::optional<size_t> Scene::find_camera(const std::string& camera_name) const {
  for (size_t i = 0; i < cameras.size(); ++i)
    if (cameras[i].name == camera_name) return i;
  return std::nullopt;
}

void Scene::validate() const {
  const std::string who = name.empty() ? std::string("scene") : name;
  if (indices.size() % 3 != 0) throw Error(who + ": index count is not a multiple of 3");
  if (normals.size() != positions.size())
    throw Error(who + ": " + std::to_string(normals.size()) + " normals for " +
                std::to_string(positions.size()) + " vertices");
  if (material_ids.size() != triangle_count())
    throw Error(who + ": material id count differs from triangle count");
  for (size_t i = 0; i < positions.size(); ++i)
    if (!is_finite(positions[i]))
      throw Error(who + ": vertex " + std::to_string(i) + " is not finite");
  for (size_t i = 0; i < indices.size(); ++i)
    if (indices[i] >= positions.size())
      throw Error(who + ": triangle " + std::to_string(i / 3) + " uses vertex " +
                  std::to_string(indices[i]) + " of " + std::to_string(positions.size()));
  for (size_t i = 0; i < material_ids.size(); ++i)
    if (material_ids[i] >= materials.size())
      throw Error(who + ": triangle " + std::to_string(i) + " uses material " +
                  std::to_string(material_ids[i]) + " of " + std::to_string(materials.size()));
  for (size_t i = 1; i < cameras.size(); ++i)
    if (const auto first = find_camera(cameras[i].name); *first != i)
      throw Error(who + ": cameras " + std::to_string(*first) + " and " + std::to_string(i) + " are both named '" +
                  cameras[i].name + "' (cameras are selected by name)");
}

void add_default_camera_and_light(Scene& scene) {
  if (scene.materials.empty()) scene.add_material(Material{});
  const Aabb b = scene.bounds();
  const Vec3 c = b.empty() ? Vec3{} : b.center();
  const Vec3 e = b.empty() ? Vec3{1, 1, 1} : b.extent();
  const float radius = std::max(0.5f * length(e), 1e-6f);
  if (scene.cameras.empty()) {
    Camera cam;
    cam.name = "default";
    cam.vfov_degrees = 40.0f;
    // Far enough that the bounding sphere fits the vertical field of view, a little above.
    const float dist = radius / std::sin(0.5f * cam.vfov_degrees * kPi / 180.0f) * 1.05f;
    const Vec3 dir = normalize(Vec3{0.0f, 0.25f, 1.0f});
    cam.position = c + dir * dist;
    cam.target = c;
    scene.cameras.push_back(cam);
  }
  if (scene.lights.empty()) {
    Light l;
    l.name = "default";
    l.type = LightType::Point;
    const Camera& cam = scene.cameras.front();
    l.position = cam.position + Vec3{0.5f, 1.0f, 0.0f} * radius * 2.0f;
    // Inverse-square falloff: choose the intensity so the scene centre receives ~1.
    const float d = length(l.position - c);
    l.intensity = d * d;
    scene.lights.push_back(l);
  }
}

}  // namespace specula
