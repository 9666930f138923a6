// load_scene dispatch, DataPaths and the helpers shared by all loaders (loader_internal.h).
#include <algorithm>
#include <cctype>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <iostream>
#include <sstream>
#include <system_error>

#include "scene/loader_internal.h"
#include "specula/error.h"
#include "specula/image.h"
#include "specula/load.h"

namespace fs = std::filesystem;

namespace specula {

// ---------------------------------------------------------------------------------------------
// DataPaths

std::vector<fs::path> DataPaths::search_path() const {
  std::vector<fs::path> dirs;
  if (!cli_dir.empty()) dirs.emplace_back(cli_dir);
  if (const char* env = std::getenv("SPECULA_DATA"); env != nullptr && *env != '\0')
    dirs.emplace_back(env);
#ifdef SPECULA_SOURCE_DIR
  dirs.push_back(fs::path(SPECULA_SOURCE_DIR "/../shared/data/meshes").lexically_normal());
#endif
  return dirs;
}

fs::path DataPaths::find(const std::string& file_name) const {
  // Only plain relative names: an absolute name would ignore the folder it is joined to.
  if (file_name.empty() || fs::path(file_name).is_absolute()) return {};
  for (const fs::path& dir : search_path()) {
    std::error_code ec;
    const fs::path p = dir / file_name;
    if (fs::is_regular_file(p, ec)) return p;
  }
  return {};
}

std::string DataPaths::describe() const {
  std::string out;
  for (const fs::path& dir : search_path()) {
    if (!out.empty()) out += ':';
    out += dir.string();
  }
  return out;
}

// ---------------------------------------------------------------------------------------------
// Sizes

std::string format_bytes(uint64_t bytes, bool exact) {
  static constexpr const char* kUnits[] = {"KiB", "MiB", "GiB", "TiB", "PiB", "EiB"};
  if (bytes < 1024) return std::to_string(bytes) + (bytes == 1 ? " byte" : " bytes");
  int unit = 0;
  uint64_t scale = 1024;
  while (unit + 1 < 6 && bytes / scale >= 1024) {
    scale *= 1024;
    ++unit;
  }
  char buf[48];
  if (bytes % scale == 0) {
    std::snprintf(buf, sizeof buf, "%llu %s", static_cast<unsigned long long>(bytes / scale), kUnits[unit]);
    return buf;
  }
  std::snprintf(buf, sizeof buf, "%.2f %s", static_cast<double>(bytes) / static_cast<double>(scale), kUnits[unit]);
  return exact ? with_thousands(bytes) + " bytes (" + buf + ")" : std::string(buf);
}

uint64_t parse_byte_size(const std::string& text) {
  const auto bad = [&text](const std::string& why) {
    return Error("'" + text + "': " + why +
                 " (expected bytes with an optional unit K, M, G or T, e.g. 8GiB, 512MiB, 1.5G; units are powers "
                 "of 1024)");
  };
  size_t i = 0;
  while (i < text.size() && (std::isdigit(static_cast<unsigned char>(text[i])) || text[i] == '.')) ++i;
  const std::string number = text.substr(0, i);
  if (number.empty() || number == "." || std::count(number.begin(), number.end(), '.') > 1)
    throw bad("not a size");
  size_t j = i;
  while (j < text.size() && text[j] == ' ') ++j;
  std::string unit = text.substr(j);
  std::transform(unit.begin(), unit.end(), unit.begin(),
                 [](unsigned char c) { return static_cast<char>(std::tolower(c)); });
  int shift = 0;
  if (unit.empty() || unit == "b") {
    shift = 0;
  } else {
    const char* const kPrefixes = "kmgt";
    const char* p = std::strchr(kPrefixes, unit[0]);
    const std::string rest = unit.substr(1);
    if (p == nullptr || *p == '\0' || !(rest.empty() || rest == "b" || rest == "ib")) throw bad("unknown unit '" + text.substr(j) + "'");
    shift = 10 * static_cast<int>(p - kPrefixes + 1);
  }
  // Integers exactly in 64 bits; fractions ("1.5G") through long double, rounded down.
  uint64_t value = 0;
  if (number.find('.') == std::string::npos) {
    for (char c : number) {
      const uint64_t digit = static_cast<uint64_t>(c - '0');
      if (value > (UINT64_MAX - digit) / 10) throw bad("too large");
      value = value * 10 + digit;
    }
    if (shift > 0 && value > (UINT64_MAX >> shift)) throw bad("too large");
    value <<= shift;
  } else {
    const long double v = std::strtold(number.c_str(), nullptr) * static_cast<long double>(uint64_t{1} << shift);
    if (!(v < 18446744073709551616.0L)) throw bad("too large");
    value = static_cast<uint64_t>(v);
  }
  if (value == 0) throw bad("must be at least 1 byte");
  return value;
}

std::string file_size_refusal(uint64_t size, const InputLimits& limits) {
  return "file is " + format_bytes(size, true) + ", over the limit of " + format_bytes(limits.max_file_bytes, true) +
         " (--max-file-size raises it)";
}

// ---------------------------------------------------------------------------------------------
// load_scene

Scene load_scene(const std::string& spec, const LoadOptions& options) {
  if (is_builtin_scene(spec)) return make_builtin_scene(spec, options);
  const fs::path path(spec);
  const std::string ext = detail::lower_extension(path);
  if (ext != ".json" && ext != ".gltf" && ext != ".glb" && ext != ".obj" && ext != ".ply") {
    std::string names;
    for (const std::string& n : builtin_scene_names()) names += (names.empty() ? "" : ", ") + n;
    names += ", city:N";
    throw file_error(spec, ext.empty() ? "not a built-in scene (" + names +
                                             ") and has no file extension (.json, .gltf, .glb, "
                                             ".obj, .ply)"
                                       : "unknown scene file extension '" + ext +
                                             "' (expected .json, .gltf, .glb, .obj or .ply)");
  }
  std::error_code ec;
  if (!fs::exists(path, ec)) throw file_error(spec, "file not found");
  Scene scene = ext == ".json"                   ? load_json_scene(path, options)
                : (ext == ".gltf" || ext == ".glb") ? load_gltf(path, options)
                : ext == ".obj"                     ? load_obj(path, options)
                                                    : load_ply(path, options);
  // The scene is complete plain data: an image sky is decoded here, not by the renderer.
  if (scene.sky.type == SkyType::Image && scene.sky.image.empty()) {
    try {
      load_sky_image(scene.sky, options.limits);
    } catch (const Error& e) {
      throw file_error(spec, std::string("sky image: ") + e.what());
    }
  }
  return scene;
}

// ---------------------------------------------------------------------------------------------
// Shared loader helpers

namespace detail {

void warn(const LoadOptions& options, const std::string& message) {
  if (options.warn) {
    options.warn(message);
  } else {
    std::cerr << "warning: " << message << '\n';
  }
}

uint64_t checked_file_size(const fs::path& path, const InputLimits& limits) {
  std::error_code ec;
  const fs::file_status st = fs::status(path, ec);
  if (ec || !fs::exists(st)) throw file_error(path.string(), "file not found");
  if (!fs::is_regular_file(st)) throw file_error(path.string(), "not a regular file");
  const uintmax_t size = fs::file_size(path, ec);
  if (ec) throw file_error(path.string(), "cannot read file size: " + ec.message());
  if (size > limits.max_file_bytes) throw file_error(path.string(), specula::file_size_refusal(size, limits));
  return size;
}

std::string read_file(const fs::path& path, const InputLimits& limits) {
  const uint64_t size = checked_file_size(path, limits);
  std::ifstream in(path, std::ios::binary);
  if (!in) throw file_error(path.string(), "cannot open file");
  std::string data(static_cast<size_t>(size), '\0');
  if (size > 0 && !in.read(data.data(), static_cast<std::streamsize>(size)))
    throw file_error(path.string(), "read error");
  return data;
}

void check_elements(const InputLimits& limits, const std::string& file, const std::string& where,
                    uint64_t count, Elements what) {
  if (count <= limits.max_elements) return;
  // Scene memory they take: a position and a normal per vertex; an index per corner plus a
  // material id per triangle. The acceleration structure comes on top.
  const bool vertices = what == Elements::Vertices;
  const uint64_t bytes = vertices ? count * 2 * sizeof(Vec3) : count * sizeof(uint32_t) + count / 3 * sizeof(uint32_t);
  throw file_error(file, where + with_thousands(count) + (vertices ? " vertices" : " triangle indices") +
                             ", over the limit of " + with_thousands(limits.max_elements) + " (about " +
                             format_bytes(bytes) + " of scene memory; --max-elements raises the limit)");
}

std::string lower_extension(const fs::path& path) {
  std::string ext = path.extension().string();
  std::transform(ext.begin(), ext.end(), ext.begin(),
                 [](unsigned char c) { return static_cast<char>(std::tolower(c)); });
  return ext;
}

fs::path confined_path(const fs::path& dir, const std::string& reference, std::string& why) {
  if (reference.empty()) {
    why = "empty file reference";
    return {};
  }
  if (reference.find('\0') != std::string::npos) {
    why = "file reference '" + reference + "' contains a NUL byte";
    return {};
  }
  if (reference.front() == '/' || reference.front() == '\\' || reference.front() == '~') {
    why = "absolute path '" + reference + "' refused: references must stay inside " +
          (dir.empty() ? std::string(".") : dir.string());
    return {};
  }
  // "C:\x", "file:..", "http://..": drive letters and URI schemes.
  const size_t colon = reference.find(':');
  if (colon != std::string::npos) {
    why = "'" + reference + "' refused: drive letters and URI schemes are not allowed in file "
          "references";
    return {};
  }
  std::string normalized = reference;
  std::replace(normalized.begin(), normalized.end(), '\\', '/');
  const fs::path rel(normalized);
  for (const fs::path& part : rel) {
    if (part == "..") {
      why = "path '" + reference + "' refused: '..' may not leave " +
            (dir.empty() ? std::string(".") : dir.string());
      return {};
    }
  }
  const fs::path full = dir / rel;
  // Symlinks may still point outside; compare canonical paths when the file exists.
  std::error_code ec;
  if (fs::exists(full, ec)) {
    const fs::path base = fs::weakly_canonical(dir.empty() ? fs::path(".") : dir, ec);
    const fs::path target = fs::weakly_canonical(full, ec);
    if (!ec) {
      const std::string b = base.string(), t = target.string();
      if (t.size() <= b.size() || t.compare(0, b.size(), b) != 0 ||
          (b.back() != '/' && t[b.size()] != '/')) {
        why = "path '" + reference + "' refused: it resolves outside " + base.string();
        return {};
      }
    }
  }
  return full;
}

void append_mesh(Scene& scene, MeshData&& mesh, uint32_t material_id, const Mat4& xf,
                 size_t& dropped_triangles) {
  const size_t nv = mesh.positions.size();
  const size_t nt = mesh.indices.size() / 3;
  // Transform into world space here (not in add_mesh) so non-finite results are caught too.
  std::vector<uint8_t> bad(nv, 0);
  bool any_bad = false;
  for (size_t i = 0; i < nv; ++i) {
    const Vec3 p = xf.transform_point(mesh.positions[i]);
    if (!is_finite(mesh.positions[i]) || !is_finite(p)) {
      bad[i] = 1;
      any_bad = true;
    }
    mesh.positions[i] = p;
  }
  bool normals_ok = mesh.normals.size() == nv && nv > 0;
  if (normals_ok) {
    for (Vec3& n : mesh.normals) {
      const Vec3 w = normalize(xf.transform_normal(n));
      if (w == Vec3{}) {
        normals_ok = false;  // zero / non-finite file normal: compute all of this mesh's
        break;
      }
      n = w;
    }
  }
  if (!normals_ok) mesh.normals.clear();
  const bool per_triangle = mesh.material_ids.size() == nt;

  if (any_bad) {
    std::vector<uint32_t> kept_indices;
    std::vector<uint32_t> kept_materials;
    kept_indices.reserve(mesh.indices.size());
    for (size_t t = 0; t < nt; ++t) {
      const uint32_t* tri = &mesh.indices[3 * t];
      if (bad[tri[0]] || bad[tri[1]] || bad[tri[2]]) {
        ++dropped_triangles;
        continue;
      }
      kept_indices.insert(kept_indices.end(), tri, tri + 3);
      if (per_triangle) kept_materials.push_back(mesh.material_ids[t]);
    }
    // Remove the unused (and all non-finite) vertices, keeping the order of the rest.
    std::vector<uint32_t> remap(nv, UINT32_MAX);
    for (uint32_t idx : kept_indices) remap[idx] = 0;
    std::vector<Vec3> pos, nrm;
    for (size_t i = 0; i < nv; ++i) {
      if (remap[i] == UINT32_MAX) continue;
      remap[i] = static_cast<uint32_t>(pos.size());
      pos.push_back(mesh.positions[i]);
      if (!mesh.normals.empty()) nrm.push_back(mesh.normals[i]);
    }
    for (uint32_t& idx : kept_indices) idx = remap[idx];
    mesh.positions = std::move(pos);
    mesh.normals = std::move(nrm);
    mesh.indices = std::move(kept_indices);
    mesh.material_ids = std::move(kept_materials);
  }
  MeshRange& range = scene.add_mesh(std::move(mesh.name), mesh.positions, mesh.indices,
                                    material_id, mesh.normals, Mat4::identity());
  if (per_triangle && mesh.material_ids.size() == range.triangle_count) {
    std::copy(mesh.material_ids.begin(), mesh.material_ids.end(),
              scene.material_ids.begin() + range.first_triangle);
  }
}

void warn_dropped(const LoadOptions& options, const std::string& file, size_t dropped_triangles) {
  if (dropped_triangles == 0) return;
  warn(options, file + ": dropped " + with_thousands(dropped_triangles) + " triangle" +
                    (dropped_triangles == 1 ? "" : "s") +
                    " with non-finite (NaN/Inf) vertex coordinates");
}

void validate_scene(const Scene& scene, const std::string& file) {
  try {
    scene.validate();
  } catch (const Error& e) {
    throw file_error(file, e.what());
  }
  // Degenerate triangles are kept (file order is triangle order), but a file of nothing else
  // has no surface: every ray would miss and every voxel set be empty or a wireframe.
  const size_t n = scene.triangle_count();
  for (size_t t = 0; t < n; ++t) {
    const Vec3& a = scene.positions[scene.indices[3 * t]];
    const Vec3 c = cross(scene.positions[scene.indices[3 * t + 1]] - a, scene.positions[scene.indices[3 * t + 2]] - a);
    if (c.x != 0.0f || c.y != 0.0f || c.z != 0.0f) return;
  }
  if (n > 0)
    throw file_error(file, "no surface: " + std::string(n == 1 ? "its one triangle has" : "all " + std::to_string(n) + " triangles have") +
                               " zero area (collinear or repeated vertices)");
}

std::string unique_camera_name(const Scene& scene, const std::string& name) {
  if (!scene.find_camera(name)) return name;
  for (size_t k = 2;; ++k) {
    std::string candidate = name + "#" + std::to_string(k);
    if (!scene.find_camera(candidate)) return candidate;
  }
}


}  // namespace detail
}  // namespace specula
