// The built-in scenes: names and dispatch (owner: render). Each scene is in its own file.
#include <string>
#include <vector>

#include "scene/builtin_scenes.h"
#include "specula/error.h"
#include "specula/load.h"

namespace specula {

namespace {

struct Entry {
  const char* name;
  Scene (*make)(const LoadOptions&);
};

constexpr Entry kScenes[] = {
    {"pool", builtin::make_pool},
    {"glassbox", builtin::make_glassbox},
    {"cornell", builtin::make_cornell},
    {"city", builtin::make_city},
};

/// "city" and "city:..." are claimed by the city, so a malformed size gets the city's error.
bool is_city_name(const std::string& name) { return name == "city" || name.rfind("city:", 0) == 0; }

std::string available_names() {
  std::string names;
  for (const Entry& e : kScenes) names += (names.empty() ? "" : ", ") + std::string(e.name);
  return names + ", city:N (N = triangles)";
}

}  // namespace

std::vector<std::string> builtin_scene_names() {
  std::vector<std::string> out;
  for (const Entry& e : kScenes) out.emplace_back(e.name);
  return out;
}

bool is_builtin_scene(const std::string& name) {
  for (const Entry& e : kScenes)
    if (name == e.name) return true;
  return is_city_name(name);
}

Scene make_builtin_scene(const std::string& name, const LoadOptions& options) {
  if (is_city_name(name)) {
    Scene s = builtin::make_city_with_triangles(*builtin::parse_city_spec(name));
    s.name = name;
    s.validate();
    return s;
  }
  for (const Entry& e : kScenes)
    if (name == e.name) {
      Scene s = e.make(options);
      s.name = name;
      s.validate();
      return s;
    }
  throw Error("unknown built-in scene '" + name + "' (available: " + available_names() + ")");
}

}  // namespace specula
