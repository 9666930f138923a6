/// \file load.h
/// Scene loading: built-in scenes, JSON scenes, glTF/GLB, OBJ(+MTL), PLY. Every loader throws
/// specula::Error with a message naming the file and the problem; none crashes on bad input.
#pragma once

#include <cstdint>
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

/// Resource limits for untrusted input (docs/SECURITY.md, "Limits"). Each is checked in 64-bit
/// arithmetic before the memory it bounds is allocated; a refusal (specula::Error) names the
/// file, the value, the limit and the `specula` flag that raises it. The defaults accept every
/// legitimate file we know of; raise them for inputs you trust.
struct InputLimits {
  /// Largest file any loader reads: scene, mesh, MTL library, glTF buffer, sky image
  /// (`--max-file-size`).
  uint64_t max_file_bytes = uint64_t{4} << 30;
  /// Most vertices, and most triangle indices (3 per triangle), in one scene
  /// (`--max-elements`); at most kMaxElementsCeiling.
  uint64_t max_elements = uint64_t{1} << 31;
  /// Most memory one image may take to decode: the decoder's buffers plus the linear RGB copy,
  /// estimated from its header before decoding (`--max-image-memory`).
  uint64_t max_image_bytes = uint64_t{1} << 30;
};

/// Hard ceiling of InputLimits::max_elements: vertex indices are 32-bit (Scene refuses more
/// than 0xFFFFFFF0 vertices).
inline constexpr uint64_t kMaxElementsCeiling = 0xFFFFFFF0u;

/// Formats a byte count for messages: "4 GiB", "1.50 GiB", "300 MiB", "12 KiB", "100 bytes".
/// \p exact (for limits and file sizes) spells out a count that is not a whole number of units:
/// "1,744 bytes (1.70 KiB)".
std::string format_bytes(uint64_t bytes, bool exact = false);

/// The refusal of a file of \p size bytes over limits.max_file_bytes, without the file name:
/// "file is 5,000,000,000 bytes (4.66 GiB), over the limit of 4 GiB (--max-file-size raises it)".
std::string file_size_refusal(uint64_t size, const InputLimits& limits);

/// Parses a size given on the command line: a number of bytes with an optional unit, e.g.
/// "4294967296", "8GiB", "512MiB", "1.5G", "64k". Units (case-insensitive) K/KB/KiB, M/MB/MiB,
/// G/GB/GiB, T/TB/TiB are all powers of 1024 (as `voxelize --memory-limit`); B alone is bytes.
/// Throws specula::Error naming the text for anything else, for 0, and for 2^64 or more.
uint64_t parse_byte_size(const std::string& text);

struct LoadOptions {
  DataPaths data;
  InputLimits limits;
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
