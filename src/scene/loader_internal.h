// Private helpers shared by the scene loaders (OBJ, PLY, glTF, JSON): warnings, file-size
// limits, path confinement and the NaN-filtering mesh appender. Not part of the public API.
#pragma once

#include "core/format.h"

#include <cstdint>
#include <filesystem>
#include <string>
#include <vector>

#include "specula/load.h"
#include "specula/scene.h"

namespace specula::detail {

/// Sends \p message to options.warn, or prints "warning: <message>" to stderr when unset.
void warn(const LoadOptions& options, const std::string& message);

/// Throws specula::Error "<file>: ..." unless \p path is an existing regular file of at most
/// limits.max_file_bytes; returns its size. (Counts inside a file are 64-bit checked against
/// the real file size, so this bounds every allocation a loader makes.)
uint64_t checked_file_size(const std::filesystem::path& path, const InputLimits& limits);

/// Reads a whole file (after checked_file_size).
std::string read_file(const std::filesystem::path& path, const InputLimits& limits);

/// What check_elements counts.
enum class Elements : uint8_t { Vertices, Indices };

/// Throws file_error(file, where + ...) when \p count vertices or triangle indices exceed
/// limits.max_elements, naming the count, the limit, the memory they would take and the flag.
/// Call with the scene-wide total a mesh would bring it to, before allocating the mesh.
void check_elements(const InputLimits& limits, const std::string& file, const std::string& where,
                    uint64_t count, Elements what);

/// Lower-case extension including the dot (".obj"), or empty.
std::string lower_extension(const std::filesystem::path& path);

/// Resolves \p reference (a relative path written inside \p file) against \p dir. Returns an
/// empty path and sets \p why when the reference is empty, absolute, has a drive letter or a
/// URI scheme, contains a '..' component, or (after resolving symlinks) leaves \p dir.
std::filesystem::path confined_path(const std::filesystem::path& dir, const std::string& reference,
                                    std::string& why);

/// One mesh in a loader's local coordinates, before it is appended to the scene.
struct MeshData {
  std::string name;
  std::vector<Vec3> positions;
  std::vector<Vec3> normals;             ///< empty, or one per position
  std::vector<uint32_t> indices;         ///< 3 per triangle, all < positions.size()
  std::vector<uint32_t> material_ids;    ///< empty (use the default id) or one per triangle
};

/// Appends \p mesh to \p scene transformed by \p xf, keeping triangle order. Triangles that use
/// a non-finite vertex (before or after the transform) are dropped and counted in
/// \p dropped_triangles (the caller warns once per file); unused vertices are removed only
/// when something was dropped. Normals are transformed by the inverse transpose; invalid
/// normals fall back to computed ones. Indices must already be bounds-checked.
void append_mesh(Scene& scene, MeshData&& mesh, uint32_t material_id, const Mat4& xf,
                 size_t& dropped_triangles);

/// Warns once about dropped non-finite triangles, if any.
void warn_dropped(const LoadOptions& options, const std::string& file, size_t dropped_triangles);

/// Runs scene.validate() and rethrows its error prefixed with \p file.
void validate_scene(const Scene& scene, const std::string& file);

/// \p name when no camera of \p scene has it yet, else the first of name#2, name#3, ... that
/// none has (cameras are selected by name: two with one name would hide the second).
std::string unique_camera_name(const Scene& scene, const std::string& name);


}  // namespace specula::detail
