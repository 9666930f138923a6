// Procedural meshes and ray generators shared by the acceleration-structure tests
// (bvh_test.cpp, watertight_test.cpp). Owner: accel.
#pragma once

#include <cmath>
#include <cstdint>
#include <cstdio>
#include <string>
#include <random>
#include <vector>

#include "specula/accel.h"
#include "specula/math.h"
#include "specula/ray.h"

namespace specula::test {

/// Every BVH kernel this CPU runs: the tests force each one in turn.
inline std::vector<BvhKernel> test_kernels() {
  std::vector<BvhKernel> k{BvhKernel::Sse4};
  for (const BvhKernel wide : {BvhKernel::Avx2x8, BvhKernel::Avx512x8, BvhKernel::Avx512x16}) {
    if (bvh_kernel_supported(wide)) {
      k.push_back(wide);
    } else {
      static bool said[3] = {false, false, false};
      bool& s = said[wide == BvhKernel::Avx2x8 ? 0 : wide == BvhKernel::Avx512x8 ? 1 : 2];
      if (!s) std::printf("note: this CPU cannot run the %s BVH kernel; it is not tested here\n", bvh_kernel_name(wide));
      s = true;
    }
  }
  return k;
}

/// One triangle tracer to test: brute force, or the BVH with one kernel.
struct TracerVariant {
  std::string name;  ///< "brute", "bvh sse4", "bvh avx2x8", ...
  AccelKind kind;
  BvhOptions options;
};

/// Brute force and the BVH with every kernel this CPU runs.
inline std::vector<TracerVariant> triangle_tracers() {
  std::vector<TracerVariant> v{{"brute", AccelKind::Brute, {}}};
  for (const BvhKernel k : test_kernels()) {
    BvhOptions o;
    o.kernel = k;
    v.push_back({std::string("bvh ") + bvh_kernel_name(k), AccelKind::Bvh, o});
  }
  return v;
}

struct Mesh {
  std::vector<Vec3> positions;
  std::vector<uint32_t> indices;

  TriangleInput input(std::span<const Vec3> transmittance = {}) const {
    return TriangleInput{positions, indices, transmittance};
  }
  size_t triangle_count() const { return indices.size() / 3; }
  Aabb bounds() const {
    Aabb b;
    for (const Vec3& p : positions) b.grow(p);
    return b;
  }
};

/// n x n quads in the plane y = \p y over [x0, x0 + n * step] x [z0, z0 + n * step], two
/// triangles per quad sharing the diagonal; \p alternate flips the diagonal in a checkerboard.
inline Mesh make_grid(int n, float step = 1.0f, float x0 = 0.0f, float z0 = 0.0f, float y = 0.0f,
                      bool alternate = true) {
  Mesh m;
  for (int j = 0; j <= n; ++j)
    for (int i = 0; i <= n; ++i)
      m.positions.push_back({x0 + static_cast<float>(i) * step, y, z0 + static_cast<float>(j) * step});
  const auto id = [n](int i, int j) { return static_cast<uint32_t>(j * (n + 1) + i); };
  for (int j = 0; j < n; ++j)
    for (int i = 0; i < n; ++i) {
      const uint32_t a = id(i, j), b = id(i + 1, j), c = id(i + 1, j + 1), d = id(i, j + 1);
      if (alternate && ((i + j) & 1)) {
        m.indices.insert(m.indices.end(), {a, b, d, b, c, d});
      } else {
        m.indices.insert(m.indices.end(), {a, b, c, a, c, d});
      }
    }
  return m;
}

/// Closed UV sphere with shared vertices (poles are single vertices), outward winding.
inline Mesh make_sphere(int stacks, int slices, float radius = 1.0f, Vec3 center = {}) {
  Mesh m;
  m.positions.push_back(center + Vec3{0, radius, 0});
  for (int s = 1; s < stacks; ++s) {
    const float theta = kPi * static_cast<float>(s) / static_cast<float>(stacks);
    for (int k = 0; k < slices; ++k) {
      const float phi = 2.0f * kPi * static_cast<float>(k) / static_cast<float>(slices);
      m.positions.push_back(center + Vec3{radius * std::sin(theta) * std::cos(phi), radius * std::cos(theta),
                                          radius * std::sin(theta) * std::sin(phi)});
    }
  }
  m.positions.push_back(center + Vec3{0, -radius, 0});
  const uint32_t south = static_cast<uint32_t>(m.positions.size() - 1);
  const auto ring = [slices](int s, int k) { return static_cast<uint32_t>(1 + (s - 1) * slices + (k % slices)); };
  for (int k = 0; k < slices; ++k) m.indices.insert(m.indices.end(), {0, ring(1, k + 1), ring(1, k)});
  for (int s = 1; s < stacks - 1; ++s)
    for (int k = 0; k < slices; ++k) {
      const uint32_t a = ring(s, k), b = ring(s, k + 1), c = ring(s + 1, k + 1), d = ring(s + 1, k);
      m.indices.insert(m.indices.end(), {a, b, c, a, c, d});
    }
  for (int k = 0; k < slices; ++k) m.indices.insert(m.indices.end(), {south, ring(stacks - 1, k), ring(stacks - 1, k + 1)});
  return m;
}

/// Random triangle soup inside the unit cube, with some degenerate triangles (repeated vertex,
/// collinear vertices) and some axis-aligned ones mixed in.
inline Mesh make_soup(int count, uint32_t seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<float> u(0.0f, 1.0f), small(-0.1f, 0.1f);
  Mesh m;
  for (int i = 0; i < count; ++i) {
    const Vec3 a{u(rng), u(rng), u(rng)};
    Vec3 b = a + Vec3{small(rng), small(rng), small(rng)};
    Vec3 c = a + Vec3{small(rng), small(rng), small(rng)};
    switch (i % 17) {
      case 3: b = a; break;                       // repeated vertex
      case 7: c = a + (b - a) * 2.0f; break;      // collinear
      case 11: b.y = a.y, c.y = a.y; break;       // axis-aligned (flat box)
      case 13: b.x = a.x, c.x = a.x; break;
      default: break;
    }
    const uint32_t base = static_cast<uint32_t>(m.positions.size());
    m.positions.insert(m.positions.end(), {a, b, c});
    m.indices.insert(m.indices.end(), {base, base + 1, base + 2});
  }
  return m;
}

inline Vec3 random_unit(std::mt19937& rng) {
  std::normal_distribution<float> n(0.0f, 1.0f);
  for (;;) {
    const Vec3 v{n(rng), n(rng), n(rng)};
    const float l = length(v);
    if (l > 1e-3f) return v / l;
  }
}

/// A mix of rays for oracle tests around and through \p box, deterministic for \p seed:
/// rays aimed through the box from outside, random directions, directions with one or two
/// exactly-zero components, rays starting inside, rays from mesh vertices, and finite
/// [tmin, tmax] intervals.
inline std::vector<Ray> make_oracle_rays(const Aabb& box, std::span<const Vec3> vertices, size_t count, uint32_t seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<float> u01(0.0f, 1.0f);
  const Vec3 ext = max(box.extent(), Vec3(1e-3f));
  const auto in_box = [&](float grow) {
    return box.min - ext * grow + Vec3{u01(rng), u01(rng), u01(rng)} * ext * (1.0f + 2.0f * grow);
  };
  std::vector<Ray> rays(count);
  for (size_t i = 0; i < count; ++i) {
    Ray& r = rays[i];
    switch (i % 10) {
      case 0:
      case 1:
      case 2:  // from outside, aimed through the box
        r.org = in_box(0.75f);
        r.dir = in_box(0.0f) - r.org;
        break;
      case 3:  // anywhere, random direction
        r.org = in_box(0.5f);
        r.dir = random_unit(rng) * (0.5f + 2.0f * u01(rng));
        break;
      case 4: {  // one or two zero direction components
        r.org = in_box(0.25f);
        r.dir = in_box(0.0f) - r.org;
        const int a = static_cast<int>(rng() % 3);
        r.dir[a] = 0.0f;
        if (rng() % 2) r.dir[(a + 1) % 3] = 0.0f;
        if (r.dir == Vec3{}) r.dir[(a + 2) % 3] = 1.0f;
        break;
      }
      case 5:
      case 6:  // starting inside the box
        r.org = in_box(0.0f);
        r.dir = random_unit(rng);
        break;
      case 7:  // starting on a mesh vertex, or aimed exactly at one
        if (!vertices.empty()) {
          const Vec3 v = vertices[rng() % vertices.size()];
          if (rng() % 2) {
            r.org = v;
            r.dir = random_unit(rng);
          } else {
            r.org = in_box(0.5f);
            r.dir = v - r.org;
          }
        } else {
          r.org = in_box(0.5f);
          r.dir = random_unit(rng);
        }
        break;
      default:  // finite interval
        r.org = in_box(0.5f);
        r.dir = in_box(0.0f) - r.org;
        r.tmin = u01(rng) * 0.5f;
        r.tmax = r.tmin + u01(rng) * 1.5f;
        break;
    }
    if (r.dir == Vec3{}) r.dir = {0.0f, 0.0f, 1.0f};
  }
  return rays;
}

}  // namespace specula::test
