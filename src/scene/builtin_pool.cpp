// Built-in scene "pool": the Stanford bunny half submerged in a tiled pool (seed 000, 1.5)
// (owner: render). Units are metres: the basin is 4 m x 3 m x 1 m deep, its rim is at y = 0,
// the water surface at y = kWater, the bunny (1.5 m tall) stands on the floor.
#include <cmath>
#include <filesystem>
#include <string>

#include "scene/builtin_geometry.h"
#include "scene/builtin_scenes.h"
#include "specula/error.h"

namespace specula::builtin {

namespace {

constexpr float kHalfX = 2.0f, kHalfZ = 1.5f, kDepth = 1.0f;
constexpr float kWater = -0.22f;        // water level
constexpr float kBunnyHeight = 1.5f;
constexpr float kBunnyX = -0.5f;       // bunny base centre (x); z = 0
constexpr float kDeck = 7.0f;           // half size of the deck around the pool
constexpr float kTile = 0.25f;          // pool tile size

/// Adds the bunny mesh (or a stand-in) standing on the pool floor; returns false for the
/// stand-in.
bool add_bunny(Scene& s, uint32_t material, const LoadOptions& options,
               const std::filesystem::path& path) {
  const std::string file = kBunnyFile;
  if (!path.empty()) {
    const Scene mesh = load_obj(path, options);
    const Aabb b = mesh.bounds();
    if (b.empty() || !(b.extent().y > 0.0f)) throw file_error(path.string(), "bunny mesh is empty");
    const float scale = kBunnyHeight / b.extent().y;
    // Base centre to the origin, scale, turn so the bunny shows its side to the "bunny"
    // camera, put it on the floor slightly left of the pool centre.
    const Vec3 base{b.center().x, b.min.y, b.center().z};
    const Mat4 xf = Mat4::translate({kBunnyX, -kDepth, 0.0f}) * Mat4::rotate({0, 1, 0}, 0.35f) *
                    Mat4::scale(Vec3{scale}) * Mat4::translate(-base);
    MeshBuilder m;
    m.positions = mesh.positions;
    m.indices = mesh.indices;
    if (mesh.normals.size() == mesh.positions.size()) m.normals = mesh.normals;
    else m.normals = compute_vertex_normals(mesh.positions, mesh.indices);
    m.transform(xf);  // normals by the inverse transpose
    m.add_to(s, "bunny", material);
    return true;
  }
  const std::string msg = file + " not found (searched: " +
                          (options.data.describe().empty() ? std::string("nothing") : options.data.describe()) +
                          "); the pool uses a procedural stand-in";
  if (options.warn) options.warn(msg);
  // Stand-in of the bunny's size: a body ellipsoid and a head.
  MeshBuilder body = icosphere({0, 0, 0}, 1.0f, 4);
  body.transform(Mat4::translate({kBunnyX, -kDepth + 0.5f, 0.0f}) * Mat4::scale({0.75f, 0.5f, 0.55f}));
  MeshBuilder head = icosphere({0, 0, 0}, 1.0f, 3);
  head.transform(Mat4::translate({kBunnyX - 0.5f, -kDepth + 1.15f, 0.0f}) * Mat4::scale({0.3f, 0.35f, 0.28f}));
  body.append(head);
  body.add_to(s, "bunny_stand_in", material);
  return false;
}

}  // namespace

Scene make_pool(const LoadOptions& options) {
  return make_pool_with_bunny(options, options.data.find(kBunnyFile));
}

Scene make_pool_with_bunny(const LoadOptions& options, const std::filesystem::path& bunny_path) {
  Scene s;
  Material tile_a;
  tile_a.name = "pool_tile_light";
  tile_a.diffuse = {0.78f, 0.88f, 0.92f};
  tile_a.specular = {0.25f, 0.25f, 0.25f};
  tile_a.phong_exponent = 60.0f;
  Material tile_b = tile_a;
  tile_b.name = "pool_tile_blue";
  tile_b.diffuse = {0.12f, 0.42f, 0.62f};
  Material deck_a;
  deck_a.name = "deck_stone";
  deck_a.diffuse = {0.66f, 0.6f, 0.5f};
  deck_a.specular = {0.05f, 0.05f, 0.05f};
  deck_a.phong_exponent = 16.0f;
  Material deck_b = deck_a;
  deck_b.name = "deck_stone_dark";
  deck_b.diffuse = {0.55f, 0.5f, 0.42f};
  Material water;
  water.name = "water";
  water.diffuse = {0.1f, 0.35f, 0.4f};
  water.specular = {1.0f, 1.0f, 1.0f};
  water.phong_exponent = 400.0f;
  water.transparency = 1.0f;
  water.ior = 1.33f;
  water.absorption = {0.5f, 0.14f, 0.1f};  // red goes first: clear blue-green water
  Material bunny;
  bunny.name = "bunny";
  bunny.diffuse = {0.74f, 0.67f, 0.58f};
  bunny.specular = {0.15f, 0.15f, 0.15f};
  bunny.phong_exponent = 30.0f;

  const uint32_t m_tile_a = s.add_material(tile_a), m_tile_b = s.add_material(tile_b),
                 m_deck_a = s.add_material(deck_a), m_deck_b = s.add_material(deck_b),
                 m_water = s.add_material(water), m_bunny = s.add_material(bunny);

  // Pool basin: tiled floor and four inner walls (facing into the pool), checkerboard tiles.
  MeshBuilder ta, tb;
  const int nx = static_cast<int>(std::lround(2.0f * kHalfX / kTile));
  const int nz = static_cast<int>(std::lround(2.0f * kHalfZ / kTile));
  const int ny = static_cast<int>(std::lround(kDepth / kTile));
  const float hy = 0.5f * kDepth, cy = -0.5f * kDepth;
  checker_quads(ta, tb, {0, -kDepth, 0}, {0, 0, kHalfZ}, {kHalfX, 0, 0}, nz, nx);         // floor +y
  checker_quads(ta, tb, {0, cy, -kHalfZ}, {kHalfX, 0, 0}, {0, hy, 0}, nx, ny);            // back, +z
  checker_quads(ta, tb, {0, cy, kHalfZ}, {0, hy, 0}, {kHalfX, 0, 0}, ny, nx);             // front, -z
  checker_quads(ta, tb, {-kHalfX, cy, 0}, {0, hy, 0}, {0, 0, kHalfZ}, ny, nz);            // left, +x
  checker_quads(ta, tb, {kHalfX, cy, 0}, {0, 0, kHalfZ}, {0, hy, 0}, nz, ny);             // right, -x
  ta.add_to(s, "pool_tiles_light", m_tile_a);
  tb.add_to(s, "pool_tiles_blue", m_tile_b);

  // Deck around the pool at y = 0: four slabs of large stone tiles framing the hole.
  MeshBuilder da, db;
  const float w = 0.5f * (kDeck - kHalfX), d = 0.5f * (kDeck - kHalfZ);
  const int n_long = 14, n_x = 5, n_z = 5;
  checker_quads(da, db, {0, 0, -(kHalfZ + d)}, {0, 0, d}, {kDeck, 0, 0}, n_z, n_long);   // back
  checker_quads(da, db, {0, 0, kHalfZ + d}, {0, 0, d}, {kDeck, 0, 0}, n_z, n_long);      // front
  checker_quads(da, db, {-(kHalfX + w), 0, 0}, {0, 0, kHalfZ}, {w, 0, 0}, 3, n_x);       // left
  checker_quads(da, db, {kHalfX + w, 0, 0}, {0, 0, kHalfZ}, {w, 0, 0}, 3, n_x);          // right
  da.add_to(s, "deck", m_deck_a);
  db.add_to(s, "deck_dark", m_deck_b);

  // Water surface: a gently rippled height field spanning the basin, normals up (+y). Rays
  // entering it from above push the water medium; below it they see the basin and bunny.
  MeshBuilder wm;
  const int gx = 96, gz = 72;
  auto height = [](float x, float z) {
    return kWater + 0.006f * std::sin(7.0f * x + 2.0f * z) + 0.004f * std::sin(11.0f * z - 5.0f * x + 1.0f) +
           0.0025f * std::sin(19.0f * x + 17.0f * z + 2.0f);
  };
  auto normal_at = [](float x, float z) {
    const float dx = 0.006f * 7.0f * std::cos(7.0f * x + 2.0f * z) -
                     0.004f * 5.0f * std::cos(11.0f * z - 5.0f * x + 1.0f) +
                     0.0025f * 19.0f * std::cos(19.0f * x + 17.0f * z + 2.0f);
    const float dz = 0.006f * 2.0f * std::cos(7.0f * x + 2.0f * z) +
                     0.004f * 11.0f * std::cos(11.0f * z - 5.0f * x + 1.0f) +
                     0.0025f * 17.0f * std::cos(19.0f * x + 17.0f * z + 2.0f);
    return normalize(Vec3{-dx, 1.0f, -dz});
  };
  for (int j = 0; j <= gz; ++j)
    for (int i = 0; i <= gx; ++i) {
      const float x = -kHalfX + 2.0f * kHalfX * static_cast<float>(i) / static_cast<float>(gx);
      const float z = -kHalfZ + 2.0f * kHalfZ * static_cast<float>(j) / static_cast<float>(gz);
      wm.positions.push_back({x, height(x, z), z});
      wm.normals.push_back(normal_at(x, z));
    }
  for (int j = 0; j < gz; ++j)
    for (int i = 0; i < gx; ++i) {
      const auto a = static_cast<uint32_t>(j * (gx + 1) + i), b = a + static_cast<uint32_t>(gx + 1);
      // (x0,z0) (x0,z1) (x1,z1) / (x0,z0) (x1,z1) (x1,z0): counter-clockwise seen from above.
      for (uint32_t idx : {a, b, b + 1, a, b + 1, a + 1}) wm.indices.push_back(idx);
    }
  wm.add_to(s, "water", m_water);

  const bool real_bunny = add_bunny(s, m_bunny, options, bunny_path);

  Light sun;
  sun.name = "sun";
  sun.type = LightType::Directional;
  sun.direction = normalize(Vec3{-0.45f, -1.0f, -0.35f});
  sun.color = {1.0f, 0.96f, 0.88f};
  sun.intensity = 1.0f;
  s.lights.push_back(sun);

  const auto camera = [&s](const char* name, Vec3 pos, Vec3 target, float vfov) { add_camera(s, name, pos, target, vfov); };
  camera("overview", {3.6f, 2.6f, 4.4f}, {-0.2f, -0.45f, 0.0f}, 42.0f);
  // The whole screen is water (seed 000, figure 1.2): looking steeply down at the free half.
  camera("water", {1.15f, 1.2f, 0.45f}, {1.15f, kWater, -0.3f}, 35.0f);
  // The bunny from the side, filling the view (figure 1.3).
  camera("bunny", {-0.5f, 0.05f, 1.3f}, {-0.5f, -0.08f, 0.0f}, 45.0f);
  // Along the bunny's hollow inside (figure 1.4): from inside the shell near the tail,
  // looking along the back towards the head.
  camera("parallel", {-0.15f, -0.62f, -0.12f}, {-1.0f, -0.1f, 0.16f}, 75.0f);

  // A dim lamp inside the hollow bunny: the shell hides it from every point outside (its
  // shadow rays are blocked), so it only lights the "parallel" view of the inside.
  Light lamp;
  lamp.name = "bunny_lamp";
  lamp.type = LightType::Point;
  lamp.position = {kBunnyX + 0.16f, -0.5f, -0.02f};
  lamp.color = {1.0f, 0.85f, 0.7f};
  lamp.intensity = 0.06f;
  if (real_bunny) s.lights.push_back(lamp);

  s.sky.type = SkyType::Gradient;
  s.sky.color = {0.32f, 0.52f, 0.88f};
  s.sky.horizon = {0.85f, 0.9f, 0.96f};
  s.sky.intensity = 1.0f;
  s.ambient = {0.12f, 0.13f, 0.15f};
  return s;
}

}  // namespace specula::builtin
