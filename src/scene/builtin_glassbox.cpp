// Built-in scene "glassbox": seed 001's voxel test space rebuilt from triangle solids
// (owner: render). A cube of "radius" 1: its outer layer is a solid frame holding glass
// panes (87.5 % of the radius) with void holes (25 %) in their centres; the front (+z) has
// no pane; the interior is void except a semi-solid cube (12.5 %). A red light between the
// cube and the camera, a blue one to the left, a green one inside near the front bottom corner.
#include "scene/builtin_geometry.h"
#include "scene/builtin_scenes.h"

namespace specula::builtin {

Scene make_glassbox(const LoadOptions& /*options*/) {
  Scene s;
  // Materials after seed 001's table 1, mapped onto the reflect/transmit/local energy split.
  Material solid;
  solid.name = "solid";
  solid.diffuse = {0.78f, 0.76f, 0.72f};
  solid.specular = {0.5f, 0.5f, 0.5f};
  solid.phong_exponent = 32.0f;
  solid.reflectivity = 0.2f;
  Material glass;
  glass.name = "glass";
  glass.diffuse = {0.92f, 0.96f, 1.0f};
  glass.specular = {0.7f, 0.7f, 0.7f};
  glass.phong_exponent = 96.0f;
  glass.reflectivity = 0.05f;
  glass.transparency = 0.85f;
  glass.ior = 1.5f;
  glass.absorption = {0.15f, 0.08f, 0.05f};
  Material semi;
  semi.name = "semi_solid";
  semi.diffuse = {0.95f, 0.95f, 0.95f};
  semi.specular = {0.7f, 0.7f, 0.7f};
  semi.phong_exponent = 48.0f;
  semi.reflectivity = 0.15f;
  semi.transparency = 0.4f;
  semi.ior = 1.5f;
  semi.absorption = {1.5f, 1.5f, 1.5f};
  Material floor_a;
  floor_a.name = "floor_dark";
  floor_a.diffuse = {0.25f, 0.25f, 0.27f};
  floor_a.specular = {0.1f, 0.1f, 0.1f};
  floor_a.reflectivity = 0.05f;
  Material floor_b = floor_a;
  floor_b.name = "floor_light";
  floor_b.diffuse = {0.55f, 0.55f, 0.57f};

  const uint32_t m_solid = s.add_material(solid), m_glass = s.add_material(glass),
                 m_semi = s.add_material(semi), m_floor_a = s.add_material(floor_a),
                 m_floor_b = s.add_material(floor_b);

  constexpr float kLayer = 0.125f;  // one voxel of seed 001's 16^3 space
  constexpr float kPane = 0.875f, kHole = 0.25f, kCore = 0.125f;
  constexpr float kGap = 0.002f;  // keeps glass and frame faces from coinciding
  MeshBuilder frame, panes;
  for (int axis = 0; axis < 3; ++axis)
    for (float sign : {1.0f, -1.0f}) {
      const Mat4 xf = face_frame(axis, sign, 1.0f - 0.5f * kLayer);
      MeshBuilder f;
      f.square_ring(1.0f, kPane, 0.5f * kLayer);
      f.transform(xf);
      frame.append(f);
      if (axis == 2 && sign > 0) continue;  // open front
      MeshBuilder p;
      p.square_ring(kPane - kGap, kHole, 0.5f * kLayer - kGap);
      p.transform(xf);
      panes.append(p);
    }
  frame.add_to(s, "frame", m_solid);
  panes.add_to(s, "glass_panes", m_glass);
  MeshBuilder core;
  core.box(Aabb{Vec3{-kCore}, Vec3{kCore}});
  core.add_to(s, "semi_solid_core", m_semi);

  MeshBuilder fa, fb;
  checker_quads(fa, fb, {0.0f, -1.35f, 0.0f}, {0, 0, 6.0f}, {6.0f, 0, 0}, 12, 12);
  fa.add_to(s, "floor_dark", m_floor_a);
  fb.add_to(s, "floor_light", m_floor_b);

  auto point = [&s](const char* name, Vec3 pos, Vec3 colour, float intensity) {
    Light l;
    l.name = name;
    l.type = LightType::Point;
    l.position = pos;
    l.color = colour;
    l.intensity = intensity;
    s.lights.push_back(l);
  };
  point("red", {0.35f, 0.45f, 2.0f}, {1.0f, 0.18f, 0.12f}, 2.2f);
  point("blue", {-3.0f, 0.8f, 0.6f}, {0.2f, 0.35f, 1.0f}, 9.0f);
  point("green", {-0.62f, -0.62f, 0.62f}, {0.2f, 1.0f, 0.25f}, 0.35f);
  point("key", {2.5f, 4.0f, 3.0f}, {1.0f, 0.97f, 0.92f}, 14.0f);

  Camera cam;
  cam.name = "front";
  cam.position = {1.6f, 1.2f, 4.3f};
  cam.target = {0.0f, -0.1f, 0.0f};
  cam.vfov_degrees = 38.0f;
  s.cameras.push_back(cam);
  Camera inside = cam;
  inside.name = "inside";
  inside.position = {0.45f, 0.3f, 0.85f};
  inside.target = {-0.3f, -0.1f, -1.0f};
  inside.vfov_degrees = 70.0f;
  s.cameras.push_back(inside);

  s.sky.type = SkyType::Gradient;
  s.sky.color = {0.02f, 0.025f, 0.05f};
  s.sky.horizon = {0.08f, 0.08f, 0.1f};
  s.ambient = {0.04f, 0.04f, 0.045f};
  return s;
}

}  // namespace specula::builtin
