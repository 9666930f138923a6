// Placeholder until the built-in scenes land; owner: render. Delete when implementing.
#include "specula/error.h"
#include "specula/load.h"

namespace specula {
std::vector<std::string> builtin_scene_names() { return {"pool", "glassbox", "cornell"}; }
bool is_builtin_scene(const std::string& name) { return name == "pool" || name == "glassbox" || name == "cornell"; }
Scene make_builtin_scene(const std::string& name, const LoadOptions&) { throw Error(name + ": not implemented"); }
}  // namespace specula
