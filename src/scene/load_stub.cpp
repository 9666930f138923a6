// Placeholder until the loaders land; owner: loaders. Delete when implementing.
#include "specula/error.h"
#include "specula/load.h"

namespace specula {
std::vector<std::filesystem::path> DataPaths::search_path() const { return {}; }
std::filesystem::path DataPaths::find(const std::string&) const { return {}; }
std::string DataPaths::describe() const { return {}; }
Scene load_scene(const std::string& spec, const LoadOptions&) { throw Error(spec + ": loading not implemented yet"); }
Scene load_obj(const std::filesystem::path& p, const LoadOptions&) { throw Error(p.string() + ": not implemented"); }
Scene load_ply(const std::filesystem::path& p, const LoadOptions&) { throw Error(p.string() + ": not implemented"); }
Scene load_gltf(const std::filesystem::path& p, const LoadOptions&) { throw Error(p.string() + ": not implemented"); }
Scene load_json_scene(const std::filesystem::path& p, const LoadOptions&) { throw Error(p.string() + ": not implemented"); }
}  // namespace specula
