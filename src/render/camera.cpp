// Pinhole camera and AOV names (owner: render).
#include <cctype>
#include <cmath>
#include <string>

#include "specula/error.h"
#include "specula/render.h"

namespace specula {

PinholeCamera::PinholeCamera(const Camera& cam, int width, int height) {
  origin_ = cam.position;
  Vec3 w = normalize(cam.target - cam.position);
  if (w == Vec3{}) w = {0, 0, -1};  // target == position: look down -z
  Vec3 u = normalize(cross(w, cam.up));
  if (u == Vec3{}) u = normalize(cross(w, std::fabs(w.y) < 0.9f ? Vec3{0, 1, 0} : Vec3{1, 0, 0}));
  const Vec3 v = cross(u, w);
  const float vfov = std::clamp(cam.vfov_degrees, 1e-3f, 179.0f) * kPi / 180.0f;
  const float half_h = std::tan(0.5f * vfov);
  const float aspect = height > 0 ? static_cast<float>(width) / static_cast<float>(height) : 1.0f;
  const float half_w = half_h * aspect;
  top_left_ = w - u * half_w + v * half_h;
  du_ = u * (2.0f * half_w / static_cast<float>(std::max(width, 1)));
  dv_ = v * (-2.0f * half_h / static_cast<float>(std::max(height, 1)));
}

const Camera& select_camera(const Scene& scene, const std::string& name) {
  if (name.empty()) {
    if (scene.cameras.empty()) throw Error((scene.name.empty() ? "scene" : scene.name) + ": has no camera");
    return scene.cameras.front();
  }
  const auto idx = scene.find_camera(name);
  if (!idx) {
    std::string names;
    for (const Camera& c : scene.cameras) names += (names.empty() ? "" : ", ") + c.name;
    throw Error("unknown camera '" + name + "' (available: " + (names.empty() ? std::string("none") : names) + ")");
  }
  return scene.cameras[*idx];
}

const char* aov_name(Aov aov) {
  switch (aov) {
    case Aov::Depth: return "depth";
    case Aov::Normal: return "normal";
    case Aov::PrimId: return "prim";
    case Aov::Cost: return "cost";
  }
  return "unknown";
}

std::vector<Aov> parse_aovs(const std::string& list) {
  std::vector<Aov> out;
  auto add = [&out](Aov a) {
    for (Aov b : out)
      if (a == b) return;
    out.push_back(a);
  };
  size_t start = 0;
  while (start <= list.size()) {
    size_t end = list.find(',', start);
    if (end == std::string::npos) end = list.size();
    std::string item;
    for (size_t i = start; i < end; ++i)
      if (!std::isspace(static_cast<unsigned char>(list[i])))
        item += static_cast<char>(std::tolower(static_cast<unsigned char>(list[i])));
    if (!item.empty()) {
      if (item == "depth") add(Aov::Depth);
      else if (item == "normal" || item == "normals") add(Aov::Normal);
      else if (item == "prim" || item == "primid" || item == "prim_id") add(Aov::PrimId);
      else if (item == "cost") add(Aov::Cost);
      else throw Error("unknown AOV '" + item + "' (valid: depth, normal, prim, cost)");
    }
    start = end + 1;
  }
  return out;
}

}  // namespace specula
