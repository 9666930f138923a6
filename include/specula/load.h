/// \file load.h
/// Scene loading: built-in scenes, JSON scenes, glTF/GLB, OBJ(+MTL), PLY. Every loader throws
/// specula::Error with a message naming the file and the problem; none crashes on bad input.
#pragma once

#include <filesystem>
#include <functional>
#include <string>
#include <vector>

#include "specula/scene.h"

namespace specula {

/// Where meshes for built-in scenes and tests are found: `--data DIR`, then $SPECULA_DATA,
/// then ../shared/data/meshes next to the source tree (compiled in as SPECULA_SOURCE_DIR).
struct DataPaths {
  std::string cli_dir;  ///< from --data; empty when not given
  /// The folders searched, in order (only those that are set).
  std::vector<std::filesystem::path> search_path() const;
  /// Full path of \p file_name in the first folder that has it, or empty.
  std::filesystem::path find(const std::string& file_name) const;
  /// "a:b:c" for messages.
  std::string describe() const;
};

struct LoadOptions {
  DataPaths data;
  /// Called with one-line warnings (missing mesh -> stand-in, dropped NaN vertices, ...).
  /// Default: print "warning: ..." to stderr.
  std::function<void(const std::string&)> warn;
};

/// Loads SCENE: a built-in name ("pool", "glassbox", "cornell", "city", "city:N" = a town of
/// about N triangles), a .json scene, a .gltf/.glb
/// file, or a bare .obj/.ply mesh (which gets a default camera, light and material).
Scene load_scene(const std::string& spec, const LoadOptions& options = {});

Scene load_obj(const std::filesystem::path& path, const LoadOptions& options = {});
Scene load_ply(const std::filesystem::path& path, const LoadOptions& options = {});
Scene load_gltf(const std::filesystem::path& path, const LoadOptions& options = {});
Scene load_json_scene(const std::filesystem::path& path, const LoadOptions& options = {});

/// Names of the built-in scenes (the city's sized form "city:N" is not listed).
std::vector<std::string> builtin_scene_names();
/// True for a built-in name; "city:" followed by anything counts (make_builtin_scene then
/// explains a malformed or out-of-range size).
bool is_builtin_scene(const std::string& name);
/// Builds a built-in scene; a missing mesh is replaced by a procedural stand-in of similar
/// size with a warning naming the file and the search path.
Scene make_builtin_scene(const std::string& name, const LoadOptions& options = {});

}  // namespace specula
