// Ray packets (BvhOptions::packets) against single-ray traversal and brute force: coherent
// camera and shadow rays, packets with mixed active masks, zero and negative-zero direction
// components, rays starting exactly on triangles, rays through shared edges and vertices, NaN
// rays, transparent layers (more than a packet lane keeps), every kernel the CPU runs.
// Owner: accel.
#include <gtest/gtest.h>

#include <cmath>
#include <cstring>
#include <limits>
#include <random>
#include <string>
#include <vector>

#include "accel_test_util.h"
#include "ray_test_util.h"
#include "specula/accel.h"
#include "specula/bvh.h"
#include "specula/load.h"
#include "specula/render.h"
#include "test_util.h"

namespace specula {
namespace {

using test::describe;
using test::Mesh;

constexpr float kNaN = std::numeric_limits<float>::quiet_NaN();

/// Primary rays of a \p w x \p h pinhole view of \p box from direction \p from (a unit-ish
/// vector from the box centre towards the eye), ordered in 4x4 pixel blocks as the Whitted
/// integrator orders them: 16 consecutive rays are one block.
std::vector<Ray> block_camera_rays(const Aabb& box, Vec3 from, int w, int h, float spread = 1.0f) {
  const Vec3 c = box.center();
  const float radius = 0.5f * length(box.max - box.min);
  const Vec3 eye = c + normalize(from) * (2.5f * radius);
  const Vec3 fwd = normalize(c - eye);
  Vec3 right, up;
  orthonormal_basis(fwd, right, up);
  std::vector<Ray> rays;
  for (int by = 0; by < h; by += 4)
    for (int bx = 0; bx < w; bx += 4)
      for (int y = by; y < std::min(by + 4, h); ++y)
        for (int x = bx; x < std::min(bx + 4, w); ++x) {
          const float sx = ((static_cast<float>(x) + 0.5f) / static_cast<float>(w) - 0.5f) * spread;
          const float sy = ((static_cast<float>(y) + 0.5f) / static_cast<float>(h) - 0.5f) * spread;
          rays.push_back(test::make_ray(eye, normalize(fwd + right * sx + up * sy)));
        }
  return rays;
}

/// Shadow rays from the hits of \p primary towards the point \p light, as the integrator makes
/// them (origin offset off the surface, direction to the light, tmax 1); with \p on_surface the
/// origin is the hit point itself (exactly on the triangle up to rounding, t = 0 crossings).
std::vector<Ray> shadow_rays(const Tracer& tracer, const std::vector<Ray>& primary, const Vec3& light,
                             bool on_surface = false) {
  std::vector<Hit> hits(primary.size());
  tracer.intersect(primary, hits);
  std::vector<Ray> out;
  for (size_t i = 0; i < hits.size(); ++i) {
    if (!hits[i].hit()) continue;
    const Ray& r = primary[i];
    const Vec3 p = r.org + r.dir * hits[i].t;
    const Vec3 n = dot(r.dir, hits[i].ng) < 0.0f ? hits[i].ng : -hits[i].ng;
    Ray s;
    s.org = on_surface ? p : offset_ray_origin(p, n);
    s.dir = light - s.org;
    s.tmin = 0.0f;
    s.tmax = 1.0f;
    out.push_back(s);
  }
  return out;
}

/// Bitwise equality (NaN payloads, signed zeros and all).
template <class T>
bool same_bits(const T& a, const T& b) {
  return std::memcmp(&a, &b, sizeof(T)) == 0;
}

std::string hit_text(const Hit& h) {
  return h.hit() ? "prim " + std::to_string(h.prim) + " t " + std::to_string(h.t) : std::string("miss");
}

struct PacketCheck {
  bool expect_packets = true;  ///< coherent input: packets must actually be traced
  size_t brute_every = 1;      ///< compare with brute force on every n-th ray (0: never)
  bool expect_hits = true;     ///< some ray must hit or be shadowed
};

/// Traces \p rays with every kernel, packets off and on, in one batch and in odd-sized chunks
/// (tail groups of every size), and expects bit-identical hit records and transmittance: packet
/// = single ray = brute force. \p options: the build (kernel and packets are set per run).
void expect_packets_match(const TriangleInput& input, const std::vector<Ray>& rays, const std::string& label,
                          const PacketCheck& check = {}, const BvhOptions& options = {}) {
  const size_t n = rays.size();
  // Every output starts as its own record no tracer returns: a ray a kernel leaves unwritten
  // (Tracer::intersect and transmittance write every ray, a miss too) shows as a difference.
  const auto poison = test::unwritten_hit;
  std::vector<Hit> hb(n, poison(0xFFFFFFF0u));
  std::vector<Vec3> tb(n, Vec3(-1.0f));
  if (check.brute_every > 0) {
    const auto brute = build_tracer(AccelKind::Brute, input);
    for (size_t i = 0; i < n; i += check.brute_every) {
      brute->intersect(std::span<const Ray>(&rays[i], 1), std::span<Hit>(&hb[i], 1));
      brute->transmittance(std::span<const Ray>(&rays[i], 1), std::span<Vec3>(&tb[i], 1));
    }
  }
  for (const BvhKernel kernel : test::test_kernels()) {
    const std::string where = label + " [" + bvh_kernel_name(kernel) + "]";
    BvhOptions single_opt = options, packet_opt = options;
    single_opt.kernel = packet_opt.kernel = kernel;
    single_opt.packets = false;
    packet_opt.packets = true;
    const auto single = build_tracer(AccelKind::Bvh, input, single_opt);
    const auto packet = build_tracer(AccelKind::Bvh, input, packet_opt);
    std::vector<Hit> hs(n, poison(0xFFFFFFF1u)), hp(n, poison(0xFFFFFFF2u)), hc(n, poison(0xFFFFFFF3u));
    std::vector<Vec3> ts(n, Vec3(-2.0f)), tp(n, Vec3(-3.0f)), tc(n, Vec3(-4.0f));
    single->intersect(rays, hs);
    single->transmittance(rays, ts);
    TraceStats st, stt;
    packet->intersect(rays, hp, &st);
    packet->transmittance(rays, tp, &stt);
    EXPECT_EQ(st.rays, n) << where;
    EXPECT_EQ(stt.rays, n) << where;
    if (check.expect_packets) {
      EXPECT_GT(st.packets, 0u) << where << ": no closest-hit packet traced";
      EXPECT_GT(stt.packets, 0u) << where << ": no transmittance packet traced";
    }
    // Chunks of 37 rays: groups of 16 at every offset, tails of 5 rays.
    for (size_t b = 0; b < n; b += 37) {
      const size_t len = std::min<size_t>(37, n - b);
      packet->intersect(std::span<const Ray>(rays).subspan(b, len), std::span<Hit>(hc).subspan(b, len));
      packet->transmittance(std::span<const Ray>(rays).subspan(b, len), std::span<Vec3>(tc).subspan(b, len));
    }
    size_t bad = 0, hits = 0;
    std::string first;
    const auto fail = [&](size_t i, const std::string& what) {
      if (bad++ == 0) first = "ray " + std::to_string(i) + " " + describe(rays[i]) + ": " + what;
    };
    for (size_t i = 0; i < n; ++i) {
      hits += hs[i].hit() || !(ts[i] == Vec3{1.0f, 1.0f, 1.0f});
      if (!same_bits(hp[i], hs[i]))
        fail(i, "packet " + hit_text(hp[i]) + ", single " + hit_text(hs[i]));
      else if (!same_bits(hc[i], hs[i]))
        fail(i, "packet (chunks of 37) " + hit_text(hc[i]) + ", single " + hit_text(hs[i]));
      else if (!same_bits(tp[i], ts[i]) || !same_bits(tc[i], ts[i]))
        fail(i, "transmittance: packet (" + std::to_string(tp[i].x) + ", " + std::to_string(tp[i].y) + ", " +
                    std::to_string(tp[i].z) + "), single (" + std::to_string(ts[i].x) + ", " + std::to_string(ts[i].y) +
                    ", " + std::to_string(ts[i].z) + ")");
      else if (check.brute_every > 0 && i % check.brute_every == 0 && (!same_bits(hs[i], hb[i]) || !same_bits(ts[i], tb[i])))
        fail(i, "single " + hit_text(hs[i]) + ", brute " + hit_text(hb[i]) + "; transmittance single (" +
                    std::to_string(ts[i].x) + ", ...), brute (" + std::to_string(tb[i].x) + ", ...)");
    }
    EXPECT_EQ(bad, 0u) << where << ": " << bad << " of " << n << " rays differ; first: " << first;
    if (check.expect_hits) {
      EXPECT_GT(hits, 0u) << where << ": nothing hit";
    }
    if (check.expect_packets) {
      EXPECT_GT(st.packet_rays, n / 2) << where << ": most rays should go in packets";
    }
  }
}

/// Opaque transmittance for every triangle of \p m except every \p clear_every-th triangle
/// pair, which lets a tinted fraction through.
std::vector<Vec3> mixed_transmittance(size_t triangles, size_t clear_every) {
  std::vector<Vec3> tr(triangles);
  for (size_t t = 0; t < triangles; ++t)
    if ((t / 2) % clear_every != 0) tr[t] = Vec3{0.9f - 0.001f * static_cast<float>(t % 97), 0.8f, 0.7f};
  return tr;
}

TEST(BvhPackets, CoherentCameraRaysMatchSingleRays) {
  const Mesh sphere = test::make_sphere(32, 64, 1.5f, {0.2f, -0.1f, 0.3f});
  const Mesh grid = test::make_grid(48, 0.25f, -6.0f, -6.0f, 0.5f);
  const Mesh soup = test::make_soup(4000, 41);
  for (const Mesh* m : {&sphere, &grid, &soup}) {
    const std::string name = m == &sphere ? "sphere" : m == &grid ? "grid" : "soup";
    for (const Vec3 from : {Vec3{0.3f, 0.4f, 1.0f}, Vec3{-1.0f, 0.7f, -0.2f}, Vec3{0.1f, -1.0f, 0.3f}}) {
      std::vector<Ray> rays = block_camera_rays(m->bounds(), from, 64, 48);
      const std::vector<Ray> wide = block_camera_rays(m->bounds(), from, 32, 24, 3.0f);  // wide angle: diverging
      rays.insert(rays.end(), wide.begin(), wide.end());
      expect_packets_match(m->input(), rays, name + " camera");
      // Shadow rays to a point light, opaque and with transparent triangles.
      const auto bvh = build_tracer(AccelKind::Bvh, m->input());
      const Vec3 light = m->bounds().center() + normalize(from + Vec3{0.5f, 1.0f, 0.0f}) * 6.0f;
      const std::vector<Ray> shadows = shadow_rays(*bvh, rays, light);
      PacketCheck check;
      check.expect_hits = m != &grid;  // a flat grid casts no shadow on itself
      expect_packets_match(m->input(), shadows, name + " shadow", check);
      const std::vector<Vec3> tr = mixed_transmittance(m->triangle_count(), 3);
      expect_packets_match(m->input(tr), shadows, name + " shadow, transparent", check);
    }
  }
}

TEST(BvhPackets, RaysStartingOnTrianglesAndVertices) {
  const Mesh sphere = test::make_sphere(24, 48, 1.0f);
  const auto bvh = build_tracer(AccelKind::Bvh, sphere.input());
  const std::vector<Ray> primary = block_camera_rays(sphere.bounds(), {0.2f, 0.3f, 1.0f}, 48, 32);
  // Origins exactly at the hit points (no offset): the own triangle at t = 0 or thereabouts.
  std::vector<Ray> rays = shadow_rays(*bvh, primary, {3.0f, 4.0f, 5.0f}, true);
  // Origins exactly on vertices, coherent directions (16 rays from neighbouring vertices).
  for (size_t v = 0; v + 16 <= sphere.positions.size(); v += 16)
    for (size_t k = 0; k < 16; ++k) rays.push_back(test::make_ray(sphere.positions[v + k], {0.31f, 0.52f, 0.79f}));
  expect_packets_match(sphere.input(), rays, "on surface");
  const std::vector<Vec3> tr = mixed_transmittance(sphere.triangle_count(), 2);
  expect_packets_match(sphere.input(tr), rays, "on surface, transparent");
}

TEST(BvhPackets, RaysThroughSharedEdgesAndVertices) {
  // A grid at integer coordinates and rays aimed exactly at its vertices and edge midpoints.
  // From eyes at height 8 or 16 over it the dominant direction component is a power of two, so
  // the watertight shear is exact and the edge functions come out exactly zero: the scalar test
  // decides those lanes in double (and the half-open rule for transparent triangles).
  const Mesh grid = test::make_grid(16, 1.0f, 0.0f, 0.0f, 0.0f);
  std::vector<Ray> rays;
  for (const Vec3 eye : {Vec3{8.0f, 8.0f, 8.0f}, Vec3{8.0f, 16.0f, 8.0f}, Vec3{3.0f, 16.0f, 12.0f},
                         Vec3{7.3f, 9.0f, 5.1f}, Vec3{-3.0f, 4.0f, -2.5f}})
    for (int bz = 0; bz < 16; bz += 4)
      for (int bx = 0; bx < 16; bx += 4)
        for (int z = bz; z < bz + 4; ++z)
          for (int x = bx; x < bx + 4; ++x) {
            rays.push_back(test::make_ray(eye, Vec3{static_cast<float>(x), 0.0f, static_cast<float>(z)} - eye));
            rays.push_back(test::make_ray(eye, Vec3{static_cast<float>(x) + 0.5f, 0.0f, static_cast<float>(z)} - eye));
          }
  expect_packets_match(grid.input(), rays, "grid edges");
  std::vector<Vec3> glass(grid.triangle_count(), Vec3{0.5f, 0.6f, 0.7f});
  expect_packets_match(grid.input(glass), rays, "grid edges, transparent (half-open edges)");
}

TEST(BvhPackets, FrustumCulledLeafTrianglesMatchSingleRays) {
  // Leaves of up to 16 triangles (a high traversal cost keeps the SAH from splitting them) that
  // a packet's frustum covers only in part: the leaf loops skip the triangles whose bounding box
  // lies outside the frustum (frustum_block()). Axis-aligned grids (flat boxes, rays exactly
  // through vertices and edges, which lie on those boxes' faces and corners), a grid far from
  // the origin, a soup with degenerate triangles; narrow packets (high resolution: the block
  // test rejects most triangles) and wide ones (it stops paying and switches itself off).
  const Mesh grid = test::make_grid(32, 1.0f, 0.0f, 0.0f, 0.0f);
  const Mesh far_grid = test::make_grid(40, 0.125f, 1000.0f, -2000.0f, 512.0f);
  const Mesh soup = test::make_soup(3000, 45);
  BvhOptions big_leaves;
  big_leaves.traversal_cost = 8.0f;
  big_leaves.max_leaf_size = 16;
  PacketCheck check;
  check.brute_every = 3;
  for (const Mesh* m : {&grid, &far_grid, &soup}) {
    const std::string name = m == &grid ? "grid" : m == &far_grid ? "far grid" : "soup";
    for (const Vec3 from : {Vec3{0.2f, 1.0f, 0.3f}, Vec3{-0.6f, 0.5f, 0.4f}}) {
      std::vector<Ray> rays = block_camera_rays(m->bounds(), from, 160, 120);  // narrow packets
      const std::vector<Ray> wide = block_camera_rays(m->bounds(), from, 24, 24, 4.0f);  // wide ones
      rays.insert(rays.end(), wide.begin(), wide.end());
      expect_packets_match(m->input(), rays, name + " camera, big leaves", check, big_leaves);
      const auto bvh = build_tracer(AccelKind::Bvh, m->input());
      const Vec3 light = m->bounds().center() + normalize(from + Vec3{0.3f, 1.0f, -0.2f}) * 50.0f;
      PacketCheck shadow_check = check;
      shadow_check.expect_hits = m == &soup;  // a flat grid casts no shadow on itself
      expect_packets_match(m->input(), shadow_rays(*bvh, rays, light), name + " shadow, big leaves", shadow_check,
                           big_leaves);
    }
  }
  // Rays exactly through the grid's vertices and edge midpoints (power-of-two heights: exact
  // shear, edge functions exactly zero), 4x4 of them per packet: each packet's frustum just
  // reaches the triangles around its 4x4 vertices, whose boxes it touches on faces and corners.
  std::vector<Ray> rays;
  for (const Vec3 eye : {Vec3{16.0f, 16.0f, 16.0f}, Vec3{8.0f, 32.0f, 24.0f}, Vec3{5.3f, 9.0f, 7.1f}})
    for (int bz = 0; bz < 32; bz += 4)
      for (int bx = 0; bx < 32; bx += 4)
        for (const float off : {0.0f, 0.5f})
          for (int z = bz; z < bz + 4; ++z)
            for (int x = bx; x < bx + 4; ++x)
              rays.push_back(test::make_ray(eye, Vec3{static_cast<float>(x) + off, 0.0f, static_cast<float>(z)} - eye));
  check.brute_every = 1;
  expect_packets_match(grid.input(), rays, "grid vertices and edges, big leaves", check, big_leaves);
  std::vector<Vec3> glass(grid.triangle_count(), Vec3{0.5f, 0.6f, 0.7f});
  expect_packets_match(grid.input(glass), rays, "grid vertices and edges, big leaves, transparent", check,
                       big_leaves);
}

TEST(BvhPackets, MixedActiveMasksZeroComponentsAndNaN) {
  const Mesh sphere = test::make_sphere(24, 48, 1.0f, {0.1f, 0.2f, -0.1f});
  const Mesh soup = test::make_soup(2000, 43);
  for (const Mesh* m : {&sphere, &soup}) {
    std::vector<Ray> rays = block_camera_rays(m->bounds(), {0.4f, 0.5f, 1.0f}, 64, 64);
    std::mt19937 rng(7);
    for (size_t g = 0; g * 16 < rays.size(); ++g) {
      // A different set of lanes in every packet leaves it: the packet keeps a mixed mask.
      const uint32_t pattern = static_cast<uint32_t>(rng());
      for (int l = 0; l < 16; ++l) {
        const size_t i = g * 16 + static_cast<size_t>(l);
        if (i >= rays.size() || !((pattern >> l) & 1) || (pattern >> 16) % 3 == 0) continue;
        Ray& r = rays[i];
        switch ((pattern >> (l + 4)) % 11) {
          case 0: r.org.x = kNaN; break;
          case 1: r.dir = {kNaN, kNaN, kNaN}; break;
          case 2: r.dir.x = 0.0f; break;
          case 3: r.dir.x = -0.0f; break;
          case 4: r.dir.y = -0.0f, r.dir.z = 0.0f; break;
          case 5: r.dir = -r.dir; break;  // another octant
          case 6: r.tmin = 2.0f, r.tmax = 1.0f; break;  // empty interval
          case 7: r.dir.y = 1e-39f; break;  // denormal component: infinite reciprocal
          case 8: r.tmax = 0.5f * static_cast<float>(l); break;  // short rays
          case 9: r.tmin = kNaN; break;
          default: r.dir = {r.dir.z, r.dir.x, r.dir.y}; break;  // another dominant axis
        }
      }
    }
    // Whole packets of zero and negative-zero components (one axis-aligned view).
    for (int k = 0; k < 64; ++k) {
      const float x = m->bounds().min.x + (m->bounds().max.x - m->bounds().min.x) * (static_cast<float>(k % 8) + 0.5f) / 8.0f;
      const float y = m->bounds().min.y + (m->bounds().max.y - m->bounds().min.y) * (static_cast<float>(k / 8) + 0.5f) / 8.0f;
      rays.push_back(test::make_ray({x, y, 5.0f}, {k % 2 ? 0.0f : -0.0f, k % 3 ? -0.0f : 0.0f, -1.0f}));
    }
    // A packet of NaN rays: all miss, nothing crashes.
    for (int k = 0; k < 16; ++k) rays.push_back(test::make_ray({kNaN, 0.0f, 0.0f}, {0.1f, 0.2f, -1.0f}));
    expect_packets_match(m->input(), rays, m == &sphere ? "sphere mixed" : "soup mixed");
    std::vector<Hit> hits(16);
    BvhOptions o;
    const auto bvh = build_tracer(AccelKind::Bvh, m->input(), o);
    bvh->intersect(std::span<const Ray>(rays).last(16), hits);
    for (const Hit& h : hits) EXPECT_FALSE(h.hit());
  }
}

TEST(BvhPackets, ManyTransparentLayersMultiplyAsSingleRays) {
  // 80 tinted layers: more than a packet lane keeps (64) before it hands the ray back.
  Mesh m;
  std::vector<Vec3> tr;
  std::mt19937 rng(11);
  std::uniform_real_distribution<float> u(0.0f, 1.0f);
  for (int l = 0; l < 80; ++l) {
    const float z = -static_cast<float>(l) * 0.05f;
    const uint32_t b = static_cast<uint32_t>(m.positions.size());
    m.positions.insert(m.positions.end(), {{-2, -2, z}, {2, -2, z}, {2, 2, z}, {-2, 2, z}});
    m.indices.insert(m.indices.end(), {b, b + 1, b + 2, b, b + 2, b + 3});
    const Vec3 t = (l == 70) ? Vec3{} : Vec3{0.9f + 0.1f * u(rng), 0.97f + 0.03f * u(rng), 1.0f};
    tr.insert(tr.end(), {t, t});
  }
  std::vector<Ray> rays;
  for (int g = 0; g < 64; ++g)
    for (int k = 0; k < 16; ++k) {
      const float x = -1.0f + 0.03f * static_cast<float>(g % 8) + 0.002f * static_cast<float>(k % 4);
      const float y = -1.0f + 0.03f * static_cast<float>(g / 8) + 0.002f * static_cast<float>(k / 4);
      // Lengths across the layer stack: some end before layer 64, some after, some behind the
      // opaque layer 70.
      rays.push_back(test::make_ray({x, y, 1.0f}, {0.01f, 0.02f, -1.0f}, 0.0f, 1.0f + 0.08f * static_cast<float>(g)));
    }
  // Brute force multiplies all layers at once, the kernels in batches of 64: compare with single rays.
  PacketCheck check;
  check.brute_every = 0;
  expect_packets_match(m.input(tr), rays, "80 layers", check);
}

class BvhPacketsMesh : public ::testing::TestWithParam<const char*> {};

TEST_P(BvhPacketsMesh, CameraAndShadowPacketsMatchSingleRays) {
  SPECULA_REQUIRE_MESH(path, GetParam());
  Scene scene = load_obj(path);
  ASSERT_GT(scene.triangle_count(), 0u);
  add_default_camera_and_light(scene);
  const TriangleInput input{scene.positions, scene.indices, {}};
  // The scene's own camera, 4x4 blocks: the rays `specula bench trace` traces as packets.
  const PinholeCamera cam(scene.cameras.front(), 160, 120);
  std::vector<Ray> rays;
  for (int by = 0; by < 120; by += 4)
    for (int bx = 0; bx < 160; bx += 4)
      for (int y = by; y < by + 4; ++y)
        for (int x = bx; x < bx + 4; ++x) rays.push_back(cam.generate(static_cast<float>(x) + 0.5f, static_cast<float>(y) + 0.5f));
  const std::vector<Ray> side = block_camera_rays(scene.bounds(), {-1.0f, 0.2f, 0.3f}, 96, 64);
  rays.insert(rays.end(), side.begin(), side.end());
  expect_packets_match(input, rays, std::string(GetParam()) + " camera", {true, 7});
  const auto bvh = build_tracer(AccelKind::Bvh, input);
  const Vec3 light = scene.lights.empty() || scene.lights.front().type == LightType::Directional
                         ? scene.bounds().center() + Vec3{0.0f, 3.0f, 2.0f} * length(scene.bounds().extent())
                         : scene.lights.front().position;
  expect_packets_match(input, shadow_rays(*bvh, rays, light), std::string(GetParam()) + " shadow", {true, 7});
}

INSTANTIATE_TEST_SUITE_P(BvhShared, BvhPacketsMesh, ::testing::ValuesIn(test::kSharedMeshes), test::mesh_param_name);

TEST(BvhPackets, RendersAreBitIdenticalWithAndWithoutPackets) {
  // The Whitted integrator hands primary rays over in 4x4 pixel blocks (and shadow rays in the
  // order of their hits), so packets trace most of them; the image must not change by a bit,
  // whatever the kernel, and must be the brute-force oracle's. An odd size and tile size give
  // partial blocks at the tile borders.
  for (const char* name : {"glassbox", "cornell", "pool"}) {
    const Scene s = make_builtin_scene(name);
    const std::vector<Vec3> tr = shadow_transmittance(s);
    const TriangleInput input{s.positions, s.indices, tr};
    RenderOptions ro;
    ro.width = 99;
    ro.height = 70;
    ro.threads = 2;
    for (const int tile : {16, 7}) {
      ro.tile_size = tile;
      // The reference: brute force, or for the larger pool single rays through the 4-wide BVH.
      BvhOptions single;
      single.kernel = BvhKernel::Sse4;
      single.packets = false;
      const bool small = s.triangle_count() < 5000;
      const Film brute = render_whitted(s, *build_tracer(small ? AccelKind::Brute : AccelKind::Bvh, input, single), ro);
      for (const BvhKernel kernel : test::test_kernels())
        for (const bool packets : {false, true}) {
          BvhOptions o;
          o.kernel = kernel;
          o.packets = packets;
          const Film f = render_whitted(s, *build_tracer(AccelKind::Bvh, input, o), ro);
          ASSERT_EQ(f.color.size(), brute.color.size());
          EXPECT_EQ(std::memcmp(f.color.data(), brute.color.data(), f.color.size() * sizeof(Vec3)), 0)
              << name << " tile " << tile << ": " << bvh_kernel_name(kernel) << (packets ? " with" : " without")
              << " packets differs from " << (small ? "brute force" : "sse4 single rays");
        }
    }
  }
}

TEST(BvhPackets, OptionIsReported) {
  const Mesh sphere = test::make_sphere(8, 16);
  BvhOptions o;
  EXPECT_TRUE(Bvh::build(sphere.input(), o).packets());
  o.packets = false;
  EXPECT_FALSE(Bvh::build(sphere.input(), o).packets());
  // Incoherent rays seldom form packets.
  const std::vector<Ray> rays = test::make_oracle_rays(sphere.bounds(), sphere.positions, 4096, 5);
  o.packets = true;
  const auto bvh = build_tracer(AccelKind::Bvh, sphere.input(), o);
  std::vector<Hit> hits(rays.size());
  TraceStats st;
  bvh->intersect(rays, hits, &st);
  EXPECT_LT(st.packet_rays, rays.size() / 10);
}

}  // namespace
}  // namespace specula
