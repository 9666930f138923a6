// Built-in scene "city": a procedural town in the spirit of seed 002's test drives (owner: render).
//
// Streets on a grid, blocks of buildings with real window geometry (recessed or framed windows,
// curtain-wall towers), glass shop windows with lit interiors at street level, a canal with a
// stone bridge, an elevated road (the underpass), a plaza with a fountain, trees and street
// lamps, a wet mirror-like road. Units are metres, y up; streets are at y = 0.
//
// Size: `city` is about kCityDefaultTriangles triangles, `city:N` about N. The grid size comes
// from N, then a height/detail factor is searched with a counting pass over the same generator
// (CountSink) until the count is close to N; the final pass writes straight into the Scene.
// Everything is integer-seeded (splitmix64) and uses only +, -, *, / and sqrt on floats, so the
// scene is bit-identical on every machine and standard library. One MeshRange per zone: a city
// block with its buildings and sidewalk props ("zone_II_JJ"), each street, each canal segment,
// the bridge, the underpass (elevated road), the plaza and the surrounding ground.
#include <algorithm>
#include <array>
#include <bit>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <optional>
#include <string>
#include <vector>

#include "scene/builtin_geometry.h"
#include "scene/builtin_scenes.h"
#include "specula/error.h"

namespace specula::builtin {

namespace {

// ---------------------------------------------------------------------------------------------
// Deterministic random numbers (splitmix64; floats from the top 24 bits).

constexpr uint64_t kCitySeed = 0x5eed002c17ull;

constexpr uint64_t splitmix(uint64_t x) {
  x += 0x9e3779b97f4a7c15ull;
  x = (x ^ (x >> 30)) * 0xbf58476d1ce4e5b9ull;
  x = (x ^ (x >> 27)) * 0x94d049bb133111ebull;
  return x ^ (x >> 31);
}

struct Rng {
  uint64_t state;
  explicit Rng(uint64_t seed) : state(splitmix(seed)) {}
  uint64_t next() {
    state += 0x9e3779b97f4a7c15ull;
    uint64_t z = state;
    z = (z ^ (z >> 30)) * 0xbf58476d1ce4e5b9ull;
    z = (z ^ (z >> 27)) * 0x94d049bb133111ebull;
    return z ^ (z >> 31);
  }
  /// Uniform in [0, 1).
  float uniform() { return static_cast<float>(next() >> 40) * (1.0f / 16777216.0f); }
  float range(float lo, float hi) { return lo + (hi - lo) * uniform(); }
  /// Uniform integer in [lo, hi].
  int irange(int lo, int hi) { return lo + static_cast<int>(next() % static_cast<uint64_t>(hi - lo + 1)); }
  bool chance(float p) { return uniform() < p; }
};

uint64_t seed_of(uint64_t kind, int a, int b) {
  return splitmix(kCitySeed ^ splitmix((kind << 40) ^ (static_cast<uint64_t>(a) << 20) ^ static_cast<uint64_t>(b)));
}

// ---------------------------------------------------------------------------------------------
// Materials (ids in the order they are added).

enum Mat : uint32_t {
  kWetRoad, kMarking, kPavement, kConcrete, kGrass, kGround,
  kWall0, kWall1, kWall2, kWall3, kWall4, kWall5, kWall6,
  kWindowGlass, kFrameLight, kFrameDark, kSill,
  kShopGlass, kShopWall, kShopCeiling, kShopFloor, kGoods0, kGoods1, kGoods2, kDoor,
  kSign0, kSign1, kSign2, kSign3,
  kRoof, kCanalWater, kMud, kBridgeStone, kRailing,
  kTrunk, kFoliage0, kFoliage1, kLampPost, kLampLight, kChrome, kPanel,
  kMatCount
};
constexpr uint32_t kWallCount = 7, kSignCount = 4;

void add_materials(Scene& s) {
  auto add = [&s](const char* name, Vec3 kd, float spec = 0.05f, float exponent = 16.0f, float refl = 0.0f) {
    Material m;
    m.name = name;
    m.diffuse = kd;
    m.specular = Vec3{spec};
    m.phong_exponent = exponent;
    m.reflectivity = refl;
    return s.add_material(m);
  };
  // Wet asphalt: almost black diffuse, strong mirror reflection (seed 002, figure 4.3 c).
  add("wet_road", {0.03f, 0.03f, 0.035f}, 0.6f, 300.0f, 0.55f);
  add("road_marking", {0.9f, 0.88f, 0.8f}, 0.3f, 120.0f, 0.12f);
  add("pavement", {0.40f, 0.39f, 0.37f}, 0.25f, 80.0f, 0.12f);
  add("concrete", {0.52f, 0.51f, 0.48f});
  add("grass", {0.16f, 0.33f, 0.10f});
  add("ground", {0.22f, 0.26f, 0.16f});
  add("wall_brick", {0.56f, 0.26f, 0.18f});
  add("wall_ochre", {0.74f, 0.56f, 0.30f});
  add("wall_cream", {0.84f, 0.79f, 0.66f});
  add("wall_bluegrey", {0.42f, 0.48f, 0.56f});
  add("wall_white", {0.86f, 0.85f, 0.82f});
  add("wall_brown", {0.38f, 0.27f, 0.21f});
  add("wall_sage", {0.52f, 0.60f, 0.49f});
  add("window_glass", {0.04f, 0.06f, 0.09f}, 0.9f, 600.0f, 0.55f);
  add("frame_light", {0.88f, 0.88f, 0.85f}, 0.1f, 40.0f);
  add("frame_dark", {0.12f, 0.12f, 0.13f}, 0.2f, 60.0f);
  add("sill_stone", {0.70f, 0.68f, 0.62f});
  Material glass;  // shop windows: real glass slabs, ior 1.5, slight green-grey absorption
  glass.name = "shop_glass";
  glass.diffuse = {0.9f, 0.95f, 0.95f};
  glass.specular = {0.9f, 0.9f, 0.9f};
  glass.phong_exponent = 800.0f;
  glass.transparency = 0.95f;
  glass.ior = 1.5f;
  glass.absorption = {1.6f, 0.6f, 1.1f};
  s.add_material(glass);
  Material lit;  // shop interiors glow warmly (emission: the Whitted integrator has no indirect light)
  lit.name = "shop_wall";
  lit.diffuse = {0.85f, 0.78f, 0.62f};
  lit.emission = {0.30f, 0.25f, 0.17f};
  s.add_material(lit);
  lit.name = "shop_ceiling";
  lit.diffuse = {0.9f, 0.9f, 0.88f};
  lit.emission = {1.4f, 1.3f, 1.1f};
  s.add_material(lit);
  add("shop_floor", {0.45f, 0.33f, 0.22f}, 0.3f, 60.0f, 0.1f);
  Material goods;
  goods.emission = {0.06f, 0.05f, 0.04f};
  goods.name = "goods_red";
  goods.diffuse = {0.75f, 0.12f, 0.10f};
  s.add_material(goods);
  goods.name = "goods_teal";
  goods.diffuse = {0.10f, 0.55f, 0.55f};
  s.add_material(goods);
  goods.name = "goods_yellow";
  goods.diffuse = {0.85f, 0.70f, 0.15f};
  s.add_material(goods);
  add("door", {0.20f, 0.12f, 0.08f}, 0.2f, 40.0f);
  const Vec3 signs[kSignCount] = {{0.75f, 0.10f, 0.08f}, {0.10f, 0.30f, 0.70f}, {0.90f, 0.75f, 0.20f}, {0.15f, 0.55f, 0.25f}};
  const char* sign_names[kSignCount] = {"sign_red", "sign_blue", "sign_yellow", "sign_green"};
  for (uint32_t i = 0; i < kSignCount; ++i) {
    Material m;
    m.name = sign_names[i];
    m.diffuse = signs[i];
    m.specular = Vec3{0.3f};
    m.phong_exponent = 60.0f;
    m.emission = signs[i] * 0.45f;
    s.add_material(m);
  }
  add("roof", {0.30f, 0.30f, 0.32f});
  Material water;  // canal water: reflective and refractive like the pool's, but murky green
  water.name = "canal_water";
  water.diffuse = {0.02f, 0.06f, 0.06f};
  water.specular = {1.0f, 1.0f, 1.0f};
  water.phong_exponent = 600.0f;
  water.transparency = 1.0f;
  water.ior = 1.33f;
  water.absorption = {0.9f, 0.35f, 0.4f};
  s.add_material(water);
  add("canal_bottom", {0.12f, 0.10f, 0.07f});
  add("bridge_stone", {0.62f, 0.56f, 0.47f});
  add("railing", {0.16f, 0.17f, 0.18f}, 0.5f, 80.0f, 0.15f);
  add("tree_trunk", {0.30f, 0.20f, 0.12f});
  add("foliage", {0.14f, 0.30f, 0.08f});
  add("foliage_light", {0.24f, 0.40f, 0.12f});
  add("lamp_post", {0.08f, 0.09f, 0.10f}, 0.5f, 80.0f);
  Material lamp;
  lamp.name = "lamp_light";
  lamp.diffuse = {0.0f, 0.0f, 0.0f};
  lamp.emission = {3.0f, 2.6f, 1.9f};
  s.add_material(lamp);
  add("chrome", {0.3f, 0.3f, 0.3f}, 1.0f, 900.0f, 0.85f);
  add("metal_panel", {0.22f, 0.24f, 0.27f}, 0.4f, 100.0f, 0.1f);
}

// ---------------------------------------------------------------------------------------------
// Sinks: the generator is a template over where triangles go. CountSink only counts (used to
// size the city), SceneSink appends flat-shaded quads straight to the Scene's arrays, with
// per-triangle materials, and closes one MeshRange per zone.

struct CountSink {
  static constexpr bool kCountOnly = true;
  uint64_t triangles = 0, vertices = 0;
  void begin_zone(const char*, int = -1, int = -1) {}
  void end_zone() {}
  void add_quads(int n) {
    triangles += 2 * static_cast<uint64_t>(n);
    vertices += 4 * static_cast<uint64_t>(n);
  }
  void quad(const Vec3&, const Vec3&, const Vec3&, const Vec3&, uint32_t) { add_quads(1); }
  void mesh(const MeshBuilder& m, const Vec3&, const Vec3&, uint32_t) {
    triangles += m.indices.size() / 3;
    vertices += m.positions.size();
  }
  void checker(const Vec3&, const Vec3&, const Vec3&, int nu, int nv, uint32_t, uint32_t) {
    triangles += 2ull * static_cast<uint64_t>(nu) * static_cast<uint64_t>(nv);
    vertices += 4ull * static_cast<uint64_t>(nu) * static_cast<uint64_t>(nv);
  }
};

class SceneSink {
 public:
  static constexpr bool kCountOnly = false;
  /// Sizes the scene's arrays for \p vertices and \p triangles more (what a CountSink pass
  /// over the same city counted) and writes them in place.
  SceneSink(Scene& s, uint64_t vertices, uint64_t triangles) : s_(s) {
    v_ = s.positions.size();
    t_ = s.material_ids.size();
    s.positions.resize(v_ + vertices);
    s.normals.resize(v_ + vertices);
    s.indices.resize(3 * (t_ + triangles));
    s.material_ids.resize(t_ + triangles);
  }
  /// True when exactly the counted vertices and triangles were written.
  bool complete() const { return v_ == s_.positions.size() && t_ == s_.material_ids.size(); }
  void add_quads(int) {}
  void begin_zone(const char* name, int a = -1, int b = -1) {
    char buf[64];
    if (a >= 0 && b >= 0) std::snprintf(buf, sizeof buf, "%s_%02d_%02d", name, a, b);
    else if (a >= 0) std::snprintf(buf, sizeof buf, "%s_%02d", name, a);
    else std::snprintf(buf, sizeof buf, "%s", name);
    name_ = buf;
    first_ = static_cast<uint32_t>(t_);
  }
  void end_zone() {
    const auto n = static_cast<uint32_t>(t_);
    if (n > first_) s_.meshes.push_back(MeshRange{name_, first_, n - first_});
  }
  /// Flat quad a-b-c-d, counter-clockwise seen from the side its normal points to.
  void quad(const Vec3& a, const Vec3& b, const Vec3& c, const Vec3& d, uint32_t m) {
    if (v_ + 4 > s_.positions.size() || t_ + 2 > s_.material_ids.size()) throw Error("city: triangle count mismatch");
    const Vec3 n = normalize(cross(b - a, c - a));
    const auto base = static_cast<uint32_t>(v_);
    Vec3* p = s_.positions.data() + v_;
    Vec3* nn = s_.normals.data() + v_;
    p[0] = a, p[1] = b, p[2] = c, p[3] = d;
    nn[0] = n, nn[1] = n, nn[2] = n, nn[3] = n;
    uint32_t* idx = s_.indices.data() + 3 * t_;
    idx[0] = base, idx[1] = base + 1, idx[2] = base + 2, idx[3] = base, idx[4] = base + 2, idx[5] = base + 3;
    s_.material_ids[t_] = m;
    s_.material_ids[t_ + 1] = m;
    v_ += 4;
    t_ += 2;
  }
  /// A template mesh scaled by \p k (per axis) and moved to \p c.
  void mesh(const MeshBuilder& t, const Vec3& c, const Vec3& k, uint32_t m) {
    const size_t nt = t.indices.size() / 3;
    if (v_ + t.positions.size() > s_.positions.size() || t_ + nt > s_.material_ids.size())
      throw Error("city: triangle count mismatch");
    const auto base = static_cast<uint32_t>(v_);
    for (size_t i = 0; i < t.positions.size(); ++i) {
      s_.positions[v_ + i] = c + t.positions[i] * k;
      s_.normals[v_ + i] = normalize(t.normals[i] / k);
    }
    for (size_t i = 0; i < t.indices.size(); ++i) s_.indices[3 * t_ + i] = base + t.indices[i];
    std::fill_n(s_.material_ids.begin() + static_cast<std::ptrdiff_t>(t_), nt, m);
    v_ += t.positions.size();
    t_ += nt;
  }
  /// Checkerboard of tiles (see checker_quads in builtin_geometry.h).
  void checker(const Vec3& c, const Vec3& u, const Vec3& v, int nu, int nv, uint32_t even, uint32_t odd) {
    MeshBuilder e, o;
    checker_quads(e, o, c, u, v, nu, nv);
    append(e, even);
    append(o, odd);
  }

 private:
  void append(const MeshBuilder& b, uint32_t m) {
    const size_t nt = b.indices.size() / 3;
    if (v_ + b.positions.size() > s_.positions.size() || t_ + nt > s_.material_ids.size())
      throw Error("city: triangle count mismatch");
    const auto base = static_cast<uint32_t>(v_);
    std::copy(b.positions.begin(), b.positions.end(), s_.positions.begin() + static_cast<std::ptrdiff_t>(v_));
    std::copy(b.normals.begin(), b.normals.end(), s_.normals.begin() + static_cast<std::ptrdiff_t>(v_));
    for (size_t i = 0; i < b.indices.size(); ++i) s_.indices[3 * t_ + i] = base + b.indices[i];
    std::fill_n(s_.material_ids.begin() + static_cast<std::ptrdiff_t>(t_), nt, m);
    v_ += b.positions.size();
    t_ += nt;
  }

  Scene& s_;
  size_t v_ = 0, t_ = 0;  // vertices and triangles written so far
  std::string name_;
  uint32_t first_ = 0;
};

// ---------------------------------------------------------------------------------------------
// Geometry on top of a sink.

/// A local frame: point (s, t, d) = o + u s + v t + n d, with u x v = n (n: the outward side).
struct Frame {
  Vec3 o, u, v, n;
  Vec3 at(float s, float t, float d) const { return o + u * s + v * t + n * d; }
};
constexpr Frame kWorld{{0, 0, 0}, {1, 0, 0}, {0, 1, 0}, {0, 0, 1}};  // s = x, t = y, d = z

/// Quad with the winding that makes its normal point along \p facing.
template <class S>
void oquad(S& s, const Vec3& a, const Vec3& b, const Vec3& c, const Vec3& d, const Vec3& facing, uint32_t m) {
  if constexpr (S::kCountOnly) {
    s.add_quads(1);
    return;
  }
  if (dot(cross(b - a, c - a), facing) < 0.0f) s.quad(a, d, c, b, m);
  else s.quad(a, b, c, d, m);
}

/// Rectangle [s0,s1] x [t0,t1] at depth d facing +n (skipped when empty).
template <class S>
void front(S& s, const Frame& f, float s0, float s1, float t0, float t1, float d, uint32_t m) {
  if (s1 - s0 < 1e-3f || t1 - t0 < 1e-3f) return;
  if constexpr (S::kCountOnly) {
    s.add_quads(1);
    return;
  }
  s.quad(f.at(s0, t0, d), f.at(s1, t0, d), f.at(s1, t1, d), f.at(s0, t1, d), m);
}

enum Face : unsigned { kFront = 1, kBack = 2, kLeft = 4, kRight = 8, kTop = 16, kBottom = 32, kAllFaces = 63 };
constexpr unsigned kNoBottom = kAllFaces & ~kBottom;
constexpr unsigned kNoBack = kAllFaces & ~kBack;

/// Box [s0,s1] x [t0,t1] x [d0,d1] in frame coordinates; \p faces selects the outward faces
/// (front = +n, back = -n, left = -u, right = +u, top = +v, bottom = -v).
template <class S>
void lbox(S& s, const Frame& f, float s0, float s1, float t0, float t1, float d0, float d1, uint32_t m,
          unsigned faces = kAllFaces) {
  if (s1 - s0 < 1e-3f || t1 - t0 < 1e-3f || d1 - d0 < 1e-3f) return;
  if constexpr (S::kCountOnly) {
    s.add_quads(std::popcount(faces & kAllFaces));
    return;
  }
  // Corner i has s1 if bit 0 is set, t1 if bit 1, d1 if bit 2.
  std::array<Vec3, 8> c;
  for (int i = 0; i < 8; ++i) c[static_cast<size_t>(i)] = f.at(i & 1 ? s1 : s0, i & 2 ? t1 : t0, i & 4 ? d1 : d0);
  if (faces & kFront) oquad(s, c[4], c[5], c[7], c[6], f.n, m);
  if (faces & kBack) oquad(s, c[0], c[1], c[3], c[2], -f.n, m);
  if (faces & kRight) oquad(s, c[1], c[5], c[7], c[3], f.u, m);
  if (faces & kLeft) oquad(s, c[0], c[4], c[6], c[2], -f.u, m);
  if (faces & kTop) oquad(s, c[2], c[3], c[7], c[6], f.v, m);
  if (faces & kBottom) oquad(s, c[0], c[1], c[5], c[4], -f.v, m);
}

/// World box (x, y, z ranges).
template <class S>
void wbox(S& s, const Vec3& lo, const Vec3& hi, uint32_t m, unsigned faces = kAllFaces) {
  lbox(s, kWorld, lo.x, hi.x, lo.y, hi.y, lo.z, hi.z, m, faces);
}

/// Horizontal rectangle [x0,x1] x [z0,z1] at height y facing up.
template <class S>
void floor_rect(S& s, float x0, float x1, float z0, float z1, float y, uint32_t m) {
  if (x1 - x0 < 1e-3f || z1 - z0 < 1e-3f) return;
  oquad(s, Vec3{x0, y, z0}, Vec3{x1, y, z0}, Vec3{x1, y, z1}, Vec3{x0, y, z1}, Vec3{0, 1, 0}, m);
}

/// Unit octagon (exact constants; no trigonometry).
constexpr float kC45 = 0.70710678f;
constexpr std::array<std::array<float, 2>, 8> kOct = {{{1, 0}, {kC45, kC45}, {0, 1}, {-kC45, kC45},
                                                        {-1, 0}, {-kC45, -kC45}, {0, -1}, {kC45, -kC45}}};

/// Vertical octagonal prism (sides and top; radius r) from y0 to y1.
template <class S>
void oct_prism(S& s, const Vec3& base, float r, float y0, float y1, uint32_t side, uint32_t top, bool with_top = true) {
  Vec3 lo[8], hi[8];
  for (int k = 0; k < 8; ++k) {
    lo[k] = {base.x + r * kOct[k][0], y0, base.z + r * kOct[k][1]};
    hi[k] = {lo[k].x, y1, lo[k].z};
  }
  for (int k = 0; k < 8; ++k) {
    const int l = (k + 1) % 8;
    const Vec3 out{kOct[k][0] + kOct[l][0], 0, kOct[k][1] + kOct[l][1]};
    oquad(s, lo[k], lo[l], hi[l], hi[k], out, side);
  }
  if (with_top) {
    const Vec3 up{0, 1, 0};
    oquad(s, hi[0], hi[1], hi[2], hi[3], up, top);
    oquad(s, hi[0], hi[3], hi[4], hi[7], up, top);
    oquad(s, hi[4], hi[5], hi[6], hi[7], up, top);
  }
}

// ---------------------------------------------------------------------------------------------
// Dimensions.

constexpr float kBlock = 36.0f;         // block side (the lots), m
constexpr float kStreet = 15.0f;        // street corridor: 2.5 m sidewalks + 10 m road
constexpr float kSidewalk = 2.5f;
constexpr float kCurb = 0.15f;          // sidewalk and block slab height
constexpr float kCanalWidth = 24.0f;    // canal corridor: sidewalks, 2 m quays, 15 m channel
constexpr float kQuay = 2.0f;
constexpr float kWaterY = -2.0f, kCanalBottom = -4.5f;
constexpr float kViaductStreet = 27.0f;  // street under the elevated road: 22 m road with a median
constexpr float kDeckHalf = 8.0f, kDeckBottom = 6.0f, kDeckTop = 6.7f, kGirderBottom = 5.2f;
constexpr float kGroundFloor = 4.2f, kFloor = 3.2f, kParapet = 1.0f;
constexpr float kMarkY = 0.012f;

struct Layout {
  int g = 4;                       // blocks per side
  int canal = 2, bridge = 2, viaduct = 1;  // x-line of the canal, z-lines of bridge and viaduct
  int plaza_i = 2, plaza_j = 2;
  std::vector<float> xl, xw, zl, zw;  // corridor start and width of each line 0..g
  float X0 = 0, X1 = 0, Z0 = 0, Z1 = 0;  // outer road edges

  float bx0(int i) const { return xl[static_cast<size_t>(i)] + xw[static_cast<size_t>(i)]; }
  float bx1(int i) const { return xl[static_cast<size_t>(i) + 1]; }
  float bz0(int j) const { return zl[static_cast<size_t>(j)] + zw[static_cast<size_t>(j)]; }
  float bz1(int j) const { return zl[static_cast<size_t>(j) + 1]; }
  float xc(int k) const { return xl[static_cast<size_t>(k)] + 0.5f * xw[static_cast<size_t>(k)]; }
  float zc(int k) const { return zl[static_cast<size_t>(k)] + 0.5f * zw[static_cast<size_t>(k)]; }
  /// Road x-range of x-line k (the canal's "road" edge is its quay's inner edge).
  float road_x0(int k) const { return xl[static_cast<size_t>(k)] + kSidewalk; }
  float road_x1(int k) const { return xl[static_cast<size_t>(k)] + xw[static_cast<size_t>(k)] - kSidewalk; }
  float road_z0(int k) const { return zl[static_cast<size_t>(k)] + kSidewalk; }
  float road_z1(int k) const { return zl[static_cast<size_t>(k)] + zw[static_cast<size_t>(k)] - kSidewalk; }
};

Layout make_layout(int g) {
  Layout L;
  L.g = g;
  L.canal = (g + 1) / 2;
  L.bridge = g / 2;
  L.viaduct = L.bridge - 1;
  L.plaza_i = L.canal;
  L.plaza_j = L.bridge;
  auto lines = [g](int special, float special_w, std::vector<float>& start, std::vector<float>& width) {
    float pos = 0.0f;
    for (int k = 0; k <= g; ++k) {
      const float w = k == special ? special_w : kStreet;
      start.push_back(pos);
      width.push_back(w);
      pos += w + (k < g ? kBlock : 0.0f);
    }
    const float half = 0.5f * pos;
    for (float& p : start) p -= half;  // centre the city on the origin
  };
  lines(L.canal, kCanalWidth, L.xl, L.xw);
  lines(L.viaduct, kViaductStreet, L.zl, L.zw);
  L.X0 = L.road_x0(0);
  L.X1 = L.road_x1(g);
  L.Z0 = L.road_z0(0);
  L.Z1 = L.road_z1(g);
  return L;
}

/// Level of detail: \p k scales building heights; props thin out below 1.
struct Detail {
  float k = 1.0f;
  float props() const { return std::clamp(k, 0.1f, 1.0f); }
  /// Below k = 0.3 windows and shops get wider (fewer of them): tiny cities for tests.
  float sparse() const { return std::max(1.0f, 0.3f / k); }
};

struct Templates {
  MeshBuilder crown = icosphere({0, 0, 0}, 1.0f, 1);  // 80 triangles
  MeshBuilder ball = icosphere({0, 0, 0}, 1.0f, 3);   // 1280 triangles
  MeshBuilder small_ball = icosphere({0, 0, 0}, 1.0f, 1);
};

// ---------------------------------------------------------------------------------------------
// Props.

template <class S>
void tree(S& s, const Templates& t, const Vec3& p, float h, bool light) {
  const float r = 0.14f * h / 6.0f + 0.08f;
  wbox(s, {p.x - r, p.y, p.z - r}, {p.x + r, p.y + 0.55f * h, p.z + r}, kTrunk, kLeft | kRight | kFront | kBack);
  const float cr = 0.3f * h;
  s.mesh(t.crown, {p.x, p.y + 0.62f * h, p.z}, {cr, 1.15f * cr, cr}, light ? kFoliage1 : kFoliage0);
}

/// Street lamp at \p p whose arm reaches \p reach metres along \p dir (a unit axis vector in xz).
/// Returns where a point light just below the lamp head would be.
template <class S>
Vec3 street_lamp(S& s, const Vec3& p, const Vec3& dir, float height = 6.0f, float reach = 1.3f) {
  wbox(s, {p.x - 0.08f, p.y, p.z - 0.08f}, {p.x + 0.08f, p.y + height, p.z + 0.08f}, kLampPost, kNoBottom);
  const Vec3 e = p + dir * reach;
  const Vec3 lo = min(p, e), hi = max(p, e);
  const Vec3 side = Vec3{1, 0, 1} - abs(dir);  // the horizontal axis across the arm
  const Vec3 w = side * 0.05f;
  wbox(s, Vec3{lo.x, p.y + height - 0.12f, lo.z} - w, Vec3{hi.x, p.y + height, hi.z} + w, kLampPost,
       kAllFaces);
  const Vec3 hw = side * 0.22f + abs(dir) * 0.32f;
  wbox(s, Vec3{e.x, p.y + height - 0.3f, e.z} - hw, Vec3{e.x, p.y + height - 0.1f, e.z} + hw, kLampPost, kNoBottom);
  wbox(s, Vec3{e.x, p.y + height - 0.32f, e.z} - hw * 0.9f, Vec3{e.x, p.y + height - 0.3f, e.z} + hw * 0.9f,
       kLampLight, kBottom);
  return {e.x, p.y + height - 0.5f, e.z};
}

template <class S>
void bench(S& s, const Vec3& p, bool along_x) {
  const Vec3 h = along_x ? Vec3{0.9f, 0, 0.25f} : Vec3{0.25f, 0, 0.9f};
  wbox(s, Vec3{p.x - h.x, p.y + 0.4f, p.z - h.z}, Vec3{p.x + h.x, p.y + 0.48f, p.z + h.z}, kBridgeStone);
  for (float f : {-0.75f, 0.75f}) {
    const Vec3 q = along_x ? Vec3{p.x + f * h.x, p.y, p.z} : Vec3{p.x, p.y, p.z + f * h.z};
    wbox(s, Vec3{q.x - 0.06f, q.y, q.z - 0.06f} + (along_x ? Vec3{0, 0, -0.15f} : Vec3{-0.15f, 0, 0}),
         Vec3{q.x + 0.06f, q.y + 0.4f, q.z + 0.06f} + (along_x ? Vec3{0, 0, 0.15f} : Vec3{0.15f, 0, 0}),
         kConcrete, kLeft | kRight | kFront | kBack);
  }
}

// ---------------------------------------------------------------------------------------------
// Buildings.

struct Opening {
  float s0, s1, t0, t1;
};

/// Wall band [tb, tt] over [0, w] at depth 0 with rectangular holes (sorted by s, disjoint).
template <class S>
void wall_with_holes(S& s, const Frame& f, float w, float tb, float tt, const std::vector<Opening>& holes, uint32_t m) {
  if (holes.empty()) {
    front(s, f, 0.0f, w, tb, tt, 0.0f, m);
    return;
  }
  bool uniform = true;
  for (const Opening& h : holes) uniform = uniform && h.t0 == holes[0].t0 && h.t1 == holes[0].t1;
  float prev = 0.0f;
  if (uniform) {
    const float t0 = holes[0].t0, t1 = holes[0].t1;
    front(s, f, 0.0f, w, tb, t0, 0.0f, m);
    front(s, f, 0.0f, w, t1, tt, 0.0f, m);
    for (const Opening& h : holes) {
      front(s, f, prev, h.s0, t0, t1, 0.0f, m);
      prev = h.s1;
    }
    front(s, f, prev, w, t0, t1, 0.0f, m);
    return;
  }
  for (const Opening& h : holes) {
    front(s, f, prev, h.s0, tb, tt, 0.0f, m);
    front(s, f, h.s0, h.s1, tb, h.t0, 0.0f, m);
    front(s, f, h.s0, h.s1, h.t1, tt, 0.0f, m);
    prev = h.s1;
  }
  front(s, f, prev, w, tb, tt, 0.0f, m);
}

/// Four faces lining a rectangular hole from depth 0 back to -depth (facing into the hole).
template <class S>
void reveals(S& s, const Frame& f, const Opening& h, float depth, uint32_t m, bool bottom = true) {
  auto P = [&f](float a, float b, float c) { return f.at(a, b, c); };
  if (bottom) oquad(s, P(h.s0, h.t0, 0), P(h.s1, h.t0, 0), P(h.s1, h.t0, -depth), P(h.s0, h.t0, -depth), f.v, m);
  oquad(s, P(h.s0, h.t1, 0), P(h.s1, h.t1, 0), P(h.s1, h.t1, -depth), P(h.s0, h.t1, -depth), -f.v, m);
  oquad(s, P(h.s0, h.t0, 0), P(h.s0, h.t1, 0), P(h.s0, h.t1, -depth), P(h.s0, h.t0, -depth), f.u, m);
  oquad(s, P(h.s1, h.t0, 0), P(h.s1, h.t1, 0), P(h.s1, h.t1, -depth), P(h.s1, h.t0, -depth), -f.u, m);
}

/// Recessed window: reveals, two panes split by a mullion, a protruding sill.
template <class S>
void window_recessed(S& s, const Frame& f, const Opening& h, uint32_t frame) {
  constexpr float r = 0.22f, mw = 0.035f;
  reveals(s, f, h, r, kSill);
  const float sc = 0.5f * (h.s0 + h.s1);
  front(s, f, h.s0, sc - mw, h.t0, h.t1, -r, kWindowGlass);
  front(s, f, sc + mw, h.s1, h.t0, h.t1, -r, kWindowGlass);
  lbox(s, f, sc - mw, sc + mw, h.t0, h.t1, -r, -r + 0.06f, frame, kFront | kLeft | kRight);
  lbox(s, f, h.s0 - 0.06f, h.s1 + 0.06f, h.t0 - 0.07f, h.t0, 0.0f, 0.1f, kSill, kNoBack);
}

/// Window in a protruding frame: the frame ring stands 0.1 m proud of the wall, the pane sits
/// 0.08 m behind it.
template <class S>
void window_framed(S& s, const Frame& f, const Opening& h, uint32_t frame) {
  constexpr float fw = 0.11f, p = 0.1f, g = 0.08f;
  auto P = [&f](float a, float b, float c) { return f.at(a, b, c); };
  const Opening in{h.s0 + fw, h.s1 - fw, h.t0 + fw, h.t1 - fw};
  // Front of the ring.
  front(s, f, h.s0, h.s1, h.t0, in.t0, p, frame);
  front(s, f, h.s0, h.s1, in.t1, h.t1, p, frame);
  front(s, f, h.s0, in.s0, in.t0, in.t1, p, frame);
  front(s, f, in.s1, h.s1, in.t0, in.t1, p, frame);
  // Outer sides (wall to ring front).
  oquad(s, P(h.s0, h.t0, 0), P(h.s1, h.t0, 0), P(h.s1, h.t0, p), P(h.s0, h.t0, p), -f.v, frame);
  oquad(s, P(h.s0, h.t1, 0), P(h.s1, h.t1, 0), P(h.s1, h.t1, p), P(h.s0, h.t1, p), f.v, frame);
  oquad(s, P(h.s0, h.t0, 0), P(h.s0, h.t1, 0), P(h.s0, h.t1, p), P(h.s0, h.t0, p), -f.u, frame);
  oquad(s, P(h.s1, h.t0, 0), P(h.s1, h.t1, 0), P(h.s1, h.t1, p), P(h.s1, h.t0, p), f.u, frame);
  // Inner sides (ring front back to the pane).
  oquad(s, P(in.s0, in.t0, p), P(in.s1, in.t0, p), P(in.s1, in.t0, -g), P(in.s0, in.t0, -g), f.v, frame);
  oquad(s, P(in.s0, in.t1, p), P(in.s1, in.t1, p), P(in.s1, in.t1, -g), P(in.s0, in.t1, -g), -f.v, frame);
  oquad(s, P(in.s0, in.t0, p), P(in.s0, in.t1, p), P(in.s0, in.t1, -g), P(in.s0, in.t0, -g), f.u, frame);
  oquad(s, P(in.s1, in.t0, p), P(in.s1, in.t1, p), P(in.s1, in.t1, -g), P(in.s1, in.t0, -g), -f.u, frame);
  front(s, f, in.s0, in.s1, in.t0, in.t1, -g, kWindowGlass);
}

struct Building {
  float x0, z0, x1, z1;
  int floors = 1;     // including the ground floor
  int style = 0;      // 0 recessed windows, 1 framed windows, 2 curtain wall
  uint32_t wall = kWall0, frame = kFrameLight;
  float bay = 3.2f;
  float shop_width = 6.5f;
  bool street[4] = {false, false, false, false};  // sides +z, +x, -z, -x face a street
  uint64_t seed = 0;
};

/// Frame of side k of a footprint (k = 0: +z, 1: +x, 2: -z, 3: -x), origin at the bottom-left
/// corner seen from outside; returns the side's width.
float side_frame(const Building& b, int k, float y0, Frame& f) {
  const Vec3 up{0, 1, 0};
  switch (k) {
    case 0: f = {{b.x0, y0, b.z1}, {1, 0, 0}, up, {0, 0, 1}}; return b.x1 - b.x0;
    case 1: f = {{b.x1, y0, b.z1}, {0, 0, -1}, up, {1, 0, 0}}; return b.z1 - b.z0;
    case 2: f = {{b.x1, y0, b.z0}, {-1, 0, 0}, up, {0, 0, -1}}; return b.x1 - b.x0;
    default: f = {{b.x0, y0, b.z0}, {0, 0, 1}, up, {-1, 0, 0}}; return b.z1 - b.z0;
  }
}

/// Ground-floor shop fronts along a street side: shop windows (glass slabs) with a lit room
/// behind, goods, a door and a sign per shop.
template <class S>
void shopfront(S& s, const Frame& f, float w, float m0, float m1, const Building& b, Rng& rng,
               std::vector<Opening>& holes) {
  // Shops between the margins m0 (s = 0 end) and m1 (s = w end), which keep the 4 m deep shop
  // rooms clear of the neighbouring sides.
  const float sw = w - m0 - m1;
  const int n = std::max(1, static_cast<int>(sw / b.shop_width));
  const float bw = sw / static_cast<float>(n);
  holes.clear();
  for (int i = 0; i < n; ++i) {
    const float a = m0 + bw * static_cast<float>(i);
    if (bw >= 4.6f) {
      holes.push_back({a + 0.5f, a + bw - 2.0f, 0.5f, 3.2f});
      holes.push_back({a + bw - 1.55f, a + bw - 0.45f, 0.0f, 2.6f});
    } else {
      holes.push_back({a + 0.4f, a + bw - 0.4f, 0.5f, 3.2f});
    }
  }
  wall_with_holes(s, f, w, 0.0f, kGroundFloor, holes, b.wall);
  for (const Opening& h : holes) {
    if (h.t0 == 0.0f) {  // door
      reveals(s, f, h, 0.3f, kFrameDark, false);
      front(s, f, h.s0, h.s1, h.t0, h.t1, -0.3f, kDoor);
      continue;
    }
    reveals(s, f, h, 0.3f, kFrameDark);
    // The glass: a closed 2 cm slab (wound outwards: a dielectric), its edges hidden in the wall.
    lbox(s, f, h.s0 - 0.04f, h.s1 + 0.04f, h.t0 - 0.04f, h.t1 + 0.04f, -0.14f, -0.12f, kShopGlass);
    // The room behind it, all faces looking into the room.
    const float rs0 = h.s0 - 0.3f, rs1 = h.s1 + 0.3f, rt0 = 0.3f, rt1 = 3.7f, back = -4.0f;
    const Frame inside{f.o, -f.u, f.v, -f.n};  // a frame looking back out of the room
    auto P = [&f](float a, float c, float d) { return f.at(a, c, d); };
    oquad(s, P(rs0, rt0, -0.3f), P(rs1, rt0, -0.3f), P(rs1, rt0, back), P(rs0, rt0, back), f.v, kShopFloor);
    oquad(s, P(rs0, rt1, -0.3f), P(rs1, rt1, -0.3f), P(rs1, rt1, back), P(rs0, rt1, back), -f.v, kShopCeiling);
    front(s, f, rs0, rs1, rt0, rt1, back, kShopWall);
    oquad(s, P(rs0, rt0, -0.3f), P(rs0, rt1, -0.3f), P(rs0, rt1, back), P(rs0, rt0, back), f.u, kShopWall);
    oquad(s, P(rs1, rt0, -0.3f), P(rs1, rt1, -0.3f), P(rs1, rt1, back), P(rs1, rt0, back), -f.u, kShopWall);
    // Inner face of the front wall around the opening (s mirrored in the inside frame).
    front(s, inside, -h.s0, -rs0, rt0, rt1, 0.3f, kShopWall);
    front(s, inside, -rs1, -h.s1, rt0, rt1, 0.3f, kShopWall);
    front(s, inside, -h.s1, -h.s0, rt0, h.t0, 0.3f, kShopWall);
    front(s, inside, -h.s1, -h.s0, h.t1, rt1, 0.3f, kShopWall);
    // Goods: a display table with two items, a shelf at the back.
    const auto goods = static_cast<uint32_t>(kGoods0 + rng.irange(0, 2));
    lbox(s, f, h.s0 + 0.3f, h.s1 - 0.3f, rt0, 1.0f, -1.9f, -1.0f, kShopFloor, kNoBottom);
    for (int k = 0; k < 2; ++k) {
      const float c = h.s0 + (h.s1 - h.s0) * (0.3f + 0.4f * static_cast<float>(k)) + rng.range(-0.2f, 0.2f);
      const float hw = rng.range(0.15f, 0.35f), hh = rng.range(0.2f, 0.8f);
      lbox(s, f, c - hw, c + hw, 1.0f, 1.0f + hh, -1.7f, -1.2f, goods, kNoBottom);
    }
    lbox(s, f, rs0 + 0.2f, rs1 - 0.2f, rt0, 2.4f, back, back + 0.5f,
         static_cast<uint32_t>(kGoods0 + rng.irange(0, 2)), kFront | kLeft | kRight | kTop);
  }
  // Signs above the shops.
  for (int i = 0; i < n; ++i) {
    const float a = m0 + bw * static_cast<float>(i);
    lbox(s, f, a + 0.3f, a + bw - 0.3f, 3.45f, 4.0f, 0.0f, 0.16f,
         static_cast<uint32_t>(kSign0 + rng.irange(0, static_cast<int>(kSignCount) - 1)), kNoBack);
  }
}

/// One floor band of windows (styles 0 and 1) or of curtain wall (style 2).
template <class S>
void window_floor(S& s, const Frame& f, float w, float tb, float fh, bool ground, const Building& b,
                  std::vector<Opening>& holes) {
  const int n = std::max(1, static_cast<int>(w / b.bay));
  const float bw = w / static_cast<float>(n);
  if (b.style == 2) {
    constexpr float sp = 0.8f, mw = 0.06f;
    lbox(s, f, -0.12f, w + 0.12f, tb, tb + sp, 0.0f, 0.12f, kPanel, kNoBack);
    for (int i = 0; i <= n; ++i) {
      const float c = bw * static_cast<float>(i);
      lbox(s, f, c - mw, c + mw, tb + sp, tb + fh, 0.0f, 0.15f, b.frame, kFront | kLeft | kRight);
    }
    for (int i = 0; i < n; ++i)
      front(s, f, bw * static_cast<float>(i) + mw, bw * static_cast<float>(i + 1) - mw, tb + sp, tb + fh, 0.0f,
            kWindowGlass);
    return;
  }
  if (w < 1.6f) {
    front(s, f, 0.0f, w, tb, tb + fh, 0.0f, b.wall);
    return;
  }
  const float ww = std::min(0.55f * bw, 1.9f);
  const float sill = ground ? 1.2f : 0.9f, wh = ground ? 2.0f : 1.7f;
  holes.clear();
  for (int i = 0; i < n; ++i) {
    const float s0 = bw * static_cast<float>(i) + 0.5f * (bw - ww);
    holes.push_back({s0, s0 + ww, tb + sill, tb + sill + wh});
  }
  wall_with_holes(s, f, w, tb, tb + fh, holes, b.wall);
  for (const Opening& h : holes) {
    if (b.style == 0) window_recessed(s, f, h, b.frame);
    else window_framed(s, f, h, b.frame);
  }
}

template <class S>
void building(S& s, const Building& b, float y0, std::vector<Opening>& holes) {
  Rng rng(b.seed);
  const float hf = kGroundFloor + kFloor * static_cast<float>(b.floors - 1);  // roof level
  for (int k = 0; k < 4; ++k) {
    Frame f;
    const float w = side_frame(b, k, y0, f);
    const float m0 = b.street[(k + 3) % 4] ? 4.3f : 0.4f, m1 = b.street[(k + 1) % 4] ? 4.3f : 0.4f;
    if (b.street[k] && w - m0 - m1 >= 4.0f) shopfront(s, f, w, m0, m1, b, rng, holes);
    else window_floor(s, f, w, 0.0f, kGroundFloor, true, b, holes);
    for (int fl = 1; fl < b.floors; ++fl)
      window_floor(s, f, w, kGroundFloor + kFloor * static_cast<float>(fl - 1), kFloor, false, b, holes);
    front(s, f, 0.0f, w, hf, hf + kParapet, 0.0f, b.style == 2 ? kPanel : b.wall);  // parapet
    if (b.style != 2)  // cornice
      lbox(s, f, -0.25f, w + 0.25f, hf - 0.3f, hf, 0.0f, 0.25f, b.frame == kFrameDark ? kSill : b.frame, kNoBack);
  }
  // Roof: parapet cap and inner faces, the roof plane, a stair house, units and a water tank.
  const float x0 = b.x0, x1 = b.x1, z0 = b.z0, z1 = b.z1, t = 0.3f, top = y0 + hf + kParapet, r = y0 + hf;
  const uint32_t pm = b.style == 2 ? kPanel : b.wall;
  floor_rect(s, x0, x1, z0, z0 + t, top, pm);
  floor_rect(s, x0, x1, z1 - t, z1, top, pm);
  floor_rect(s, x0, x0 + t, z0 + t, z1 - t, top, pm);
  floor_rect(s, x1 - t, x1, z0 + t, z1 - t, top, pm);
  oquad(s, Vec3{x0 + t, r, z0 + t}, Vec3{x1 - t, r, z0 + t}, Vec3{x1 - t, top, z0 + t}, Vec3{x0 + t, top, z0 + t}, {0, 0, 1}, pm);
  oquad(s, Vec3{x0 + t, r, z1 - t}, Vec3{x1 - t, r, z1 - t}, Vec3{x1 - t, top, z1 - t}, Vec3{x0 + t, top, z1 - t}, {0, 0, -1}, pm);
  oquad(s, Vec3{x0 + t, r, z0 + t}, Vec3{x0 + t, r, z1 - t}, Vec3{x0 + t, top, z1 - t}, Vec3{x0 + t, top, z0 + t}, {1, 0, 0}, pm);
  oquad(s, Vec3{x1 - t, r, z0 + t}, Vec3{x1 - t, r, z1 - t}, Vec3{x1 - t, top, z1 - t}, Vec3{x1 - t, top, z0 + t}, {-1, 0, 0}, pm);
  floor_rect(s, x0 + t, x1 - t, z0 + t, z1 - t, r, kRoof);
  const float wx = x1 - x0 - 2 * t, wz = z1 - z0 - 2 * t;
  if (wx > 6.0f && wz > 6.0f) {
    const float sx = rng.range(x0 + t + 0.5f, x1 - t - 3.5f), sz = rng.range(z0 + t + 0.5f, z1 - t - 3.5f);
    wbox(s, {sx, r, sz}, {sx + 3.0f, r + 2.8f, sz + 3.0f}, pm, kNoBottom);
    const int units = rng.irange(0, 3);
    for (int u = 0; u < units; ++u) {
      const float ux = rng.range(x0 + t + 0.3f, x1 - t - 1.5f), uz = rng.range(z0 + t + 0.3f, z1 - t - 1.2f);
      wbox(s, {ux, r, uz}, {ux + 1.2f, r + 0.9f, uz + 0.9f}, kConcrete, kNoBottom);
    }
    if (rng.chance(0.3f)) {
      const Vec3 c{rng.range(x0 + t + 1.5f, x1 - t - 1.5f), r, rng.range(z0 + t + 1.5f, z1 - t - 1.5f)};
      oct_prism(s, c, 1.1f, r + 1.2f, r + 3.4f, kBridgeStone, kRoof);
      for (const auto& q : {std::array<float, 2>{-0.6f, -0.6f}, {0.6f, -0.6f}, {0.6f, 0.6f}, {-0.6f, 0.6f}})
        wbox(s, {c.x + q[0] - 0.07f, r, c.z + q[1] - 0.07f}, {c.x + q[0] + 0.07f, r + 1.2f, c.z + q[1] + 0.07f},
             kRailing, kLeft | kRight | kFront | kBack);
    }
  }
}

// ---------------------------------------------------------------------------------------------
// Zones.

/// Is x-line / z-line k a tree-lined boulevard?
bool boulevard_x(const Layout& L, int k) { return k != L.canal && k % 2 == 1; }
bool boulevard_z(const Layout& L, int k) { return k == L.bridge || (k != L.viaduct && k % 3 == 0); }

/// Position of street lamp \p idx (0 or 1) on side \p side of block (i, j), and its arm direction.
void block_lamp(const Layout& L, int i, int j, int side, int idx, Vec3& p, Vec3& dir) {
  const float x0 = L.bx0(i), x1 = L.bx1(i), z0 = L.bz0(j), z1 = L.bz1(j);
  const float f = (idx == 0 ? 0.22f : 0.72f) + 0.04f * static_cast<float>(side);
  constexpr float off = kSidewalk - 0.45f;
  switch (side) {
    case 0: p = {x0 + f * (x1 - x0), kCurb, z1 + off}; dir = {0, 0, 1}; break;
    case 1: p = {x1 + off, kCurb, z1 - f * (z1 - z0)}; dir = {1, 0, 0}; break;
    case 2: p = {x1 - f * (x1 - x0), kCurb, z0 - off}; dir = {0, 0, -1}; break;
    default: p = {x0 - off, kCurb, z0 + f * (z1 - z0)}; dir = {-1, 0, 0}; break;
  }
}

/// Which street line borders side \p side of block (i, j), and whether it is the canal.
bool side_on_canal(const Layout& L, int i, int side) {
  return (side == 1 && i + 1 == L.canal) || (side == 3 && i == L.canal);
}

template <class S>
void block_zone(S& s, const Layout& L, int i, int j, const Detail& d, const Templates& T, std::vector<Opening>& holes) {
  Rng rng(seed_of(1, i, j));
  const float x0 = L.bx0(i), x1 = L.bx1(i), z0 = L.bz0(j), z1 = L.bz1(j);
  s.begin_zone("zone", i, j);
  wbox(s, {x0 - kSidewalk, 0.0f, z0 - kSidewalk}, {x1 + kSidewalk, kCurb, z1 + kSidewalk}, kPavement, kNoBottom);
  // Lots.
  int na, nb;
  const float pick = rng.uniform();
  if (pick < 0.10f) na = 1, nb = 1;
  else if (pick < 0.20f) na = 2, nb = 1;
  else if (pick < 0.30f) na = 1, nb = 2;
  else if (pick < 0.62f) na = 2, nb = 2;
  else if (pick < 0.76f) na = 3, nb = 2;
  else if (pick < 0.90f) na = 2, nb = 3;
  else na = 3, nb = 3;
  if (d.k < 0.25f) na = 1, nb = std::min(nb, 2);  // tiny cities: fewer, bigger buildings
  if (d.k < 0.12f) nb = 1;
  auto cuts = [&rng](int n, float a0, float a1, std::vector<float>& out) {
    out.clear();
    out.push_back(a0);
    for (int c = 1; c < n; ++c)
      out.push_back(a0 + (a1 - a0) * (static_cast<float>(c) / static_cast<float>(n) + rng.range(-0.08f, 0.08f)));
    out.push_back(a1);
  };
  std::vector<float> cx, cz;
  cuts(na, x0, x1, cx);
  cuts(nb, z0, z1, cz);
  std::vector<float> gx(static_cast<size_t>(na) + 1, 0.0f), gz(static_cast<size_t>(nb) + 1, 0.0f);
  for (int c = 1; c < na; ++c) gx[static_cast<size_t>(c)] = rng.range(1.4f, 5.0f);
  for (int c = 1; c < nb; ++c) gz[static_cast<size_t>(c)] = rng.range(1.4f, 5.0f);
  const float dist = std::max(std::fabs(L.xc(L.canal) - 0.5f * (x0 + x1)), std::fabs(0.5f * (z0 + z1)));
  const bool central = dist < 2.5f * (kBlock + kStreet);
  for (int b = 0; b < nb; ++b)
    for (int a = 0; a < na; ++a) {
      const auto ua = static_cast<size_t>(a), ub = static_cast<size_t>(b);
      Building bl;
      bl.x0 = cx[ua] + 0.5f * gx[ua];
      bl.x1 = cx[ua + 1] - 0.5f * gx[ua + 1];
      bl.z0 = cz[ub] + 0.5f * gz[ub];
      bl.z1 = cz[ub + 1] - 0.5f * gz[ub + 1];
      bl.street[0] = b == nb - 1;
      bl.street[1] = a == na - 1 && !side_on_canal(L, i, 1);
      bl.street[2] = b == 0;
      bl.street[3] = a == 0 && !side_on_canal(L, i, 3);
      if (d.k < 0.1f) bl.street[1] = bl.street[3] = false;  // tiny cities: shops on two sides only
      bl.seed = rng.next();
      const bool inner = a > 0 && a < na - 1 && b > 0 && b < nb - 1;
      int base = rng.irange(3, 7);
      if (rng.chance(0.15f)) base = rng.irange(8, 12);
      bl.style = rng.chance(0.5f) ? 0 : 1;
      if (na * nb <= 2 && central && rng.chance(0.6f)) {
        base = rng.irange(12, 22);
        bl.style = 2;
      } else if (base >= 8 && rng.chance(0.4f)) {
        bl.style = 2;
      }
      bl.wall = kWall0 + static_cast<uint32_t>(rng.irange(0, static_cast<int>(kWallCount) - 1));
      const float fr = rng.uniform();
      bl.frame = fr < 0.5f ? kFrameLight : (fr < 0.8f ? kFrameDark : kSill);
      bl.bay = (bl.style == 2 ? 1.8f : rng.range(2.8f, 3.6f)) * d.sparse();
      bl.shop_width = 6.5f * d.sparse();
      if (bl.style == 2) bl.wall = kPanel, bl.frame = rng.chance(0.5f) ? kFrameDark : kFrameLight;
      bl.floors = std::max(1, static_cast<int>(std::lround(static_cast<float>(base) * d.k)));
      if (inner) {  // courtyard: a lawn with a tree
        floor_rect(s, bl.x0, bl.x1, bl.z0, bl.z1, kCurb + 0.02f, kGrass);
        tree(s, T, {0.5f * (bl.x0 + bl.x1), kCurb, 0.5f * (bl.z0 + bl.z1)}, 7.0f, true);
        continue;
      }
      building(s, bl, kCurb, holes);
    }
  // Sidewalk props: two lamps per side, trees along boulevards.
  const float props = d.props();
  for (int side = 0; side < 4; ++side) {
    if (side_on_canal(L, i, side)) continue;
    for (int idx = 0; idx < 2; ++idx) {
      if ((idx == 1 && props < 0.5f) || (props < 0.2f && side % 2 == 1)) continue;
      Vec3 p, dir;
      block_lamp(L, i, j, side, idx, p, dir);
      street_lamp(s, p, dir);
    }
    const bool bx = side == 1 ? boulevard_x(L, i + 1) : side == 3 ? boulevard_x(L, i) : false;
    const bool bz = side == 0 ? boulevard_z(L, j + 1) : side == 2 ? boulevard_z(L, j) : false;
    if (!(bx || bz)) continue;
    // Up to three trees, kept clear of the lamps (at fractions 0.22..0.34 and 0.72..0.84).
    constexpr float kTreeAt[3] = {0.5f, 0.04f, 0.96f};
    const int n = static_cast<int>(3.0f * props);
    for (int t = 0; t < n; ++t) {
      const float f = kTreeAt[t];
      constexpr float off = kSidewalk - 0.9f;
      Vec3 p;
      switch (side) {
        case 0: p = {x0 + f * (x1 - x0), kCurb, z1 + off}; break;
        case 1: p = {x1 + off, kCurb, z1 - f * (z1 - z0)}; break;
        case 2: p = {x1 - f * (x1 - x0), kCurb, z0 - off}; break;
        default: p = {x0 - off, kCurb, z0 + f * (z1 - z0)}; break;
      }
      tree(s, T, p, rng.range(5.5f, 7.5f), rng.chance(0.5f));
    }
  }
  s.end_zone();
}

/// Road markings on a road strip running along \p axis (0 = x, 2 = z) from a0 to a1, centred
/// at c across, half width hw: a dashed centre line (or lane lines) and zebra crossings at
/// both ends.
template <class S>
void markings(S& s, int axis, float a0, float a1, float c, float hw, bool zebra, bool median) {
  auto rect = [&](float u0, float u1, float w0, float w1) {  // u along the road, w across
    if (axis == 0) floor_rect(s, u0, u1, w0, w1, kMarkY, kMarking);
    else floor_rect(s, w0, w1, u0, u1, kMarkY, kMarking);
  };
  const float z = zebra ? 4.5f : 0.5f;
  const float len = a1 - a0 - 2.0f * z;
  if (len > 3.0f) {
    const int n = static_cast<int>(len / 6.0f);
    const float step = len / static_cast<float>(std::max(n, 1));
    for (int k = 0; k < std::max(n, 1); ++k) {
      const float u = a0 + z + step * static_cast<float>(k) + 0.5f * (step - 3.0f);
      if (median) {
        rect(u, u + 3.0f, c - 5.5f - 0.08f, c - 5.5f + 0.08f);
        rect(u, u + 3.0f, c + 5.5f - 0.08f, c + 5.5f + 0.08f);
      } else {
        rect(u, u + 3.0f, c - 0.08f, c + 0.08f);
      }
    }
  }
  if (len > 3.0f) {  // solid edge lines along both curbs
    rect(a0 + z, a1 - z, c - hw + 0.25f, c - hw + 0.4f);
    rect(a0 + z, a1 - z, c + hw - 0.4f, c + hw - 0.25f);
  }
  if (!zebra) return;
  const int stripes = static_cast<int>((2.0f * hw - 0.6f) / 1.0f);
  for (int e = 0; e < 2; ++e) {
    const float u0 = e == 0 ? a0 + 0.8f : a1 - 3.8f;
    for (int k = 0; k < stripes; ++k) {
      const float w = c - hw + 0.5f + static_cast<float>(k) * 1.0f;
      rect(u0, u0 + 3.0f, w, w + 0.5f);
    }
  }
}

template <class S>
void street_zones(S& s, const Layout& L, const Detail& d) {
  const int g = L.g;
  const bool zebra = d.props() >= 0.5f;
  // Streets along z (x-lines): the road runs through the intersections.
  for (int k = 0; k <= g; ++k) {
    if (k == L.canal) continue;
    s.begin_zone("street_x", k);
    const float r0 = L.road_x0(k), r1 = L.road_x1(k), c = L.xc(k);
    for (int m = 0; m <= g; ++m) {
      const float a0 = std::max(L.zl[static_cast<size_t>(m)], L.Z0);
      const float a1 = std::min(L.zl[static_cast<size_t>(m)] + L.zw[static_cast<size_t>(m)], L.Z1);
      floor_rect(s, r0, r1, a0, a1, 0.0f, kWetRoad);
      if (m < g) {
        floor_rect(s, r0, r1, L.bz0(m), L.bz1(m), 0.0f, kWetRoad);
        markings(s, 2, L.bz0(m), L.bz1(m), c, 0.5f * (r1 - r0), zebra, false);
      }
    }
    s.end_zone();
  }
  // Streets along x (z-lines): segments between the x-line roads; the canal interrupts them
  // except at the bridge (its own zone).
  for (int m = 0; m <= g; ++m) {
    s.begin_zone("street_z", m);
    const float r0 = L.road_z0(m), r1 = L.road_z1(m), c = L.zc(m);
    for (int k = 0; k < g; ++k) {
      // Between two x-line roads (next to the canal: up to its quay).
      floor_rect(s, L.road_x1(k), L.road_x0(k + 1), r0, r1, 0.0f, kWetRoad);
      markings(s, 0, L.bx0(k), L.bx1(k), c, 0.5f * (r1 - r0), zebra && m != L.viaduct, m == L.viaduct);
    }
    s.end_zone();
  }
}

/// The canal: quays, walls, bottom, water, parapets, trees and lamps on the quays; one zone per
/// stretch between two street lines and per crossing.
template <class S>
void canal_zones(S& s, const Layout& L, const Detail& d, const Templates& T, std::vector<Vec3>& lights) {
  const int g = L.g;
  const float c0 = L.xl[static_cast<size_t>(L.canal)], c1 = c0 + L.xw[static_cast<size_t>(L.canal)];
  const float q0 = c0 + kSidewalk, q1 = q0 + kQuay;  // west quay
  const float e1 = c1 - kSidewalk, e0 = e1 - kQuay;  // east quay
  int zone = 0;
  for (int m = 0; m <= g; ++m)
    for (int part = 0; part < 2; ++part) {
      if (part == 1 && m == g) break;
      float a0, a1;
      if (part == 0) {
        a0 = std::max(L.zl[static_cast<size_t>(m)], L.Z0);
        a1 = std::min(L.zl[static_cast<size_t>(m)] + L.zw[static_cast<size_t>(m)], L.Z1);
      } else {
        a0 = L.bz0(m);
        a1 = L.bz1(m);
      }
      s.begin_zone("canal", zone++);
      const bool bridge = part == 0 && m == L.bridge;
      // Quays (a gap for the bridge road) and the parapets along the water.
      auto quays = [&](float z0, float z1, bool parapet) {
        wbox(s, {q0, 0.0f, z0}, {q1, kCurb, z1}, kPavement, kNoBottom);
        wbox(s, {e0, 0.0f, z0}, {e1, kCurb, z1}, kPavement, kNoBottom);
        if (!parapet) return;
        wbox(s, {q1 - 0.35f, kCurb, z0}, {q1, kCurb + 0.9f, z1}, kBridgeStone, kNoBottom);
        wbox(s, {e0, kCurb, z0}, {e0 + 0.35f, kCurb + 0.9f, z1}, kBridgeStone, kNoBottom);
      };
      if (bridge) {
        quays(a0, L.road_z0(m), false);
        quays(L.road_z1(m), a1, false);
      } else {
        quays(a0, a1, true);
      }
      // Channel walls (facing the water), bottom and water surface.
      oquad(s, Vec3{q1, kCanalBottom, a0}, Vec3{q1, kCanalBottom, a1}, Vec3{q1, 0.0f, a1}, Vec3{q1, 0.0f, a0}, {1, 0, 0}, kConcrete);
      oquad(s, Vec3{e0, kCanalBottom, a0}, Vec3{e0, kCanalBottom, a1}, Vec3{e0, 0.0f, a1}, Vec3{e0, 0.0f, a0}, {-1, 0, 0}, kConcrete);
      floor_rect(s, q1, e0, a0, a1, kCanalBottom, kMud);
      floor_rect(s, q1, e0, a0, a1, kWaterY, kCanalWater);
      if (a0 == L.Z0)
        oquad(s, Vec3{q1, kCanalBottom, a0}, Vec3{e0, kCanalBottom, a0}, Vec3{e0, 0.0f, a0}, Vec3{q1, 0.0f, a0}, {0, 0, 1}, kConcrete);
      if (a1 == L.Z1)
        oquad(s, Vec3{q1, kCanalBottom, a1}, Vec3{e0, kCanalBottom, a1}, Vec3{e0, 0.0f, a1}, Vec3{q1, 0.0f, a1}, {0, 0, -1}, kConcrete);
      // Trees and lamps along the quays.
      if (part == 1) {
        const int n = static_cast<int>(4.0f * d.props());
        Rng rng(seed_of(2, m, 0));
        for (int t = 0; t < n; ++t) {
          const float z = a0 + (a1 - a0) * (static_cast<float>(t) + 0.5f) / static_cast<float>(n);
          tree(s, T, {c0 + 1.4f, kCurb, z}, rng.range(6.0f, 8.0f), rng.chance(0.5f));
          tree(s, T, {c1 - 1.4f, kCurb, z + 2.0f}, rng.range(6.0f, 8.0f), rng.chance(0.5f));
        }
        const Vec3 lw = street_lamp(s, {q1 - 0.6f, kCurb, 0.5f * (a0 + a1)}, {1, 0, 0}, 5.0f, 0.8f);
        street_lamp(s, {e0 + 0.6f, kCurb, 0.5f * (a0 + a1) + 6.0f}, {-1, 0, 0}, 5.0f, 0.8f);
        if (m == L.bridge) lights.push_back(lw);
      }
      s.end_zone();
    }
}

/// The stone bridge carrying z-line L.bridge over the canal: a flat segmental arch, road,
/// sidewalks, balustrades and four lamps.
template <class S>
void bridge_zone(S& s, const Layout& L, const Detail& d, std::vector<Vec3>& lights) {
  s.begin_zone("bridge");
  const float c0 = L.xl[static_cast<size_t>(L.canal)], c1 = c0 + L.xw[static_cast<size_t>(L.canal)];
  const float w0 = c0 + kSidewalk + kQuay, w1 = c1 - kSidewalk - kQuay;  // channel
  const int m = L.bridge;
  const float z0 = L.zl[static_cast<size_t>(m)], z1 = z0 + L.zw[static_cast<size_t>(m)];
  const float r0 = L.road_z0(m), r1 = L.road_z1(m);
  // Road over the quays and the channel, sidewalks over the channel.
  floor_rect(s, c0 + kSidewalk, c1 - kSidewalk, r0, r1, 0.0f, kWetRoad);
  markings(s, 0, c0 + kSidewalk, c1 - kSidewalk, L.zc(m), 0.5f * (r1 - r0), false, false);
  wbox(s, {w0, 0.0f, z0}, {w1, kCurb, r0}, kPavement, kTop | kFront);
  wbox(s, {w0, 0.0f, r1}, {w1, kCurb, z1}, kPavement, kTop | kBack);
  // Arch: intrados from wall to wall (springing just above the water), spandrel faces.
  constexpr int kSeg = 16;
  const float span = w1 - w0, rise = 1.3f, spring = kWaterY + 0.3f;
  const float R = (0.25f * span * span + rise * rise) / (2.0f * rise);
  std::array<Vec3, kSeg + 1> arch;
  for (int i = 0; i <= kSeg; ++i) {
    const float x = w0 + span * static_cast<float>(i) / static_cast<float>(kSeg);
    const float dx = x - 0.5f * (w0 + w1);
    arch[static_cast<size_t>(i)] = {x, spring + std::sqrt(R * R - dx * dx) - (R - rise), 0.0f};
  }
  for (int i = 0; i < kSeg; ++i) {
    const Vec3 a = arch[static_cast<size_t>(i)], b = arch[static_cast<size_t>(i) + 1];
    oquad(s, Vec3{a.x, a.y, z0}, Vec3{b.x, b.y, z0}, Vec3{b.x, b.y, z1}, Vec3{a.x, a.y, z1}, {0, -1, 0}, kBridgeStone);
    oquad(s, Vec3{a.x, a.y, z0}, Vec3{b.x, b.y, z0}, Vec3{b.x, kCurb, z0}, Vec3{a.x, kCurb, z0}, {0, 0, -1}, kBridgeStone);
    oquad(s, Vec3{a.x, a.y, z1}, Vec3{b.x, b.y, z1}, Vec3{b.x, kCurb, z1}, Vec3{a.x, kCurb, z1}, {0, 0, 1}, kBridgeStone);
  }
  // Arch ring (voussoir band) standing proud of the spandrels.
  for (int i = 0; i < kSeg; ++i) {
    const Vec3 a = arch[static_cast<size_t>(i)], b = arch[static_cast<size_t>(i) + 1];
    for (float z : {z0, z1}) {
      const float o = z == z0 ? -0.12f : 0.12f;
      oquad(s, Vec3{a.x, a.y, z + o}, Vec3{b.x, b.y, z + o}, Vec3{b.x, b.y + 0.7f, z + o}, Vec3{a.x, a.y + 0.7f, z + o},
            {0, 0, o}, kConcrete);
      oquad(s, Vec3{a.x, a.y, z}, Vec3{b.x, b.y, z}, Vec3{b.x, b.y, z + o}, Vec3{a.x, a.y, z + o}, {0, -1, 0}, kConcrete);
      oquad(s, Vec3{a.x, a.y + 0.7f, z}, Vec3{b.x, b.y + 0.7f, z}, Vec3{b.x, b.y + 0.7f, z + o},
            Vec3{a.x, a.y + 0.7f, z + o}, {0, 1, 0}, kConcrete);
    }
  }
  // Balustrades: posts and a handrail on both sides, from quay parapet to quay parapet.
  for (float zz : {z0 + 0.2f, z1 - 0.2f}) {
    const int n = static_cast<int>(span / (d.props() < 0.5f ? 3.0f : 0.9f));
    for (int i = 0; i <= n; ++i) {
      const float x = w0 + span * static_cast<float>(i) / static_cast<float>(n);
      wbox(s, {x - 0.08f, kCurb, zz - 0.08f}, {x + 0.08f, kCurb + 0.85f, zz + 0.08f}, kBridgeStone,
           kLeft | kRight | kFront | kBack);
    }
    wbox(s, {w0 - 0.35f, kCurb + 0.85f, zz - 0.17f}, {w1 + 0.35f, kCurb + 1.0f, zz + 0.17f}, kBridgeStone, kAllFaces);
    wbox(s, {w0 - 0.35f, kCurb, zz - 0.2f}, {w0, kCurb + 0.85f, zz + 0.2f}, kBridgeStone, kNoBottom);
    wbox(s, {w1, kCurb, zz - 0.2f}, {w1 + 0.35f, kCurb + 0.85f, zz + 0.2f}, kBridgeStone, kNoBottom);
  }
  // Lamps on the four corners.
  for (float x : {w0 + 0.4f, w1 - 0.4f})
    for (float zz : {z0 + 0.6f, z1 - 0.6f}) {
      const Vec3 l = street_lamp(s, {x, kCurb, zz}, zz < L.zc(m) ? Vec3{0, 0, 1} : Vec3{0, 0, -1}, 4.5f, 0.6f);
      if (x < L.xc(L.canal) && zz > L.zc(m)) lights.push_back(l);
    }
  s.end_zone();
}

/// The elevated road along z-line L.viaduct: deck, girders, barriers, pillars on the median
/// with pier caps, lamps under the deck and ramps beyond the city. Streets crossing it pass
/// underneath (the underpass).
template <class S>
void underpass_zone(S& s, const Layout& L, std::vector<Vec3>& lights, int light_line) {
  s.begin_zone("underpass");
  const int m = L.viaduct;
  const float zc = L.zc(m), d0 = zc - kDeckHalf, d1 = zc + kDeckHalf;
  // Deck segments: one per line corridor and per block (keeps triangles short).
  std::vector<float> xs;
  for (int k = 0; k <= L.g; ++k) {
    xs.push_back(L.xl[static_cast<size_t>(k)]);
    xs.push_back(L.xl[static_cast<size_t>(k)] + L.xw[static_cast<size_t>(k)]);
  }
  constexpr float kRamp = 90.0f, kLevel = 25.0f;
  xs.front() -= kLevel;
  xs.back() += kLevel;
  auto deck = [&](float a0, float a1, float y0a, float y0b, bool girders) {
    // Constant-thickness deck between a0 and a1, bottom height from y0a to y0b.
    const float t = kDeckTop - kDeckBottom;
    auto P = [](float x, float y, float z) { return Vec3{x, y, z}; };
    oquad(s, P(a0, y0a + t, d0), P(a1, y0b + t, d0), P(a1, y0b + t, d1), P(a0, y0a + t, d1), {0, 1, 0}, kWetRoad);
    oquad(s, P(a0, y0a, d0), P(a1, y0b, d0), P(a1, y0b, d1), P(a0, y0a, d1), {0, -1, 0}, kConcrete);
    oquad(s, P(a0, y0a, d0), P(a1, y0b, d0), P(a1, y0b + t, d0), P(a0, y0a + t, d0), {0, 0, -1}, kConcrete);
    oquad(s, P(a0, y0a, d1), P(a1, y0b, d1), P(a1, y0b + t, d1), P(a0, y0a + t, d1), {0, 0, 1}, kConcrete);
    // Barriers on top.
    for (float z : {d0, d1 - 0.3f}) {
      oquad(s, P(a0, y0a + t + 1.0f, z), P(a1, y0b + t + 1.0f, z), P(a1, y0b + t + 1.0f, z + 0.3f),
            P(a0, y0a + t + 1.0f, z + 0.3f), {0, 1, 0}, kConcrete);
      oquad(s, P(a0, y0a + t, z), P(a1, y0b + t, z), P(a1, y0b + t + 1.0f, z), P(a0, y0a + t + 1.0f, z), {0, 0, -1}, kConcrete);
      oquad(s, P(a0, y0a + t, z + 0.3f), P(a1, y0b + t, z + 0.3f), P(a1, y0b + t + 1.0f, z + 0.3f),
            P(a0, y0a + t + 1.0f, z + 0.3f), {0, 0, 1}, kConcrete);
    }
    if (!girders) return;
    for (float z : {zc - 4.5f, zc + 4.5f})
      lbox(s, kWorld, a0, a1, kGirderBottom, kDeckBottom, z - 0.35f, z + 0.35f, kConcrete, kBottom | kFront | kBack);
  };
  for (size_t k = 0; k + 1 < xs.size(); ++k) deck(xs[k], xs[k + 1], kDeckBottom, kDeckBottom, true);
  deck(xs.front() - kRamp, xs.front(), -0.8f, kDeckBottom, false);
  deck(xs.back(), xs.back() + kRamp, kDeckBottom, -0.8f, false);
  // End caps of the girders.
  for (float z : {zc - 4.5f, zc + 4.5f}) {
    lbox(s, kWorld, xs.front() - 0.01f, xs.front(), kGirderBottom, kDeckBottom, z - 0.35f, z + 0.35f, kConcrete, kLeft);
    lbox(s, kWorld, xs.back(), xs.back() + 0.01f, kGirderBottom, kDeckBottom, z - 0.35f, z + 0.35f, kConcrete, kRight);
  }
  // Median with pillars and pier caps along each block; lamps under the deck.
  for (int i = 0; i < L.g; ++i) {
    const float a0 = L.bx0(i) - kSidewalk, a1 = L.bx1(i) + kSidewalk;
    wbox(s, {a0, 0.0f, zc - 1.0f}, {a1, 0.2f, zc + 1.0f}, kConcrete, kNoBottom);
    for (int p = 0; p < 3; ++p) {
      const float x = L.bx0(i) + kBlock * (static_cast<float>(p) + 0.5f) / 3.0f;
      wbox(s, {x - 0.6f, 0.2f, zc - 0.6f}, {x + 0.6f, 4.4f, zc + 0.6f}, kConcrete, kLeft | kRight | kFront | kBack);
      wbox(s, {x - 0.8f, 4.4f, zc - 5.2f}, {x + 0.8f, kGirderBottom, zc + 5.2f}, kConcrete, kAllFaces);
    }
  }
  for (int k = 0; k <= L.g; ++k) {
    if (k == L.canal) continue;
    const float x = L.xc(k);
    for (float z : {zc - 2.0f, zc + 2.0f})
      wbox(s, {x - 0.6f, kDeckBottom - 0.12f, z - 0.25f}, {x + 0.6f, kDeckBottom, z + 0.25f}, kLampLight, kBottom);
    if (k == light_line) lights.push_back({x, kGirderBottom - 0.5f, zc});
  }
  s.end_zone();
}

/// The plaza: a paved square with lawns, trees, benches, lamps and a fountain with a chrome ball.
template <class S>
void plaza_zone(S& s, const Layout& L, const Detail& d, const Templates& T, std::vector<Vec3>& lights) {
  s.begin_zone("plaza");
  const float x0 = L.bx0(L.plaza_i), x1 = L.bx1(L.plaza_i), z0 = L.bz0(L.plaza_j), z1 = L.bz1(L.plaza_j);
  const float cx = 0.5f * (x0 + x1), cz = 0.5f * (z0 + z1), h = 0.5f * (x1 - x0);
  wbox(s, {x0 - kSidewalk, 0.0f, z0 - kSidewalk}, {x1 + kSidewalk, kCurb, z1 + kSidewalk}, kPavement, kNoBottom);
  const int tiles = d.props() < 0.5f ? 4 : 14;
  s.checker({cx, kCurb + 0.01f, cz}, {0, 0, h - 1.0f}, {h - 1.0f, 0, 0}, tiles, tiles, kPavement, kBridgeStone);
  const float y = kCurb + 0.01f;
  // Lawns in the four corners, each with trees.
  const int trees = d.props() < 0.5f ? 1 : 3;
  Rng rng(seed_of(3, 0, 0));
  for (int qx = 0; qx < 2; ++qx)
    for (int qz = 0; qz < 2; ++qz) {
      const float lx0 = qx == 0 ? x0 + 2.0f : cx + 7.0f, lx1 = qx == 0 ? cx - 7.0f : x1 - 2.0f;
      const float lz0 = qz == 0 ? z0 + 2.0f : cz + 7.0f, lz1 = qz == 0 ? cz - 7.0f : z1 - 2.0f;
      wbox(s, {lx0, y, lz0}, {lx1, y + 0.25f, lz1}, kGrass, kNoBottom);
      for (int t = 0; t < trees; ++t) {
        const float f = (static_cast<float>(t) + 0.5f) / static_cast<float>(trees);
        tree(s, T, {lx0 + (lx1 - lx0) * f, y + 0.25f, lz0 + (lz1 - lz0) * (1.0f - f)}, rng.range(6.0f, 9.0f),
             rng.chance(0.5f));
      }
      bench(s, {0.5f * (lx0 + lx1), y, qz == 0 ? lz1 + 1.2f : lz0 - 1.2f}, true);
    }
  // Fountain: an octagonal basin, water, a pedestal and a chrome ball.
  const Vec3 c{cx, y, cz};
  oct_prism(s, c, 5.0f, y, y + 0.6f, kBridgeStone, kBridgeStone, false);
  for (int k = 0; k < 8; ++k) {  // basin rim (cap ring) and inner wall
    const int l = (k + 1) % 8;
    const Vec3 o0{cx + 5.0f * kOct[k][0], y + 0.6f, cz + 5.0f * kOct[k][1]}, o1{cx + 5.0f * kOct[l][0], y + 0.6f, cz + 5.0f * kOct[l][1]};
    const Vec3 i0{cx + 4.6f * kOct[k][0], y + 0.6f, cz + 4.6f * kOct[k][1]}, i1{cx + 4.6f * kOct[l][0], y + 0.6f, cz + 4.6f * kOct[l][1]};
    oquad(s, o0, o1, i1, i0, {0, 1, 0}, kBridgeStone);
    const Vec3 in{-(kOct[k][0] + kOct[l][0]), 0, -(kOct[k][1] + kOct[l][1])};
    oquad(s, i0, i1, Vec3{i1.x, y + 0.1f, i1.z}, Vec3{i0.x, y + 0.1f, i0.z}, in, kBridgeStone);
  }
  auto octagon = [&](float r, float yy, uint32_t mat) {
    Vec3 v[8];
    for (int k = 0; k < 8; ++k) v[k] = {cx + r * kOct[k][0], yy, cz + r * kOct[k][1]};
    oquad(s, v[0], v[1], v[2], v[3], {0, 1, 0}, mat);
    oquad(s, v[0], v[3], v[4], v[7], {0, 1, 0}, mat);
    oquad(s, v[4], v[5], v[6], v[7], {0, 1, 0}, mat);
  };
  octagon(4.6f, y + 0.1f, kMud);
  octagon(4.6f, y + 0.45f, kCanalWater);
  wbox(s, {cx - 0.7f, y + 0.1f, cz - 0.7f}, {cx + 0.7f, y + 2.2f, cz + 0.7f}, kBridgeStone, kNoBottom);
  s.mesh(d.props() < 0.5f ? T.small_ball : T.ball, {cx, y + 3.2f, cz}, {1.0f, 1.0f, 1.0f}, kChrome);
  // Lamps on the square; the one by the fountain carries a point light.
  const Vec3 lp = street_lamp(s, {cx + 6.5f, y, cz + 6.5f}, {-1, 0, 0}, 5.0f, 0.9f);
  lights.push_back(lp);
  street_lamp(s, {cx - 6.5f, y, cz - 6.5f}, {1, 0, 0}, 5.0f, 0.9f);
  s.end_zone();
}

template <class S>
void ground_zone(S& s, const Layout& L) {
  s.begin_zone("ground");
  constexpr float far = 2500.0f;
  floor_rect(s, -far, far, -far, L.Z0, 0.0f, kGround);
  floor_rect(s, -far, far, L.Z1, far, 0.0f, kGround);
  floor_rect(s, -far, L.X0, L.Z0, L.Z1, 0.0f, kGround);
  floor_rect(s, L.X1, far, L.Z0, L.Z1, 0.0f, kGround);
  s.end_zone();
}

struct CityLights {
  std::vector<Vec3> points;
};

template <class S>
void emit_city(S& s, const Layout& L, const Detail& d, const Templates& T, CityLights& lights) {
  std::vector<Opening> holes;
  holes.reserve(64);
  ground_zone(s, L);
  street_zones(s, L, d);
  canal_zones(s, L, d, T, lights.points);
  bridge_zone(s, L, d, lights.points);
  underpass_zone(s, L, lights.points, L.canal + 1);
  plaza_zone(s, L, d, T, lights.points);
  for (int j = 0; j < L.g; ++j)
    for (int i = 0; i < L.g; ++i)
      if (!(i == L.plaza_i && j == L.plaza_j)) block_zone(s, L, i, j, d, T, holes);
}

uint64_t count_city(const Layout& L, const Detail& d, const Templates& T) {
  CountSink c;
  CityLights lights;
  emit_city(c, L, d, T, lights);
  return c.triangles;
}

/// Grid size and detail factor whose triangle count is closest to \p target.
void size_city(uint64_t target, const Templates& T, Layout& L, Detail& d) {
  const double per_block = 9000.0;
  const int g = static_cast<int>(std::clamp<long>(std::lround(std::sqrt(static_cast<double>(target) / per_block)), 4L, 120L));
  L = make_layout(g);
  // Bisection on log(k): the count never decreases with k.
  float lo = 0.03f, hi = 16.0f;
  Detail best{1.0f};
  uint64_t best_err = UINT64_MAX;
  for (int it = 0; it < 16; ++it) {
    const Detail mid{std::sqrt(lo * hi)};
    const uint64_t n = count_city(L, mid, T);
    const uint64_t err = n > target ? n - target : target - n;
    if (err < best_err) best_err = err, best = mid;
    if (n > target) hi = mid.k;
    else lo = mid.k;
    if (static_cast<double>(err) < 0.01 * static_cast<double>(target)) break;
  }
  d = best;
}

}  // namespace

std::optional<uint64_t> parse_city_spec(const std::string& spec) {
  if (spec == "city") return kCityDefaultTriangles;
  if (spec.rfind("city:", 0) != 0) return std::nullopt;
  const std::string n = spec.substr(5);
  const std::string range = "between " + std::to_string(kCityMinTriangles) + " and " + std::to_string(kCityMaxTriangles);
  bool digits = !n.empty();
  for (char ch : n) digits = digits && ch >= '0' && ch <= '9';
  if (!digits)
    throw Error("scene '" + spec + "': the city size must be a whole number of triangles " + range +
                " (e.g. city:50000)");
  uint64_t v = 0;
  for (char ch : n) {
    v = v * 10 + static_cast<uint64_t>(ch - '0');
    if (v > kCityMaxTriangles) break;
  }
  if (v < kCityMinTriangles || v > kCityMaxTriangles)
    throw Error("scene '" + spec + "': city size " + (v > kCityMaxTriangles ? std::string("too large") : n) +
                " is out of range: ask for " + range + " triangles");
  return v;
}

Scene make_city(const LoadOptions& /*options*/) { return make_city_with_triangles(kCityDefaultTriangles); }

Scene make_city_with_triangles(uint64_t target) {
  if (target < kCityMinTriangles || target > kCityMaxTriangles)
    throw Error("city: " + std::to_string(target) + " triangles is out of range [" + std::to_string(kCityMinTriangles) +
                ", " + std::to_string(kCityMaxTriangles) + "]");
  const Templates T;
  Layout L;
  Detail d;
  size_city(target, T, L, d);

  Scene s;
  add_materials(s);
  CountSink count;
  CityLights lights;
  emit_city(count, L, d, T, lights);
  SceneSink sink(s, count.vertices, count.triangles);
  lights.points.clear();
  emit_city(sink, L, d, T, lights);
  if (!sink.complete()) throw Error("city: triangle count mismatch");

  // Lights: a low afternoon sun and the street lamps near the cameras.
  Light sun;
  sun.name = "sun";
  sun.type = LightType::Directional;
  sun.direction = normalize(Vec3{0.3f, -0.7f, -0.65f});  // from the south-west, behind the street camera
  sun.color = {1.0f, 0.9f, 0.75f};
  sun.intensity = 1.1f;
  s.lights.push_back(sun);
  // The street camera's lamp: the first lamp on the west side of the block it stands by.
  const int sx = L.canal - 1;
  Vec3 p, dir;
  block_lamp(L, sx, L.bridge, 3, 0, p, dir);
  lights.points.push_back(p + dir * 1.3f + Vec3{0, 6.0f - 0.5f, 0});
  for (size_t i = 0; i < lights.points.size(); ++i) {
    Light l;
    l.name = "lamp_" + std::to_string(i);
    l.type = LightType::Point;
    l.position = lights.points[i];
    l.color = {1.0f, 0.82f, 0.6f};
    l.intensity = 22.0f;
    s.lights.push_back(l);
  }

  const auto camera = [&s](const char* name, Vec3 pos, Vec3 look_at, float vfov) { add_camera(s, name, pos, look_at, vfov); };
  // street: eye height in the x-line west of the canal, looking north along the street.
  const float xs = L.xc(sx), zs = L.bz1(L.bridge) - 8.0f;
  camera("street", {xs + 1.5f, 1.7f, zs}, {xs - 0.5f, 3.5f, zs - 60.0f}, 55.0f);
  // underpass: in the x-line east of the canal, just before the elevated road, looking through.
  const float xu = L.xc(L.canal + 1), zv = L.zc(L.viaduct);
  camera("underpass", {xu - 2.0f, 1.7f, zv - kDeckHalf - 12.0f}, {xu + 0.5f, 3.2f, zv + 40.0f}, 60.0f);
  // bridge: above the canal south of the bridge, looking along the water at the bridge.
  const float xcn = L.xc(L.canal), zb = L.zc(L.bridge);
  camera("bridge", {xcn - 1.5f, 2.6f, zb + 32.0f}, {xcn + 0.5f, -1.0f, zb - 10.0f}, 50.0f);
  // plaza: the square from above at an angle.
  const float px1 = L.bx1(L.plaza_i), pz1 = L.bz1(L.plaza_j);
  camera("plaza", {px1 + 14.0f, 21.0f, pz1 + 16.0f},
         {0.5f * (L.bx0(L.plaza_i) + px1), 3.0f, 0.5f * (L.bz0(L.plaza_j) + pz1)}, 55.0f);

  s.sky.type = SkyType::Gradient;
  s.sky.color = {0.2f, 0.33f, 0.62f};
  s.sky.horizon = {0.7f, 0.66f, 0.62f};
  s.sky.intensity = 1.0f;
  s.ambient = {0.2f, 0.2f, 0.22f};
  return s;
}

}  // namespace specula::builtin
