// Procedural meshes for the built-in scenes (owner: render).
#include <array>
#include <map>
#include <utility>

#include "scene/builtin_geometry.h"

namespace specula::builtin {

void MeshBuilder::quad(const Vec3& a, const Vec3& b, const Vec3& c, const Vec3& d) {
  const Vec3 n = normalize(cross(b - a, c - a));
  const auto base = static_cast<uint32_t>(positions.size());
  for (const Vec3& p : {a, b, c, d}) {
    positions.push_back(p);
    normals.push_back(n);
  }
  for (uint32_t i : {0u, 1u, 2u, 0u, 2u, 3u}) indices.push_back(base + i);
}

void MeshBuilder::quad_uv(const Vec3& c, const Vec3& u, const Vec3& v) {
  quad(c - u - v, c + u - v, c + u + v, c - u + v);
}

void MeshBuilder::box(const Aabb& b) {
  const Vec3 c = b.center(), h = b.extent() * 0.5f;
  for (int k = 0; k < 3; ++k) {
    const int k1 = (k + 1) % 3, k2 = (k + 2) % 3;
    Vec3 n, u, v;
    n[k] = h[k];
    u[k1] = h[k1];
    v[k2] = h[k2];
    quad_uv(c + n, u, v);   // faces +axis: cross(e_k1, e_k2) = e_k
    quad_uv(c - n, v, u);   // faces -axis
  }
}

void MeshBuilder::square_ring(float outer, float inner, float half_t) {
  const float R = outer, r = inner, t = half_t;
  // Four 90-degree rotations of one side (exact: coordinates are swapped and negated).
  auto rot = [](const Vec3& p, int q) {
    Vec3 o = p;
    for (int i = 0; i < q; ++i) o = {-o.y, o.x, o.z};
    return o;
  };
  for (int q = 0; q < 4; ++q) {
    // Side at y = -R .. -r (the strip below the hole before rotation).
    const Vec3 o0{-R, -R, 0}, o1{R, -R, 0}, i1{r, -r, 0}, i0{-r, -r, 0};
    const Vec3 zt{0, 0, t};
    // Top (+z) and bottom (-z) trapezoids.
    quad(rot(o0 + zt, q), rot(o1 + zt, q), rot(i1 + zt, q), rot(i0 + zt, q));
    quad(rot(i0 - zt, q), rot(i1 - zt, q), rot(o1 - zt, q), rot(o0 - zt, q));
    // Outer wall facing -y, inner wall (hole side) facing +y.
    quad(rot(o0 - zt, q), rot(o1 - zt, q), rot(o1 + zt, q), rot(o0 + zt, q));
    quad(rot(i1 - zt, q), rot(i0 - zt, q), rot(i0 + zt, q), rot(i1 + zt, q));
  }
}


void MeshBuilder::transform(const Mat4& xf) {
  for (Vec3& p : positions) p = xf.transform_point(p);
  for (Vec3& n : normals) n = normalize(xf.transform_normal(n));
}

void MeshBuilder::append(const MeshBuilder& other) {
  const auto base = static_cast<uint32_t>(positions.size());
  positions.insert(positions.end(), other.positions.begin(), other.positions.end());
  normals.insert(normals.end(), other.normals.begin(), other.normals.end());
  for (uint32_t i : other.indices) indices.push_back(base + i);
}

void MeshBuilder::add_to(Scene& scene, const std::string& name, uint32_t material) const {
  if (indices.empty()) return;
  scene.add_mesh(name, positions, indices, material, normals);
}

MeshBuilder icosphere(const Vec3& centre, float radius, int levels) {
  const float g = (1.0f + std::sqrt(5.0f)) * 0.5f;
  std::vector<Vec3> v = {{-1, g, 0}, {1, g, 0}, {-1, -g, 0}, {1, -g, 0}, {0, -1, g}, {0, 1, g},
                         {0, -1, -g}, {0, 1, -g}, {g, 0, -1}, {g, 0, 1}, {-g, 0, -1}, {-g, 0, 1}};
  for (Vec3& p : v) p = normalize(p);
  std::vector<std::array<uint32_t, 3>> f = {
      {0, 11, 5}, {0, 5, 1}, {0, 1, 7}, {0, 7, 10}, {0, 10, 11}, {1, 5, 9}, {5, 11, 4},
      {11, 10, 2}, {10, 7, 6}, {7, 1, 8}, {3, 9, 4}, {3, 4, 2}, {3, 2, 6}, {3, 6, 8},
      {3, 8, 9}, {4, 9, 5}, {2, 4, 11}, {6, 2, 10}, {8, 6, 7}, {9, 8, 1}};
  for (int l = 0; l < levels; ++l) {
    std::map<std::pair<uint32_t, uint32_t>, uint32_t> mid;
    auto midpoint = [&](uint32_t a, uint32_t b) {
      const auto key = std::minmax(a, b);
      auto it = mid.find(key);
      if (it != mid.end()) return it->second;
      v.push_back(normalize(v[a] + v[b]));
      const auto id = static_cast<uint32_t>(v.size() - 1);
      mid.emplace(key, id);
      return id;
    };
    std::vector<std::array<uint32_t, 3>> nf;
    nf.reserve(f.size() * 4);
    for (const auto& t : f) {
      const uint32_t a = midpoint(t[0], t[1]), b = midpoint(t[1], t[2]), c = midpoint(t[2], t[0]);
      nf.push_back({t[0], a, c});
      nf.push_back({t[1], b, a});
      nf.push_back({t[2], c, b});
      nf.push_back({a, b, c});
    }
    f = std::move(nf);
  }
  MeshBuilder m;
  for (const Vec3& p : v) {
    m.positions.push_back(centre + p * radius);
    m.normals.push_back(p);
  }
  for (const auto& t : f)
    for (uint32_t i : t) m.indices.push_back(i);
  return m;
}

void add_camera(Scene& scene, const char* name, const Vec3& position, const Vec3& target, float vfov_degrees) {
  Camera c;
  c.name = name;
  c.position = position;
  c.target = target;
  c.vfov_degrees = vfov_degrees;
  scene.cameras.push_back(c);
}

Mat4 face_frame(int axis, float sign, float offset) {
  const int k1 = (axis + 1) % 3, k2 = (axis + 2) % 3;
  Vec3 u, v, n;
  n[axis] = sign;
  if (sign > 0) {
    u[k1] = 1;
    v[k2] = 1;
  } else {
    u[k2] = 1;
    v[k1] = 1;
  }
  Mat4 m;
  // Columns are the images of the local axes.
  for (size_t r = 0; r < 3; ++r) {
    const int i = static_cast<int>(r);
    m.m[r * 4 + 0] = u[i];
    m.m[r * 4 + 1] = v[i];
    m.m[r * 4 + 2] = n[i];
    m.m[r * 4 + 3] = n[i] * offset;
  }
  return m;
}

void checker_quads(MeshBuilder& even, MeshBuilder& odd, const Vec3& c, const Vec3& u,
                   const Vec3& v, int nu, int nv) {
  const Vec3 du = u * (2.0f / static_cast<float>(nu)), dv = v * (2.0f / static_cast<float>(nv));
  const Vec3 origin = c - u - v;
  for (int j = 0; j < nv; ++j)
    for (int i = 0; i < nu; ++i) {
      // Corners from integer multiples so neighbouring tiles share exact edge positions.
      const Vec3 a = origin + du * static_cast<float>(i) + dv * static_cast<float>(j);
      const Vec3 b = origin + du * static_cast<float>(i + 1) + dv * static_cast<float>(j);
      const Vec3 cc = origin + du * static_cast<float>(i + 1) + dv * static_cast<float>(j + 1);
      const Vec3 d = origin + du * static_cast<float>(i) + dv * static_cast<float>(j + 1);
      ((i + j) % 2 == 0 ? even : odd).quad(a, b, cc, d);
    }
}

}  // namespace specula::builtin
