// Built-in scene "cornell": a Cornell box with a mirror block and a glass sphere (owner: render).
#include <cmath>

#include "scene/builtin_geometry.h"
#include "scene/builtin_scenes.h"

namespace specula::builtin {

Scene make_cornell(const LoadOptions& /*options*/) {
  Scene s;
  Material white;
  white.name = "white";
  white.diffuse = {0.73f, 0.71f, 0.68f};
  Material red = white;
  red.name = "red";
  red.diffuse = {0.63f, 0.07f, 0.05f};
  Material green = white;
  green.name = "green";
  green.diffuse = {0.14f, 0.45f, 0.09f};
  Material lamp;
  lamp.name = "lamp";
  lamp.diffuse = {0, 0, 0};
  lamp.emission = {6.0f, 5.4f, 4.6f};
  Material mirror;
  mirror.name = "mirror";
  mirror.diffuse = {0.8f, 0.8f, 0.8f};
  mirror.specular = {0.6f, 0.6f, 0.6f};
  mirror.phong_exponent = 200.0f;
  mirror.reflectivity = 0.85f;
  Material glass;
  glass.name = "glass";
  glass.diffuse = {0.9f, 0.95f, 1.0f};
  glass.specular = {0.9f, 0.9f, 0.9f};
  glass.phong_exponent = 400.0f;
  glass.transparency = 0.97f;
  glass.ior = 1.5f;
  glass.absorption = {0.08f, 0.04f, 0.02f};

  const uint32_t m_white = s.add_material(white), m_red = s.add_material(red),
                 m_green = s.add_material(green), m_lamp = s.add_material(lamp),
                 m_mirror = s.add_material(mirror), m_glass = s.add_material(glass);

  // The box: x in [-1, 1], y in [0, 2], z in [-1, 1], open towards +z; walls face inwards.
  MeshBuilder walls, left, right, light;
  walls.quad_uv({0, 0, 0}, {0, 0, 1}, {1, 0, 0});   // floor, faces +y
  walls.quad_uv({0, 2, 0}, {1, 0, 0}, {0, 0, 1});   // ceiling, faces -y
  walls.quad_uv({0, 1, -1}, {1, 0, 0}, {0, 1, 0});  // back, faces +z
  left.quad_uv({-1, 1, 0}, {0, 1, 0}, {0, 0, 1});   // faces +x
  right.quad_uv({1, 1, 0}, {0, 0, 1}, {0, 1, 0});   // faces -x
  light.quad_uv({0, 1.998f, 0}, {0.26f, 0, 0}, {0, 0, 0.26f});  // lamp panel, faces -y
  // A shallow lamp housing around the light keeps its inverse-square hot spot off the
  // ceiling (a point-like light right under a ceiling would burn a white disc into it).
  MeshBuilder housing;
  constexpr float kH = 0.27f, kTop = 2.0f, kBottom = 1.84f;
  const float hc = 0.5f * (kTop + kBottom), hh = 0.5f * (kTop - kBottom);
  housing.quad_uv({-kH, hc, 0}, {0, 0, kH}, {0, hh, 0});   // faces -x (outside)
  housing.quad_uv({-kH, hc, 0}, {0, hh, 0}, {0, 0, kH});   // faces +x (inside)
  housing.quad_uv({kH, hc, 0}, {0, hh, 0}, {0, 0, kH});    // faces +x (outside)
  housing.quad_uv({kH, hc, 0}, {0, 0, kH}, {0, hh, 0});    // faces -x (inside)
  housing.quad_uv({0, hc, -kH}, {0, hh, 0}, {kH, 0, 0});   // faces -z
  housing.quad_uv({0, hc, -kH}, {kH, 0, 0}, {0, hh, 0});   // faces +z
  housing.quad_uv({0, hc, kH}, {kH, 0, 0}, {0, hh, 0});    // faces +z
  housing.quad_uv({0, hc, kH}, {0, hh, 0}, {kH, 0, 0});    // faces -z
  walls.add_to(s, "walls", m_white);
  left.add_to(s, "left_wall", m_red);
  right.add_to(s, "right_wall", m_green);
  light.add_to(s, "lamp", m_lamp);
  housing.add_to(s, "lamp_housing", m_white);

  // Tall mirror block, turned 20 degrees about y.
  MeshBuilder block;
  block.box(Aabb{{-0.28f, 0.0f, -0.28f}, {0.28f, 1.25f, 0.28f}});
  block.transform(Mat4::translate({-0.42f, 0.0f, -0.4f}) * Mat4::rotate({0, 1, 0}, 0.6f));
  block.add_to(s, "mirror_block", m_mirror);

  // Glass sphere (icosphere, 5120 triangles).
  icosphere({0.42f, 0.36f, 0.3f}, 0.36f, 4).add_to(s, "glass_sphere", m_glass);

  Light l;
  l.name = "ceiling";
  l.type = LightType::Sphere;
  l.position = {0.0f, 1.9f, 0.0f};
  l.radius = 0.08f;
  l.samples = 32;
  l.color = {1.0f, 0.92f, 0.82f};
  l.intensity = 3.2f;
  s.lights.push_back(l);

  Camera cam;
  cam.name = "front";
  cam.position = {0.0f, 1.0f, 3.9f};
  cam.target = {0.0f, 1.0f, 0.0f};
  cam.vfov_degrees = 37.0f;
  s.cameras.push_back(cam);

  s.sky.type = SkyType::Constant;
  s.sky.color = {0.0f, 0.0f, 0.0f};
  s.ambient = {0.03f, 0.03f, 0.03f};
  return s;
}

}  // namespace specula::builtin
