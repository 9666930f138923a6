// Watertightness: rays through shared edges and vertices of tessellated surfaces, and rays
// from inside closed meshes, must never slip through (Woop, Benthin, Wald 2013). Owner: accel.
#include <gtest/gtest.h>

#include <cmath>
#include <random>
#include <string>
#include <vector>

#include "accel_test_util.h"
#include "specula/accel.h"
#include "specula/load.h"
#include "test_util.h"

namespace specula {
namespace {

using test::Mesh;

/// Traces \p rays through both accelerators and expects every one of them to hit.
void expect_all_hit(const Mesh& mesh, const std::vector<Ray>& rays, const std::string& label) {
  for (const test::TracerVariant& variant : test::triangle_tracers()) {
    const auto t = build_tracer(variant.kind, mesh.input(), variant.options);
    std::vector<Hit> hits(rays.size());
    std::vector<Vec3> tr(rays.size());
    t->intersect(rays, hits);
    t->transmittance(rays, tr);
    size_t misses = 0, clear = 0, first = rays.size();
    for (size_t i = 0; i < rays.size(); ++i) {
      if (!hits[i].hit()) {
        ++misses;
        if (first == rays.size()) first = i;
      }
      clear += !(tr[i] == Vec3{});
    }
    const std::string first_ray =
        first < rays.size() ? "first: org (" + std::to_string(rays[first].org.x) + ", " + std::to_string(rays[first].org.y) + ", " +
                                  std::to_string(rays[first].org.z) + ") dir (" + std::to_string(rays[first].dir.x) + ", " +
                                  std::to_string(rays[first].dir.y) + ", " + std::to_string(rays[first].dir.z) + ")"
                            : "";
    EXPECT_EQ(misses, 0u) << label << " (" << variant.name << "): " << misses << " of " << rays.size()
                          << " rays slipped through; " << first_ray;
    EXPECT_EQ(clear, 0u) << label << " (" << variant.name << "): shadow rays slipped through";
  }
}

/// Rays from above aimed exactly at every vertex and at points on every edge of \p grid
/// (n x n quads of size \p step in the plane y = \p y starting at x0, z0), from random heights
/// and slants, plus straight-down rays with two zero direction components.
std::vector<Ray> rays_at_edges_and_vertices(int n, float step, float x0, float z0, float y, uint32_t seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<float> u(0.0f, 1.0f);
  std::vector<Ray> rays;
  const auto at = [&](float i, float j) { return Vec3{x0 + i * step, y, z0 + j * step}; };
  const auto add = [&](const Vec3& target, bool straight) {
    Ray r;
    if (straight) {
      r.org = target + Vec3{0, 1.0f + u(rng), 0};
      r.dir = {0, -1, 0};
    } else {
      r.org = target + Vec3{(u(rng) - 0.5f) * 4.0f * step, 0.5f + u(rng) * 3.0f, (u(rng) - 0.5f) * 4.0f * step};
      r.dir = target - r.org;
    }
    rays.push_back(r);
  };
  // Interior vertices (the outer boundary may legitimately be missed).
  for (int j = 1; j < n; ++j)
    for (int i = 1; i < n; ++i) {
      add(at(static_cast<float>(i), static_cast<float>(j)), true);
      add(at(static_cast<float>(i), static_cast<float>(j)), false);
    }
  // Points on interior edges: axis-aligned edges and both diagonal directions.
  for (int k = 0; k < 4 * n * n; ++k) {
    const int i = 1 + static_cast<int>(rng() % static_cast<uint32_t>(n - 1));
    const int j = 1 + static_cast<int>(rng() % static_cast<uint32_t>(n - 1));
    const float s = u(rng);
    const Vec3 base = at(static_cast<float>(i), static_cast<float>(j));
    Vec3 target;
    switch (k % 4) {
      case 0: target = lerp(base, at(static_cast<float>(i) + 1, static_cast<float>(j)), s); break;
      case 1: target = lerp(base, at(static_cast<float>(i), static_cast<float>(j) + 1), s); break;
      case 2: target = lerp(base, at(static_cast<float>(i) + 1, static_cast<float>(j) + 1), s); break;
      default: target = lerp(at(static_cast<float>(i) + 1, static_cast<float>(j)), at(static_cast<float>(i), static_cast<float>(j) + 1), s); break;
    }
    if (target.x >= x0 + static_cast<float>(n) * step || target.z >= z0 + static_cast<float>(n) * step) continue;
    add(target, (k / 4) % 2 == 0);
  }
  return rays;
}

TEST(Watertight, TessellatedPlaneHasNoCracks) {
  const Mesh grid = test::make_grid(16, 1.0f);
  expect_all_hit(grid, rays_at_edges_and_vertices(16, 1.0f, 0.0f, 0.0f, 0.0f, 1), "unit grid");
}

TEST(Watertight, PlaneWithUglyCoordinatesHasNoCracks) {
  // Non-representable step and a large offset: vertices are rounded, edges are not axis
  // aligned in the ray's sheared space, and the plane is far from the origin.
  const Mesh grid = test::make_grid(20, 0.1f, 1000.3f, -2000.7f, 17.77f);
  expect_all_hit(grid, rays_at_edges_and_vertices(20, 0.1f, 1000.3f, -2000.7f, 17.77f, 2), "offset grid");
  const Mesh tiny = test::make_grid(12, 1e-3f, 0.1f, 0.2f, -0.3f, false);
  expect_all_hit(tiny, rays_at_edges_and_vertices(12, 1e-3f, 0.1f, 0.2f, -0.3f, 3), "tiny grid");
}

/// Random rays from inside a closed mesh: from near the centre, from close to the surface,
/// aimed exactly at vertices, and along the axes (zero direction components).
std::vector<Ray> rays_from_inside(const Mesh& m, Vec3 center, float inner_radius, size_t count, uint32_t seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<float> u(0.0f, 1.0f);
  std::vector<Ray> rays;
  for (size_t i = 0; i < count; ++i) {
    Ray r;
    r.org = center + test::random_unit(rng) * (inner_radius * std::cbrt(u(rng)));
    switch (i % 4) {
      case 0: r.dir = test::random_unit(rng); break;
      case 1: r.dir = m.positions[rng() % m.positions.size()] - r.org; break;  // at a vertex
      case 2: {                                                            // axis aligned
        const int a = static_cast<int>(rng() % 3);
        r.dir = Vec3{};
        r.dir[a] = (rng() % 2) ? 1.0f : -1.0f;
        break;
      }
      default: {  // at a point on an edge
        const uint32_t t = static_cast<uint32_t>(rng() % m.triangle_count());
        const Vec3 a = m.positions[m.indices[3 * t]], b = m.positions[m.indices[3 * t + 1]];
        r.dir = lerp(a, b, u(rng)) - r.org;
        break;
      }
    }
    rays.push_back(r);
  }
  return rays;
}

// A transparent surface crossed exactly on an edge or vertex shared by several of its triangles
// must attenuate a shadow ray once, not once per triangle (both accelerators, any winding).
TEST(Watertight, TransparentSurfaceCountedOnceOnSharedEdgesAndVertices) {
  for (const bool alternate : {false, true}) {
    Mesh grid = test::make_grid(8, 0.25f, -1.0f, -1.0f, 0.0f, alternate);
    // Flip the winding of every third triangle: the rule must not depend on consistent winding.
    for (size_t t = 0; t < grid.triangle_count(); t += 3) std::swap(grid.indices[3 * t + 1], grid.indices[3 * t + 2]);
    const std::vector<Vec3> half(grid.triangle_count(), Vec3{0.5f, 0.5f, 0.5f});
    // Rays straight down through every vertex, edge midpoint and quad centre of the interior
    // (dyadic coordinates: the edge functions are exactly zero on edges and vertices), and
    // tilted rays through the same points.
    std::vector<Ray> rays;
    for (int j = 1; j < 16; ++j)
      for (int i = 1; i < 16; ++i) {
        const float x = -1.0f + 0.125f * static_cast<float>(i), z = -1.0f + 0.125f * static_cast<float>(j);
        rays.push_back({{x, 1.0f, z}, 0.0f, {0.0f, -1.0f, 0.0f}, kInf});
        rays.push_back({{x + 0.5f, 2.0f, z}, 0.0f, {-0.25f, -1.0f, 0.0f}, kInf});
        rays.push_back({{x, 2.0f, z - 0.5f}, 0.0f, {0.0f, -1.0f, 0.25f}, kInf});
      }
    for (const test::TracerVariant& variant : test::triangle_tracers()) {
      const auto tracer = build_tracer(variant.kind, grid.input(half), variant.options);
      std::vector<Vec3> tr(rays.size());
      tracer->transmittance(rays, tr);
      for (size_t r = 0; r < rays.size(); ++r)
        ASSERT_EQ(tr[r], (Vec3{0.5f, 0.5f, 0.5f}))
            << variant.name << (alternate ? " alternating" : "") << " ray " << r << " org ("
            << rays[r].org.x << ", " << rays[r].org.y << ", " << rays[r].org.z << ") gave " << tr[r].x;
      // Opaque triangles stay closed: every one of these rays is blocked, and hits. (The axis-
      // parallel rays run inside BVH boxes' face planes: 0 * inf slabs must not cull them.)
      const auto opaque = build_tracer(variant.kind, grid.input(), variant.options);
      opaque->transmittance(rays, tr);
      std::vector<Hit> hits(rays.size());
      opaque->intersect(rays, hits);
      for (size_t r = 0; r < rays.size(); ++r) {
        ASSERT_EQ(tr[r], Vec3{}) << "opaque, ray " << r;
        ASSERT_TRUE(hits[r].hit()) << "closest hit, ray " << r;
      }
    }
  }
}

TEST(Watertight, RaysFromInsideClosedSphereAlwaysHit) {
  const Mesh sphere = test::make_sphere(32, 64, 1.0f);
  expect_all_hit(sphere, rays_from_inside(sphere, {}, 0.9f, 20000, 4), "sphere");
  // Rays starting exactly at the centre, aimed at every vertex (poles: zero components).
  std::vector<Ray> at_vertices;
  for (const Vec3& p : sphere.positions) {
    Ray r;
    r.dir = p;
    at_vertices.push_back(r);
  }
  expect_all_hit(sphere, at_vertices, "sphere vertices from centre");
  // An off-centre, far-from-origin sphere.
  const Vec3 c{-300.25f, 12.5f, 4096.125f};
  const Mesh far = test::make_sphere(20, 40, 3.0f, c);
  expect_all_hit(far, rays_from_inside(far, c, 2.5f, 20000, 5), "far sphere");
}

TEST(Watertight, RaysFromInsideShippedClosedMesh) {
  // spot.obj is a closed genus-0 mesh: rays from a point inside it must all hit.
  SPECULA_REQUIRE_MESH(path, "spot.obj");
  const Scene scene = load_obj(path);
  Mesh m;
  m.positions = scene.positions;
  m.indices = scene.indices;
  // Find an interior point: the centre of the bounding box works for spot's body, but check it
  // with a majority vote of ray parities to be independent of the model's shape.
  const Vec3 center = scene.bounds().center();
  const auto bvh = build_tracer(AccelKind::Bvh, m.input());
  int inside_votes = 0;
  std::mt19937 rng(6);
  for (int i = 0; i < 15; ++i) {
    Ray r;
    r.org = center;
    r.dir = test::random_unit(rng);
    int crossings = 0;
    for (int guard = 0; guard < 100; ++guard) {
      Hit h;
      bvh->intersect(std::span<const Ray>(&r, 1), std::span<Hit>(&h, 1));
      if (!h.hit()) break;
      ++crossings;
      r.tmin = h.t * (1.0f + 1e-6f) + 1e-6f;
    }
    inside_votes += crossings % 2;
  }
  if (inside_votes < 12) GTEST_SKIP() << "bounding-box centre of spot.obj is not inside the mesh";
  expect_all_hit(m, rays_from_inside(m, center, 0.0f, 20000, 7), "spot.obj");
}

}  // namespace
}  // namespace specula
