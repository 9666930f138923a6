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
};

}  // namespace

std::vector<std::string> builtin_scene_names() {
  std::vector<std::string> out;
  for (const Entry& e : kScenes) out.emplace_back(e.name);
  return out;
}

bool is_builtin_scene(const std::string& name) {
  for (const Entry& e : kScenes)
    if (name == e.name) return true;
  return false;
}

Scene make_builtin_scene(const std::string& name, const LoadOptions& options) {
  for (const Entry& e : kScenes)
    if (name == e.name) {
      Scene s = e.make(options);
      s.name = name;
      s.validate();
      return s;
    }
  std::string names;
  for (const Entry& e : kScenes) names += (names.empty() ? "" : ", ") + std::string(e.name);
  throw Error("unknown built-in scene '" + name + "' (available: " + names + ")");
}

}  // namespace specula
