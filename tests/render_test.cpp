// The Whitted integrator against closed-form answers, plus determinism, errors and AOVs.
//
// Shading convention under test (docs/rendering.md): a point light of intensity I at
// distance d gives irradiance E = I / d^2; a diffuse surface of albedo kd returns
// L = kd * E * cos(theta) (Phong convention, no 1/pi), plus ambient * kd.
#include <gtest/gtest.h>

#include <atomic>
#include <cmath>
#include <cstring>
#include <string>
#include <thread>
#include <vector>

#include "accel_test_util.h"
#include "render/fresnel.h"
#include "render/sky.h"
#include "specula/accel.h"
#include "specula/error.h"
#include "specula/load.h"
#include "specula/render.h"
#include "specula/voxel_scene.h"

using namespace specula;

namespace {

/// Adds an axis-aligned quad centred at c spanned by half vectors u, v (facing cross(u, v)).
void add_quad(Scene& s, const char* name, const Vec3& c, const Vec3& u, const Vec3& v, uint32_t mat) {
  const std::vector<Vec3> p{c - u - v, c + u - v, c + u + v, c - u + v};
  const std::vector<uint32_t> idx{0, 1, 2, 0, 2, 3};
  s.add_mesh(name, p, idx, mat);
}

/// Adds an axis-aligned box with outward winding and flat faces (six quads).
void add_box(Scene& s, const char* name, const Vec3& lo, const Vec3& hi, uint32_t mat) {
  const Vec3 c = (lo + hi) * 0.5f, h = (hi - lo) * 0.5f;
  const Vec3 hx{h.x, 0, 0}, hy{0, h.y, 0}, hz{0, 0, h.z};
  add_quad(s, name, c - hz, hy, hx, mat);  // -z
  add_quad(s, name, c + hz, hx, hy, mat);  // +z
  add_quad(s, name, c - hx, hz, hy, mat);  // -x
  add_quad(s, name, c + hx, hy, hz, mat);  // +x
  add_quad(s, name, c - hy, hx, hz, mat);  // -y
  add_quad(s, name, c + hy, hz, hx, mat);  // +y
}

Material diffuse(Vec3 kd) {
  Material m;
  m.diffuse = kd;
  m.specular = Vec3{0.0f};
  return m;
}

Scene base_scene() {
  Scene s;
  s.name = "test";
  s.ambient = Vec3{0.0f};
  s.sky.type = SkyType::Constant;
  s.sky.color = Vec3{0.0f};
  return s;
}

std::unique_ptr<Tracer> make_tracer(const Scene& s, AccelKind kind = AccelKind::Bvh, const BvhOptions& bvh = {}) {
  const std::vector<Vec3> tr = shadow_transmittance(s);
  return build_tracer(kind, TriangleInput{s.positions, s.indices, tr}, bvh);
}

Camera look(Vec3 from, Vec3 to, float vfov = 40.0f) {
  Camera c;
  c.name = "main";
  c.position = from;
  c.target = to;
  c.vfov_degrees = vfov;
  return c;
}

Light point_light(Vec3 pos, float intensity, Vec3 colour = Vec3{1.0f}) {
  Light l;
  l.type = LightType::Point;
  l.position = pos;
  l.intensity = intensity;
  l.color = colour;
  return l;
}

RenderOptions small(int w = 33, int h = 25) {
  RenderOptions o;
  o.width = w;
  o.height = h;
  o.threads = 2;
  return o;
}

void expect_vec_near(const Vec3& a, const Vec3& b, float tol, const std::string& what) {
  EXPECT_NEAR(a.x, b.x, tol) << what;
  EXPECT_NEAR(a.y, b.y, tol) << what;
  EXPECT_NEAR(a.z, b.z, tol) << what;
}

}  // namespace

TEST(Render, DiffusePlaneUnderPointLightMatchesClosedForm) {
  Scene s = base_scene();
  const Vec3 albedo{0.5f, 0.3f, 0.8f};
  add_quad(s, "plane", {0, 0, 0}, {0, 0, 50}, {50, 0, 0}, s.add_material(diffuse(albedo)));
  const Vec3 lpos{0.3f, 2.0f, -0.2f};
  const float intensity = 8.0f;
  s.lights.push_back(point_light(lpos, intensity));
  s.cameras.push_back(look({0, 1.5f, 3}, {0, 0, 0}));
  const auto tracer = make_tracer(s);
  const RenderOptions o = small();
  const Film f = render_whitted(s, *tracer, o);
  ASSERT_EQ(f.color.size(), static_cast<size_t>(o.width * o.height));
  const PinholeCamera cam(s.cameras[0], o.width, o.height);
  int checked = 0;
  for (int y = 0; y < o.height; ++y)
    for (int x = 0; x < o.width; ++x) {
      const Ray r = cam.generate(static_cast<float>(x) + 0.5f, static_cast<float>(y) + 0.5f);
      if (r.dir.y >= -1e-3f) continue;
      const float t = -r.org.y / r.dir.y;
      const Vec3 p = r.org + r.dir * t;
      const Vec3 to = lpos - p;
      const float d2 = dot(to, to);
      const float cos_t = to.y / std::sqrt(d2);
      const Vec3 expected = albedo * (intensity * cos_t / d2);
      const Vec3 got = f.color[static_cast<size_t>(y * o.width + x)];
      expect_vec_near(got, expected, 1e-3f * std::max(1.0f, max_component(expected)),
                      "pixel " + std::to_string(x) + "," + std::to_string(y));
      ++checked;
    }
  EXPECT_GT(checked, o.width * o.height / 2);
}

TEST(Render, AmbientAndEmissionAddUp) {
  Scene s = base_scene();
  s.ambient = {0.2f, 0.1f, 0.05f};
  Material m = diffuse({0.5f, 0.5f, 0.5f});
  m.emission = {0.01f, 0.02f, 0.03f};
  add_quad(s, "wall", {0, 0, 0}, {5, 0, 0}, {0, 5, 0}, s.add_material(m));
  s.cameras.push_back(look({0, 0, 3}, {0, 0, 0}));
  const auto tracer = make_tracer(s);
  const Film f = render_whitted(s, *tracer, small());
  expect_vec_near(f.color[f.color.size() / 2], {0.11f, 0.07f, 0.055f}, 1e-6f, "centre");
}

TEST(Render, DirectionalLightGivesCosineFalloffOnly) {
  Scene s = base_scene();
  add_quad(s, "plane", {0, 0, 0}, {0, 0, 50}, {50, 0, 0}, s.add_material(diffuse(Vec3{0.5f})));
  Light sun;
  sun.type = LightType::Directional;
  sun.direction = normalize(Vec3{0.0f, -1.0f, -1.0f});
  sun.intensity = 2.0f;
  s.lights.push_back(sun);
  s.cameras.push_back(look({0, 1.5f, 3}, {0, 0, 0}));
  const auto tracer = make_tracer(s);
  const Film f = render_whitted(s, *tracer, small());
  // Every plane pixel: 0.5 * 2 * cos(45 deg).
  const float expected = 0.5f * 2.0f * std::sqrt(0.5f);
  EXPECT_NEAR(f.color[f.color.size() / 2].x, expected, 1e-4f);
  EXPECT_NEAR(f.color.back().y, expected, 1e-4f);
}

namespace {

/// Floor lit from straight above through a pane at y = 1; the camera looks at the origin
/// from below the pane's height so only the shadow ray crosses it.
struct PaneSetup {
  Scene scene;
  uint32_t pane_material = 0;
  Vec3 albedo{0.6f, 0.6f, 0.6f};
  float intensity = 4.0f;
};

PaneSetup pane_scene(const Material& pane, int panes = 1) {
  PaneSetup p;
  p.scene = base_scene();
  p.scene.ambient = Vec3{0.05f};
  add_quad(p.scene, "floor", {0, 0, 0}, {0, 0, 20}, {20, 0, 0}, p.scene.add_material(diffuse(p.albedo)));
  p.pane_material = p.scene.add_material(pane);
  for (int i = 0; i < panes; ++i)
    // Off-centre so the shadow ray does not cross the quad's diagonal edge, where both of
    // its triangles may count as crossed.
    add_quad(p.scene, "pane", {0.13f, 1.0f + 0.2f * static_cast<float>(i), 0.07f}, {0, 0, 0.5f},
             {0.5f, 0, 0}, p.pane_material);
  p.scene.lights.push_back(point_light({0, 2, 0}, p.intensity));
  p.scene.cameras.push_back(look({0, 0.4f, 3}, {0, 0, 0}));
  return p;
}

Vec3 centre_pixel(const Scene& s) {
  const auto tracer = make_tracer(s);
  const RenderOptions o = small(21, 21);  // odd: the centre pixel's ray hits the origin
  return render_whitted(s, *tracer, o).color[static_cast<size_t>(10 * 21 + 10)];
}

}  // namespace

TEST(Render, ShadowThroughTransparentPaneIsAttenuatedByItsTransmittance) {
  Material glass;
  glass.diffuse = {1.0f, 0.5f, 0.25f};
  glass.transparency = 0.6f;
  glass.ior = 1.5f;
  PaneSetup p = pane_scene(glass);
  const std::vector<Vec3> tr = shadow_transmittance(p.scene);
  const Vec3 t = tr[p.scene.triangle_count() - 1];
  // Transmittance is tinted, partial and below the transparency.
  EXPECT_GT(min_component(t), 0.0f);
  EXPECT_LT(max_component(t), 0.6f + 1e-6f);
  EXPECT_GT(t.x, t.z);
  const Vec3 unshadowed = p.albedo * (p.intensity / 4.0f);  // d = 2, cos = 1
  const Vec3 expected = p.albedo * 0.05f + unshadowed * t;
  expect_vec_near(centre_pixel(p.scene), expected, 1e-4f, "through one pane");

  // Two panes multiply.
  PaneSetup two = pane_scene(glass, 2);
  expect_vec_near(centre_pixel(two.scene), p.albedo * 0.05f + unshadowed * t * t, 1e-4f, "two panes");
}

TEST(Render, OpaquePaneLeavesOnlyAmbient) {
  PaneSetup p = pane_scene(diffuse(Vec3{0.7f}));
  expect_vec_near(centre_pixel(p.scene), p.albedo * 0.05f, 1e-6f, "opaque pane");
  // And without any pane the full light arrives (the setup itself is right).
  PaneSetup none = pane_scene(diffuse(Vec3{0.7f}), 0);
  expect_vec_near(centre_pixel(none.scene), none.albedo * 0.05f + none.albedo * 1.0f, 1e-4f, "no pane");
}

namespace {

/// An emissive wall at z = -2 seen straight on through an absorbing slab z in [-0.5, 0.5].
Vec3 through_slab(const Material& slab, float thickness) {
  Scene s = base_scene();
  Material wall;
  wall.diffuse = Vec3{0.0f};
  wall.emission = {2.0f, 1.0f, 0.5f};
  add_quad(s, "wall", {0, 0, -2}, {10, 0, 0}, {0, 10, 0}, s.add_material(wall));
  add_box(s, "slab", {-3, -3, -0.5f * thickness}, {3, 3, 0.5f * thickness}, s.add_material(slab));
  s.cameras.push_back(look({0, 0, 3}, {0, 0, 0}));
  return centre_pixel(s);
}

}  // namespace

TEST(Render, BeerLambertThroughAbsorbingSlab) {
  Material m;
  m.diffuse = Vec3{0.0f};
  m.transparency = 1.0f;
  m.ior = 1.0f;  // no Fresnel, no bending: only absorption remains
  m.absorption = {0.5f, 1.0f, 2.0f};
  for (float d : {0.5f, 1.0f}) {
    const Vec3 expected = Vec3{2.0f, 1.0f, 0.5f} * exp(m.absorption * -d);
    expect_vec_near(through_slab(m, d), expected, 1e-5f, "thickness " + std::to_string(d));
  }
  // With glass's ior: two interfaces each pass (1 - F0) at normal incidence.
  m.ior = 1.5f;
  const float t = 1.0f - 0.04f;
  const Vec3 expected = Vec3{2.0f, 1.0f, 0.5f} * exp(m.absorption * -1.0f) * (t * t);
  expect_vec_near(through_slab(m, 1.0f), expected, 2e-3f * 2.0f, "ior 1.5");
}

TEST(Render, NestedMediaUseTheMediumStack) {
  // Slab A (z in [-1, 1]) contains slab B (z in [-0.25, 0.25]). Leaving B must return the
  // path to A's medium, not to air: the absorption is exp(-sA (2 - 0.5) - sB 0.5).
  Scene s = base_scene();
  Material wall;
  wall.diffuse = Vec3{0.0f};
  wall.emission = Vec3{1.0f};
  add_quad(s, "wall", {0, 0, -3}, {10, 0, 0}, {0, 10, 0}, s.add_material(wall));
  Material a;
  a.diffuse = Vec3{0.0f};
  a.transparency = 1.0f;
  a.absorption = {0.4f, 0.4f, 0.4f};
  Material b = a;
  b.absorption = {0.0f, 2.0f, 0.0f};
  add_box(s, "a", {-3, -3, -1}, {3, 3, 1}, s.add_material(a));
  add_box(s, "b", {-2, -2, -0.25f}, {2, 2, 0.25f}, s.add_material(b));
  s.cameras.push_back(look({0, 0, 4}, {0, 0, 0}));
  const Vec3 got = centre_pixel(s);
  const float ea = std::exp(-0.4f * 1.5f);
  expect_vec_near(got, {ea, ea * std::exp(-1.0f), ea}, 1e-5f, "nested");
}

TEST(Render, PerfectMirrorShowsTheSky) {
  Scene s = base_scene();
  s.sky.color = {0.3f, 0.6f, 0.9f};
  Material mirror;
  mirror.diffuse = Vec3{0.0f};
  mirror.reflectivity = 1.0f;
  add_quad(s, "mirror", {0, 0, 0}, {5, 0, 0}, {0, 5, 0}, s.add_material(mirror));
  s.cameras.push_back(look({0.2f, 0.1f, 3}, {0, 0, 0}));
  const auto tracer = make_tracer(s);
  const Film f = render_whitted(s, *tracer, small());
  expect_vec_near(f.color[f.color.size() / 2], s.sky.color, 1e-6f, "mirror");
  // With no reflection depth the mirror is black.
  RenderOptions o = small();
  o.max_reflect = 0;
  expect_vec_near(render_whitted(s, *tracer, o).color[f.color.size() / 2], Vec3{0.0f}, 1e-6f, "depth 0");
}

TEST(Render, IndexMatchedGlassIsInvisible) {
  Scene s = base_scene();
  Material wall = diffuse(Vec3{0.0f});
  wall.emission = {0.25f, 0.5f, 0.75f};
  add_quad(s, "wall", {0, 0, -3}, {10, 0, 0}, {0, 10, 0}, s.add_material(wall));
  Material clear;
  clear.diffuse = Vec3{0.0f};
  clear.transparency = 1.0f;
  clear.ior = 1.0f;
  add_box(s, "box", {-0.5f, -0.5f, -0.5f}, {0.5f, 0.5f, 0.5f}, s.add_material(clear));
  s.cameras.push_back(look({0.7f, 0.6f, 3}, {0, 0, 0}));
  const auto tracer = make_tracer(s);
  const Film f = render_whitted(s, *tracer, small());
  for (const Vec3& c : f.color) expect_vec_near(c, wall.emission, 1e-5f, "behind clear box");
}

TEST(Render, SmallSphereLightMatchesPointLight) {
  Scene s = base_scene();
  add_quad(s, "plane", {0, 0, 0}, {0, 0, 50}, {50, 0, 0}, s.add_material(diffuse(Vec3{0.5f})));
  s.lights.push_back(point_light({0, 2, 0}, 4.0f));
  s.cameras.push_back(look({0, 1.5f, 3}, {0, 0, 0}));
  const Vec3 point = centre_pixel(s);
  s.lights[0].type = LightType::Sphere;
  s.lights[0].radius = 0.02f;
  s.lights[0].samples = 16;
  const Vec3 sphere = centre_pixel(s);
  expect_vec_near(sphere, point, 2e-3f * point.x, "sphere vs point");
}

TEST(Render, SphereLightCastsSoftShadowEdges) {
  // A large sphere light partly hidden by an occluder's edge gives a value strictly
  // between umbra and full light.
  Scene s = base_scene();
  add_quad(s, "floor", {0, 0, 0}, {0, 0, 20}, {20, 0, 0}, s.add_material(diffuse(Vec3{0.5f})));
  add_quad(s, "blocker", {-1.0f, 1.0f, 0}, {0, 0, 2}, {1.0f, 0, 0}, s.add_material(diffuse(Vec3{0.5f})));
  Light l = point_light({0, 2, 0}, 4.0f);
  l.type = LightType::Sphere;
  l.radius = 0.3f;
  l.samples = 64;
  s.lights.push_back(l);
  s.cameras.push_back(look({0, 0.4f, 3}, {0, 0, 0}));
  const Vec3 c = centre_pixel(s);
  EXPECT_GT(c.x, 0.5f * 0.25f * 4.0f * 0.2f);
  EXPECT_LT(c.x, 0.5f * 0.25f * 4.0f * 0.8f);
}

namespace {

Film render_scene(const Scene& s, const Tracer& tracer, int threads, int tile = 16) {
  RenderOptions o;
  o.width = 96;
  o.height = 72;
  o.threads = threads;
  o.tile_size = tile;
  return render_whitted(s, tracer, o);
}

}  // namespace

TEST(Render, BitIdenticalForAnyThreadCountAndTileSize) {
  for (const char* name : {"glassbox", "cornell"}) {
    const Scene s = make_builtin_scene(name);
    const auto tracer = make_tracer(s);  // one structure: this tests the integrator
    const Film a = render_scene(s, *tracer, 1);
    const Film b = render_scene(s, *tracer, 2);
    const Film c = render_scene(s, *tracer, 2, 7);
    ASSERT_EQ(a.color.size(), b.color.size());
    EXPECT_EQ(std::memcmp(a.color.data(), b.color.data(), a.color.size() * sizeof(Vec3)), 0)
        << name << ": threads 1 vs 2";
    EXPECT_EQ(std::memcmp(a.color.data(), c.color.data(), a.color.size() * sizeof(Vec3)), 0)
        << name << ": tile 16 vs 7";
    double sum = 0;
    for (const Vec3& v : a.color) sum += v.x + v.y + v.z;
    EXPECT_GT(sum, 0.0) << name << " rendered black";
  }
}

TEST(Render, BitIdenticalWhicheverBvhKernelTraced) {
  const std::vector<BvhKernel> kernels = test::test_kernels();
  if (kernels.size() < 2) GTEST_SKIP() << "this CPU runs only the sse4 BVH kernel";
  for (const char* name : {"glassbox", "cornell", "pool"}) {
    const Scene s = make_builtin_scene(name);
    BvhOptions four;
    four.kernel = BvhKernel::Sse4;
    const Film a = render_scene(s, *make_tracer(s, AccelKind::Bvh, four), 2);
    for (size_t k = 1; k < kernels.size(); ++k) {
      BvhOptions other;
      other.kernel = kernels[k];
      const Film b = render_scene(s, *make_tracer(s, AccelKind::Bvh, other), 2);
      ASSERT_EQ(a.color.size(), b.color.size());
      EXPECT_EQ(std::memcmp(a.color.data(), b.color.data(), a.color.size() * sizeof(Vec3)), 0)
          << name << ": sse4 vs " << bvh_kernel_name(kernels[k]) << " kernel";
    }
  }
}

TEST(Render, GroupingCoherentRaysLeavesTheImageBitIdentical) {
  // The pool's wavefronts mix mirror and refraction rays and its shadow batches two lights; the
  // BVH traces them in packets when grouped. Grouped, wavefronts are built in history order
  // (each pixel's own segments keep their order) when a path cannot bounce 15 times, else traced
  // through TraceOrder (the 8 + 8 bounce limits below); either way the films match the ones
  // built in emission order. The third scene has more lights than TraceOrder has groups (the
  // last group takes the rest).
  for (const int limit : {0, 8})
  for (const char* name : {"pool", "glassbox", "glassbox+40 lights"}) {
    SCOPED_TRACE(limit == 0 ? "default bounce limits" : "8 mirror + 8 refraction bounces");
    Scene s = make_builtin_scene(std::string(name).substr(0, std::string(name).find('+')));
    if (std::string(name).find('+') != std::string::npos)
      for (int i = 0; i < 40; ++i)
        s.lights.push_back(point_light({-1.0f + 0.05f * static_cast<float>(i), 1.5f, 0.5f}, 0.05f));
    const auto tracer = make_tracer(s);
    RenderOptions o;
    o.width = 96;
    o.height = 72;
    o.threads = 2;
    if (limit > 0) o.max_reflect = o.max_refract = limit;
    const Film grouped = render_whitted(s, *tracer, o);
    o.group_coherent_rays = false;
    RenderStats st;
    const Film plain = render_whitted(s, *tracer, o, &st);
    EXPECT_GT(st.secondary_rays, 0u) << name;
    EXPECT_GT(st.shadow_rays, 0u) << name;
    ASSERT_EQ(grouped.color.size(), plain.color.size());
    EXPECT_EQ(std::memcmp(grouped.color.data(), plain.color.data(), plain.color.size() * sizeof(Vec3)), 0) << name;
  }
}

TEST(Render, UnknownCameraListsTheAvailableOnes) {
  Scene s = make_builtin_scene("glassbox");
  const auto tracer = make_tracer(s);
  RenderOptions o = small();
  o.camera = "nope";
  try {
    render_whitted(s, *tracer, o);
    FAIL() << "expected specula::Error";
  } catch (const Error& e) {
    const std::string msg = e.what();
    EXPECT_NE(msg.find("nope"), std::string::npos) << msg;
    EXPECT_NE(msg.find("front"), std::string::npos) << msg;
    EXPECT_NE(msg.find("inside"), std::string::npos) << msg;
  }
  o.camera = "inside";
  EXPECT_NO_THROW(render_whitted(s, *tracer, o));
}

TEST(Render, RejectsAbsurdImageSizes) {
  Scene s = make_builtin_scene("glassbox");
  const auto tracer = make_tracer(s);
  for (auto [w, h] : {std::pair{0, 10}, {10, 0}, {-5, 10}, {32769, 10}, {10, 40000}, {30000, 30000}}) {
    RenderOptions o = small();
    o.width = w;
    o.height = h;
    EXPECT_THROW(render_whitted(s, *tracer, o), Error) << w << "x" << h;
    EXPECT_THROW(check_image_size(w, h), Error) << w << "x" << h;  // the same refusal, up front
  }
  // The film limit (2 GiB) counts the AOV planes: 16384x8192 is 1.5 GiB of colour alone.
  EXPECT_NO_THROW(check_image_size(32768, 1));
  EXPECT_NO_THROW(check_image_size(16384, 8192));
  EXPECT_NO_THROW(check_image_size(16384, 8192, std::vector<Aov>{Aov::Depth}));  // + 0.5 GiB: exactly 2 GiB
  EXPECT_THROW(check_image_size(16384, 8192, std::vector<Aov>{Aov::Depth, Aov::Cost}), Error);
  EXPECT_THROW(check_image_size(16384, 8192, std::vector<Aov>{Aov::Normal}), Error);
}

namespace {

/// A lit plane seen from above, small enough that the top rows look past its far edge (misses).
Scene lit_plane() {
  Scene s = base_scene();
  add_quad(s, "plane", {0, 0, 0}, {0, 0, 5}, {5, 0, 0}, s.add_material(diffuse(Vec3{0.5f})));
  s.lights.push_back(point_light({0, 2, 0}, 4.0f));
  s.cameras.push_back(look({0, 1.5f, 3}, {0, 0, 0}));
  return s;
}

}  // namespace

TEST(Render, StatsProgressAndAovs) {
  const Scene s = lit_plane();
  const auto tracer = make_tracer(s);
  RenderOptions o = small(41, 31);
  o.tile_size = 8;
  o.aovs = parse_aovs("depth, normal,prim,cost");
  std::vector<double> progress;
  std::atomic<bool> other_thread{false};  // the callback must only run on the thread that called render
  const std::thread::id caller = std::this_thread::get_id();
  o.progress = [&](double f) {
    if (std::this_thread::get_id() != caller) other_thread = true;
    else progress.push_back(f);
  };
  RenderStats st;
  const Film f = render_whitted(s, *tracer, o, &st);
  EXPECT_EQ(st.primary_rays, 41u * 31u);
  EXPECT_GT(st.shadow_rays, 0u);
  EXPECT_EQ(st.secondary_rays, 0u);
  EXPECT_GE(st.render_ms, 0.0);
  ASSERT_FALSE(progress.empty());
  EXPECT_DOUBLE_EQ(progress.back(), 1.0);
  for (size_t i = 1; i < progress.size(); ++i) EXPECT_GE(progress[i], progress[i - 1]);
  EXPECT_FALSE(other_thread);

  ASSERT_EQ(f.depth.size(), f.color.size());
  ASSERT_EQ(f.normal.size(), f.color.size());
  ASSERT_EQ(f.prim_id.size(), f.color.size());
  ASSERT_EQ(f.cost.size(), f.color.size());
  const size_t centre = static_cast<size_t>(15 * 41 + 20);
  EXPECT_NEAR(f.depth[centre], std::sqrt(1.5f * 1.5f + 9.0f), 1e-4f);
  expect_vec_near(f.normal[centre], {0, 1, 0}, 1e-5f, "normal");
  EXPECT_LT(f.prim_id[centre], 2u);
  EXPECT_GT(f.cost[centre], 0u);
  // The top rows look above the horizon: misses.
  EXPECT_TRUE(std::isinf(f.depth[0]));
  EXPECT_EQ(f.prim_id[0], kNoHit);
  EXPECT_EQ(f.normal[0], Vec3{});
  // Without AOVs the planes stay empty.
  const Film plain = render_whitted(s, *tracer, small(41, 31));
  EXPECT_TRUE(plain.depth.empty());
  EXPECT_TRUE(plain.cost.empty());
  // The cost pass must not change the image.
  EXPECT_EQ(std::memcmp(plain.color.data(), f.color.data(), f.color.size() * sizeof(Vec3)), 0);
}

TEST(Render, RenderingIntoAReusedFilmGivesTheFreshImage) {
  const Scene s = lit_plane();
  const auto tracer = make_tracer(s);
  RenderOptions o = small(41, 31);
  o.aovs = parse_aovs("depth,normal,prim,cost");
  const Film fresh = render_whitted(s, *tracer, o);
  // A film holding another image of the same size (NaN colours, stale planes) and one of
  // another size: both must end up exactly as the fresh render.
  Film same;
  same.width = 41;
  same.height = 31;
  same.color.assign(41 * 31, Vec3{std::nanf("")});
  same.depth.assign(41 * 31, -1.0f);
  same.normal.assign(41 * 31, Vec3{7.0f});
  same.prim_id.assign(41 * 31, 12345u);
  same.cost.assign(41 * 31, 99u);
  Film other = render_whitted(s, *tracer, small(13, 9));
  for (Film* f : {&same, &other}) {
    render_whitted(s, *tracer, o, *f);
    EXPECT_EQ(f->width, 41);
    EXPECT_EQ(f->height, 31);
    ASSERT_EQ(f->color.size(), fresh.color.size());
    EXPECT_EQ(std::memcmp(f->color.data(), fresh.color.data(), fresh.color.size() * sizeof(Vec3)), 0);
    EXPECT_EQ(f->depth, fresh.depth);
    EXPECT_EQ(f->normal, fresh.normal);
    EXPECT_EQ(f->prim_id, fresh.prim_id);
    EXPECT_EQ(f->cost, fresh.cost);
  }
  // AOVs no longer requested leave no stale planes behind.
  render_whitted(s, *tracer, small(41, 31), same);
  EXPECT_TRUE(same.depth.empty() && same.normal.empty() && same.prim_id.empty() && same.cost.empty());
  EXPECT_EQ(std::memcmp(same.color.data(), fresh.color.data(), fresh.color.size() * sizeof(Vec3)), 0);
}

TEST(Render, ParseAovs) {
  EXPECT_EQ(parse_aovs("").size(), 0u);
  const auto a = parse_aovs("depth,prim_id,primid,Cost");
  ASSERT_EQ(a.size(), 3u);
  EXPECT_EQ(a[0], Aov::Depth);
  EXPECT_EQ(a[1], Aov::PrimId);
  EXPECT_EQ(a[2], Aov::Cost);
  EXPECT_THROW(parse_aovs("depth,albedo"), Error);
  EXPECT_STREQ(aov_name(Aov::Normal), "normal");
}

TEST(Render, SkyGradientAndCameraOrientation) {
  Scene s = base_scene();
  s.sky.type = SkyType::Gradient;
  s.sky.color = {0.0f, 0.0f, 1.0f};
  s.sky.horizon = {1.0f, 0.0f, 0.0f};
  s.cameras.push_back(look({0, 0, 0}, {0, 0, -1}, 90.0f));
  const auto tracer = make_tracer(s);  // empty scene
  const Film f = render_whitted(s, *tracer, small(21, 21));
  // Top row looks up (bluer), bottom row down (horizon colour), centre at the horizon.
  EXPECT_GT(f.color[10].z, 0.5f);
  expect_vec_near(f.color[20 * 21 + 10], {1, 0, 0}, 1e-6f, "below horizon");
  expect_vec_near(f.color[10 * 21 + 10], {1, 0, 0}, 1e-6f, "horizon");
}

TEST(Render, OffsetRayOriginMatchesItsScalarFormulaBitForBit) {
  // offset_ray_origin runs three lanes at a time (SSE2); it must give exactly what the
  // per-component formula of Waechter and Binder gives, including near the origin, for
  // negative and signed-zero coordinates, huge magnitudes and non-finite input.
  const auto reference = [](const Vec3& p, const Vec3& n) {
    Vec3 out;
    for (int i = 0; i < 3; ++i) {
      const int32_t of = static_cast<int32_t>(256.0f * n[i]);
      uint32_t bits;
      float pi = p[i];
      std::memcpy(&bits, &pi, sizeof bits);
      bits += static_cast<uint32_t>((p[i] < 0.0f) ? -of : of);
      std::memcpy(&pi, &bits, sizeof pi);
      out[i] = std::fabs(p[i]) < 1.0f / 32.0f ? p[i] + (1.0f / 65536.0f) * n[i] : pi;
    }
    return out;
  };
  const auto bits = [](const Vec3& v) {
    uint32_t b[3];
    std::memcpy(b, &v.x, 4);
    std::memcpy(b + 1, &v.y, 4);
    std::memcpy(b + 2, &v.z, 4);
    return std::vector<uint32_t>(b, b + 3);
  };
  const std::vector<float> special{0.0f, -0.0f, 1e-30f, -1e-30f, 0.03124f, -0.03126f, 0.03125f, -0.03125f,
                                   1.0f, -1.0f, 5e4f, -5e4f, 3e38f, -3e38f, kInf, -kInf, std::nanf("")};
  uint32_t state = 12345u;
  const auto next = [&state] {
    state = state * 1664525u + 1013904223u;
    return static_cast<float>(state >> 8) * (1.0f / 16777216.0f);
  };
  int checked = 0;
  for (int k = 0; k < 20000; ++k) {
    Vec3 p{(next() - 0.5f) * 200.0f, (next() - 0.5f) * 0.1f, (next() - 0.5f) * 1e5f};
    if (k < static_cast<int>(special.size() * special.size())) {
      p.x = special[static_cast<size_t>(k) % special.size()];
      p.y = special[static_cast<size_t>(k) / special.size()];
    }
    const Vec3 n = normalize(Vec3{next() - 0.5f, next() - 0.5f, next() - 0.5f});
    for (const Vec3& nn : {n, -n, Vec3{0, 0, 0}, Vec3{1, 0, 0}, Vec3{0, -1, 0}}) {
      ASSERT_EQ(bits(offset_ray_origin(p, nn)), bits(reference(p, nn))) << p.x << " " << p.y << " " << p.z;
      ++checked;
    }
  }
  EXPECT_EQ(checked, 100000);
}

TEST(Render, RaysLeavingASurfaceDoNotHitItAgain) {
  // Far from the origin a fixed epsilon fails; the scaled offset must not. A mirror at
  // large coordinates facing a constant sky: every pixel must be the sky colour.
  for (float offset : {0.0f, 1000.0f, 50000.0f}) {
    Scene s = base_scene();
    s.sky.color = {0.2f, 0.4f, 0.6f};
    Material mirror;
    mirror.diffuse = Vec3{0.0f};
    mirror.reflectivity = 1.0f;
    const Vec3 c{offset, offset * 0.5f, -offset};
    add_quad(s, "mirror", c, {3, 0, 0}, {0, 1, 2}, s.add_material(mirror));
    s.cameras.push_back(look(c + Vec3{0.3f, 2.0f, 2.5f}, c));
    const auto tracer = make_tracer(s);
    const Film f = render_whitted(s, *tracer, small());
    for (const Vec3& px : f.color) expect_vec_near(px, s.sky.color, 1e-6f, "offset " + std::to_string(offset));
  }
}

TEST(Render, EveryLightSampleOfAHitGetsItsShadowRay) {
  // Every pixel sees one unoccluded diffuse plane lit by a directional light, a point light, a
  // 16-sample sphere light and a zero-radius sphere light: each hit shoots 1 + 1 + 16 + 1 shadow
  // rays (the most the integrator sizes its shadow batch for), all of them transmit exactly 1,
  // so the film equals the one rendered without shadow rays bit for bit (same additions in the
  // same order per pixel).
  Scene s = base_scene();
  add_quad(s, "plane", {0, 0, 0}, {0, 0, 50}, {50, 0, 0}, s.add_material(diffuse(Vec3{0.5f})));
  Light sun;
  sun.type = LightType::Directional;
  sun.direction = normalize(Vec3{0.2f, -1.0f, 0.1f});
  sun.intensity = 0.5f;
  s.lights.push_back(sun);
  s.lights.push_back(point_light({0.5f, 2, 0}, 2.0f));
  Light sphere = point_light({-0.5f, 3, 0.2f}, 3.0f);
  sphere.type = LightType::Sphere;
  sphere.radius = 0.1f;
  sphere.samples = 16;
  s.lights.push_back(sphere);
  sphere.radius = 0.0f;
  sphere.position = {0, 2.5f, -0.3f};
  s.lights.push_back(sphere);
  s.cameras.push_back(look({0, 3, 0.5f}, {0, 0, 0}));
  const auto tracer = make_tracer(s);
  for (const int tile : {16, 5}) {
    RenderOptions o = small();
    o.tile_size = tile;
    RenderStats with, without;
    const Film a = render_whitted(s, *tracer, o, &with);
    o.shadows = false;
    const Film b = render_whitted(s, *tracer, o, &without);
    const uint64_t pixels = static_cast<uint64_t>(o.width) * static_cast<uint64_t>(o.height);
    EXPECT_EQ(with.primary_rays, pixels);
    EXPECT_EQ(with.shadow_rays, pixels * 19) << "tile " << tile;
    EXPECT_EQ(without.shadow_rays, 0u);
    ASSERT_EQ(a.color.size(), b.color.size());
    EXPECT_EQ(std::memcmp(a.color.data(), b.color.data(), a.color.size() * sizeof(Vec3)), 0) << "tile " << tile;
    EXPECT_GT(a.color[a.color.size() / 2].x, 0.0f);
  }
}

TEST(Render, VoxelMaterialsReusedAcrossHitsLeaveTheImageBitIdentical) {
  // The integrator keeps the shading material of the last voxel it shaded and reuses it while
  // hits stay on that voxel (it is reset per tile). One-pixel tiles share nothing across pixels;
  // 16 and 7 pixel tiles reuse it along runs of hits. Coarse depths (big voxels, many pixels on
  // one) and a finer one, cubes and contours, with and without shadow rays.
  LoadOptions lo;
  lo.warn = [](const std::string&) {};
  const Scene scene = make_builtin_scene("glassbox", lo);
  for (const int depth : {3, 5})
    for (const auto mode : {VoxelHitMode::Cubes, VoxelHitMode::Contours}) {
      SceneVoxelOptions vo;
      vo.depth = depth;
      vo.tracer.mode = mode;
      const auto svo = voxelize_scene(scene, vo);
      for (const bool shadows : {true, false}) {
        SCOPED_TRACE("depth " + std::to_string(depth) + (mode == VoxelHitMode::Cubes ? " cubes" : " contours") +
                     (shadows ? "" : " no shadows"));
        RenderOptions o;
        o.width = 40;
        o.height = 30;
        o.threads = 2;
        o.shadows = shadows;
        o.tile_size = 1;
        const Film a = render_whitted(scene, *svo, o);
        for (const int tile : {16, 7}) {
          o.tile_size = tile;
          const Film b = render_whitted(scene, *svo, o);
          ASSERT_EQ(a.color.size(), b.color.size());
          EXPECT_EQ(std::memcmp(a.color.data(), b.color.data(), a.color.size() * sizeof(Vec3)), 0) << "tile " << tile;
        }
      }
    }
}

TEST(Render, SkyAndFresnelFastPathsMatchTheirFormulasBitForBit) {
  // The constant and gradient skies are answered inline (SkyEval::radiance), images out of line;
  // fresnel_dielectric and refract are inline bodies (render/fresnel.h) behind the public calls.
  Sky sky;
  sky.color = {0.3f, 0.5f, 0.9f};
  sky.horizon = {0.8f, 0.85f, 0.95f};
  sky.intensity = 1.7f;
  const std::vector<Vec3> dirs{{0, 1, 0}, {0.3f, 0.2f, -0.9f}, {1, -0.5f, 0}, {0, 0, 0}, {-2, 7, 0.5f}, {0.1f, 0, 1}};
  for (const SkyType type : {SkyType::Constant, SkyType::Gradient, SkyType::Image}) {
    sky.type = type;
    const SkyEval eval(sky);
    for (const Vec3& d : dirs) {
      Vec3 want = sky.color * sky.intensity;  // constant; also an image sky without an image
      if (type == SkyType::Gradient)
        want = lerp(sky.horizon, sky.color, std::sqrt(std::clamp(normalize(d).y, 0.0f, 1.0f))) * sky.intensity;
      const Vec3 got = eval.radiance(d);
      EXPECT_EQ(std::memcmp(&got, &want, sizeof(Vec3)), 0) << static_cast<int>(type) << " " << d.x << " " << d.y;
    }
  }
  for (float c = 0.0f; c <= 1.0f; c += 0.0625f)
    for (const float eta : {1.0f, 1.0f / 1.33f, 1.33f, 1.5f, 1.0f / 1.5f}) {
      const float a = fresnel_dielectric(c, eta), b = detail::fresnel_dielectric(c, eta);
      EXPECT_EQ(std::memcmp(&a, &b, sizeof a), 0);
      const Vec3 d = normalize(Vec3{std::sqrt(std::max(0.0f, 1.0f - c * c)), -c, 0.1f});
      Vec3 r1, r2;
      const bool k1 = refract(d, {0, 1, 0}, eta, r1), k2 = detail::refract(d, {0, 1, 0}, eta, r2);
      EXPECT_EQ(k1, k2);
      if (k1 && k2) {
        EXPECT_EQ(std::memcmp(&r1, &r2, sizeof(Vec3)), 0);
      }
    }
  // Total internal reflection and a known value (normal incidence, glass: 4%).
  EXPECT_EQ(detail::fresnel_dielectric(0.1f, 1.5f), 1.0f);
  EXPECT_NEAR(detail::fresnel_dielectric(1.0f, 1.0f / 1.5f), 0.04f, 1e-6f);
}
