// Wavefront OBJ + MTL loader on top of tinyobjloader.
//
// Triangle order is file order: tinyobjloader is run with triangulate=false and every polygon
// with vertices 0..n-1 is fanned here as (0,1,2), (0,2,3), ... Faces with fewer than three
// vertices are dropped by tinyobjloader (with a warning). Each OBJ shape (o/g) becomes one
// MeshRange; its vertices are the distinct (position, normal) pairs it uses, in file order
// (a single shape without normals keeps all file vertices, so vertex ids match the file).
// File normals are used when every corner of the shape has one; otherwise normals are computed.
//
// MTL -> Material mapping (also in docs/scene-format.md):
//   Kd -> diffuse, Ks -> specular, Ns -> phong_exponent (at least 1), Ke -> emission,
//   Ni -> ior (values <= 0 mean 1), d -> transparency = 1 - d (Tr is read as 1 - d by
//   tinyobjloader, so "Tr 0.3" == "d 0.7"),
//   Tf -> absorption = -ln(clamp(Tf, 1e-4, 1)) per scene unit, only for transparent materials
//         and only when Tf is neither all zero (= unset) nor all one (= clear);
//   illum 0,1,2      : local shading only;
//   illum 3, 8       : reflection on -> reflectivity = max component of Ks;
//   illum 5          : Fresnel mirror -> reflectivity = max(Ks), or 1 when Ks is zero;
//   illum 4, 6, 7, 9 : glass / refraction -> transparency = 1 - d, or 1 when d = 1; ior = Ni,
//                      or 1.5 when Ni is unset (<= 1); the integrator's Fresnel split makes the
//                      reflection, so reflectivity stays 0;
//   reflectivity + transparency is clamped to 1 (transparency gives way).
// MTL files are resolved only inside the OBJ's own folder: absolute paths, drive letters, URI
// schemes and '..' components are errors; a missing MTL is a warning (default material).
#include <algorithm>
#include <cmath>
#include <cctype>
#include <fstream>
#include <iterator>
#include <limits>
#include <map>
#include <sstream>
#include <unordered_map>

#pragma GCC diagnostic push
#pragma GCC diagnostic ignored "-Wconversion"
#pragma GCC diagnostic ignored "-Wshadow"
#include <tiny_obj_loader.h>
#pragma GCC diagnostic pop

#include "scene/loader_internal.h"
#include "specula/error.h"
#include "specula/load.h"

namespace fs = std::filesystem;

namespace specula {
namespace {

/// The first number of \p text whose exponent has 10 or more significant digits ("2e-2147483648"),
/// with its 1-based line in \p line, or "" when there is none. tinyobjloader overflows a signed
/// int while it reads such an exponent (undefined behaviour, found by fuzz_obj) in OBJ and MTL
/// files alike; no real file needs one (10^±1e9 is zero or infinite in any float format).
std::string overlong_exponent(const std::string& text, size_t& line) {
  auto digit = [](char c) { return c >= '0' && c <= '9'; };
  auto blank = [](char c) { return c == ' ' || c == '\t' || c == '\n' || c == '\r'; };
  for (size_t k = 1; k + 1 < text.size(); ++k) {
    if (text[k] != 'e' && text[k] != 'E') continue;
    // A mantissa before: [+-]? digits and at most one '.', from the start of a token.
    size_t b = k, digits = 0, dots = 0;
    while (b > 0 && (digit(text[b - 1]) || text[b - 1] == '.')) digits += digit(text[--b]), dots += text[b] == '.';
    if (digits == 0 || dots > 1) continue;
    if (b > 0 && (text[b - 1] == '+' || text[b - 1] == '-')) --b;
    if (b > 0 && !blank(text[b - 1])) continue;
    size_t j = k + 1;
    if (j < text.size() && (text[j] == '+' || text[j] == '-')) ++j;
    while (j < text.size() && text[j] == '0') ++j;
    size_t e = j;
    while (e < text.size() && digit(text[e])) ++e;
    if (e - j < 10) continue;
    line = 1 + static_cast<size_t>(std::count(text.begin(), text.begin() + static_cast<std::ptrdiff_t>(k), '\n'));
    size_t end = e;
    while (end < text.size() && !blank(text[end]) && end - b < 40) ++end;
    return text.substr(b, end - b);
  }
  return "";
}

/// Refusal text for overlong_exponent()'s finding, or "".
std::string exponent_refusal(const std::string& text) {
  size_t line = 0;
  const std::string number = overlong_exponent(text, line);
  if (number.empty()) return "";
  return "line " + std::to_string(line) + ": number '" + number +
         "' has an exponent of 10 or more digits (out of range for any float)";
}

/// Reads mtllib files only from the OBJ's folder; records a refusal so the loader can throw.
class ConfinedMaterialReader : public tinyobj::MaterialReader {
 public:
  ConfinedMaterialReader(fs::path dir, const InputLimits& limits) : dir_(std::move(dir)), limits_(limits) {}

  bool operator()(const std::string& mat_id, std::vector<tinyobj::material_t>* materials,
                  std::map<std::string, int>* mat_map, std::string* warn,
                  std::string* err) override {
    std::string why;
    const fs::path p = detail::confined_path(dir_, mat_id, why);
    if (p.empty()) {
      if (refusal.empty()) refusal = "mtllib " + why;
      return false;
    }
    std::error_code ec;
    if (!fs::is_regular_file(p, ec)) {
      if (warn) *warn += "material library '" + mat_id + "' not found in " + dir_.string() + "\n";
      return false;
    }
    if (const uintmax_t size = fs::file_size(p, ec); !ec && size > limits_.max_file_bytes) {
      if (refusal.empty()) refusal = "mtllib '" + mat_id + "': " + file_size_refusal(size, limits_);
      return false;
    }
    std::ifstream file(p, std::ios::binary);
    if (!file) {
      if (warn) *warn += "cannot open material library '" + mat_id + "'\n";
      return false;
    }
    std::string text{std::istreambuf_iterator<char>(file), std::istreambuf_iterator<char>()};
    if (const std::string bad = exponent_refusal(text); !bad.empty()) {
      if (refusal.empty()) refusal = "mtllib '" + mat_id + "': " + bad;
      return false;
    }
    std::istringstream in(std::move(text));
    tinyobj::LoadMtl(mat_map, materials, &in, warn, err);
    return true;
  }

  std::string refusal;

 private:
  fs::path dir_;
  InputLimits limits_;
};

float clamp01(double v) { return static_cast<float>(std::clamp(std::isfinite(v) ? v : 0.0, 0.0, 1.0)); }
Vec3 vec3(const tinyobj::real_t* c) {
  auto f = [](tinyobj::real_t v) { return std::isfinite(v) ? static_cast<float>(v) : 0.0f; };
  return {f(c[0]), f(c[1]), f(c[2])};
}

Material map_material(const tinyobj::material_t& m) {
  Material out;
  out.name = m.name.empty() ? std::string("unnamed") : m.name;
  out.diffuse = vec3(m.diffuse);
  out.specular = vec3(m.specular);
  out.emission = vec3(m.emission);
  out.phong_exponent =
      std::isfinite(m.shininess) ? std::clamp(static_cast<float>(m.shininess), 1.0f, 1e6f) : 32.0f;
  const float ni = std::isfinite(m.ior) ? static_cast<float>(m.ior) : 1.0f;
  out.ior = ni > 0.0f ? ni : 1.0f;
  float transparency = 1.0f - clamp01(m.dissolve);
  float reflectivity = 0.0f;
  const float ks = std::clamp(max_component(out.specular), 0.0f, 1.0f);
  switch (m.illum) {
    case 3:
    case 8:
      reflectivity = ks;
      break;
    case 5:
      reflectivity = ks > 0.0f ? ks : 1.0f;
      break;
    case 4:
    case 6:
    case 7:
    case 9:
      if (transparency <= 0.0f) transparency = 1.0f;
      if (out.ior <= 1.0f) out.ior = 1.5f;
      break;
    default:
      break;
  }
  transparency = std::min(transparency, 1.0f - reflectivity);
  out.reflectivity = reflectivity;
  out.transparency = std::max(transparency, 0.0f);
  if (out.transparency > 0.0f) {
    const Vec3 tf = vec3(m.transmittance);
    if (!(tf == Vec3{}) && !(tf == Vec3{1, 1, 1})) {
      for (int i = 0; i < 3; ++i) out.absorption[i] = -std::log(std::clamp(tf[i], 1e-4f, 1.0f));
    }
  }
  return out;
}

/// First few lines of a tinyobjloader message block, joined with "; ".
std::string summarize(const std::string& text, size_t max_lines) {
  std::istringstream in(text);
  std::string line, out;
  size_t n = 0;
  while (std::getline(in, line)) {
    while (!line.empty() && (line.back() == '\r' || line.back() == ' ')) line.pop_back();
    if (line.empty() || line == ".") continue;
    if (n < max_lines) out += (out.empty() ? "" : "; ") + line;
    ++n;
  }
  if (n > max_lines) out += " (and " + std::to_string(n - max_lines) + " more)";
  return out;
}

/// Calls fn(first, end) for every line of \p text: first = index of its first character after
/// leading blanks, end = index just past it. Lines end at '\n', '\r' or "\r\n", as tinyobjloader
/// splits them (so line and vertex numbers agree with what it parses).
template <class Fn>
void for_each_line(const std::string& text, Fn&& fn) {
  size_t pos = 0;
  while (pos < text.size()) {
    size_t end = text.find_first_of("\r\n", pos);
    if (end == std::string::npos) end = text.size();
    size_t i = pos;
    while (i < end && (text[i] == ' ' || text[i] == '\t')) ++i;
    fn(i, end);
    pos = end + 1;
  }
}

/// Indices of the "v" lines that contain a nan / inf token (tinyobjloader turns those into 0).
/// \p vertex_lines is set to the number of "v" lines.
std::vector<size_t> non_finite_vertices(const std::string& text, size_t& vertex_lines) {
  std::vector<size_t> out;
  size_t vertex = 0;
  for_each_line(text, [&](size_t i, size_t end) {
    if (!(i + 1 < end && text[i] == 'v' && (text[i + 1] == ' ' || text[i + 1] == '\t'))) return;
    bool bad = false;
    // Ignore trailing comments ("# banana"); search this line only.
    const size_t stop = static_cast<size_t>(
        std::find(text.begin() + static_cast<std::ptrdiff_t>(i), text.begin() + static_cast<std::ptrdiff_t>(end), '#') -
        text.begin());
    for (size_t k = i + 2; k + 2 < stop && !bad; ++k) {
      const char a = static_cast<char>(std::tolower(static_cast<unsigned char>(text[k])));
      const char b = static_cast<char>(std::tolower(static_cast<unsigned char>(text[k + 1])));
      const char c = static_cast<char>(std::tolower(static_cast<unsigned char>(text[k + 2])));
      bad = (a == 'n' && b == 'a' && c == 'n') || (a == 'i' && b == 'n' && c == 'f');
    }
    if (bad) out.push_back(vertex);
    ++vertex;
  });
  vertex_lines = vertex;
  return out;
}

/// Turns "vw" lines (skin weights, an OBJ extension specula does not use) into comments before
/// tinyobjloader sees them: it converts their joint ids from float to int unchecked, which is
/// undefined behaviour for "inf" or "1e999" (found by fuzz_obj).
void comment_out_skin_weights(std::string& text) {
  for_each_line(text, [&text](size_t i, size_t end) {
    if (i + 2 < end && text[i] == 'v' && text[i + 1] == 'w' && (text[i + 2] == ' ' || text[i + 2] == '\t'))
      text[i] = '#';  // one character in place: the line positions for_each_line holds stay valid
  });
}

}  // namespace

Scene load_obj(const fs::path& path, const LoadOptions& options) {
  const std::string file = path.string();
  std::string text = detail::read_file(path, options.limits);
  size_t vertex_lines = 0;
  if (const std::string why = exponent_refusal(text); !why.empty()) throw file_error(file, why);
  const std::vector<size_t> non_finite = non_finite_vertices(text, vertex_lines);
  // Before tinyobjloader allocates them: every "v" line becomes a vertex.
  detail::check_elements(options.limits, file, "", vertex_lines, detail::Elements::Vertices);
  comment_out_skin_weights(text);
  std::istringstream in(std::move(text));  // C++20: no copy

  ConfinedMaterialReader reader(path.parent_path(), options.limits);
  tinyobj::attrib_t attrib;
  std::vector<tinyobj::shape_t> shapes;
  std::vector<tinyobj::material_t> obj_materials;
  std::string warn, err;
  const bool ok = tinyobj::LoadObj(&attrib, &shapes, &obj_materials, &warn, &err, &in, &reader,
                                   /*triangulate=*/false, /*default_vcols_fallback=*/false);
  if (!reader.refusal.empty()) throw file_error(file, reader.refusal);
  if (!ok) {
    const std::string msg = summarize(err, 3);
    throw file_error(file, msg.empty() ? std::string("cannot parse OBJ") : msg);
  }
  if (!err.empty()) warn += err;
  if (const std::string w = summarize(warn, 3); !w.empty()) detail::warn(options, file + ": " + w);

  Scene scene;
  scene.name = path.stem().string();
  for (const tinyobj::material_t& m : obj_materials) scene.add_material(map_material(m));
  uint32_t default_material = UINT32_MAX;
  auto get_default = [&]() {
    if (default_material == UINT32_MAX) {
      Material m;
      m.name = "default";
      default_material = scene.add_material(m);
    }
    return default_material;
  };

  const size_t num_positions = attrib.vertices.size() / 3;
  // tinyobjloader reads "nan" / "inf" as 0; restore them so those triangles get dropped.
  for (size_t v : non_finite)
    if (v < num_positions) attrib.vertices[3 * v] = std::numeric_limits<tinyobj::real_t>::quiet_NaN();
  const size_t num_normals = attrib.normals.size() / 3;
  size_t dropped = 0;
  size_t face_base = 0;  // global face number for messages
  for (const tinyobj::shape_t& shape : shapes) {
    const tinyobj::mesh_t& mesh = shape.mesh;
    // num_face_vertices is unsigned char in tinyobjloader: polygons with more than 255
    // corners wrap around, which shows up as a corner-count mismatch.
    uint64_t corners = 0;
    for (unsigned char c : mesh.num_face_vertices) corners += c;
    if (corners != mesh.indices.size())
      throw file_error(file, "shape '" + shape.name +
                                 "': a polygon has more than 255 vertices (not supported)");
    if (mesh.material_ids.size() != mesh.num_face_vertices.size())
      throw file_error(file, "shape '" + shape.name + "': inconsistent material ids");

    // Validate indices and decide whether file normals are usable.
    bool use_normals = num_normals > 0 && !mesh.indices.empty();
    for (size_t k = 0, face = 0, left = 0; k < mesh.indices.size(); ++k) {
      while (left == 0) left = mesh.num_face_vertices[face++];
      --left;
      const tinyobj::index_t& idx = mesh.indices[k];
      if (idx.vertex_index < 0 || static_cast<size_t>(idx.vertex_index) >= num_positions)
        throw file_error(file, "face " + std::to_string(face_base + face) + " (shape '" +
                                   shape.name + "'): vertex index " +
                                   std::to_string(static_cast<long long>(idx.vertex_index) + 1) +
                                   " out of range (" + std::to_string(num_positions) +
                                   " vertices)");
      if (idx.normal_index >= 0 && static_cast<size_t>(idx.normal_index) >= num_normals)
        throw file_error(file, "face " + std::to_string(face_base + face) + " (shape '" +
                                   shape.name + "'): normal index " +
                                   std::to_string(idx.normal_index + 1) + " out of range (" +
                                   std::to_string(num_normals) + " normals)");
      if (idx.normal_index < -1)
        throw file_error(file, "face " + std::to_string(face_base + face) + " (shape '" +
                                   shape.name + "'): normal index out of range");
      if (idx.normal_index < 0) use_normals = false;
    }

    // Distinct (position, normal) pairs in file order.
    auto key_of = [&](const tinyobj::index_t& idx) -> uint64_t {
      const uint64_t v = static_cast<uint32_t>(idx.vertex_index);
      const uint64_t n = use_normals ? static_cast<uint32_t>(idx.normal_index) : 0u;
      return (v << 32) | n;
    };
    std::vector<uint64_t> keys;
    if (shapes.size() == 1 && !use_normals) {
      // One shape without normals: keep every file vertex so vertex ids match the file.
      keys.resize(num_positions);
      for (size_t v = 0; v < num_positions; ++v) keys[v] = uint64_t{v} << 32;
    } else {
      keys.reserve(mesh.indices.size());
      for (const tinyobj::index_t& idx : mesh.indices) keys.push_back(key_of(idx));
      std::sort(keys.begin(), keys.end());
      keys.erase(std::unique(keys.begin(), keys.end()), keys.end());
    }
    const std::string shape_where = shape.name.empty() ? std::string() : "shape '" + shape.name + "': ";
    detail::check_elements(options.limits, file, shape_where, scene.positions.size() + keys.size(),
                           detail::Elements::Vertices);
    uint64_t fanned = 0;  // indices after fan triangulation: 3 (n - 2) per n-gon
    for (unsigned char n : mesh.num_face_vertices)
      if (n >= 3) fanned += 3 * (uint64_t{n} - 2);
    detail::check_elements(options.limits, file, shape_where, scene.indices.size() + fanned,
                           detail::Elements::Indices);

    detail::MeshData md;
    md.name = shape.name.empty() ? scene.name : shape.name;
    md.positions.reserve(keys.size());
    for (uint64_t key : keys) {
      const size_t v = static_cast<size_t>(key >> 32);
      md.positions.push_back({attrib.vertices[3 * v], attrib.vertices[3 * v + 1],
                              attrib.vertices[3 * v + 2]});
      if (use_normals) {
        const size_t n = static_cast<size_t>(key & 0xFFFFFFFFu);
        md.normals.push_back(
            {attrib.normals[3 * n], attrib.normals[3 * n + 1], attrib.normals[3 * n + 2]});
      }
    }
    auto local = [&](const tinyobj::index_t& idx) {
      const auto it = std::lower_bound(keys.begin(), keys.end(), key_of(idx));
      return static_cast<uint32_t>(it - keys.begin());
    };
    // Fan-triangulate each polygon in order: (0,1,2), (0,2,3), ...
    size_t k = 0;
    for (size_t f = 0; f < mesh.num_face_vertices.size(); ++f) {
      const size_t n = mesh.num_face_vertices[f];
      const int obj_mat = mesh.material_ids[f];
      const uint32_t mat = (obj_mat >= 0 && static_cast<size_t>(obj_mat) < obj_materials.size())
                               ? static_cast<uint32_t>(obj_mat)
                               : get_default();
      if (n >= 3) {
        const uint32_t a = local(mesh.indices[k]);
        for (size_t j = 1; j + 1 < n; ++j) {
          md.indices.push_back(a);
          md.indices.push_back(local(mesh.indices[k + j]));
          md.indices.push_back(local(mesh.indices[k + j + 1]));
          md.material_ids.push_back(mat);
        }
      }
      k += n;
    }
    face_base += mesh.num_face_vertices.size();
    if (md.indices.empty()) continue;
    const uint32_t first_mat = md.material_ids.front();
    detail::append_mesh(scene, std::move(md), first_mat, Mat4::identity(), dropped);
  }
  detail::warn_dropped(options, file, dropped);
  if (scene.triangle_count() == 0) throw file_error(file, "no triangles (no usable faces)");
  add_default_camera_and_light(scene);
  detail::validate_scene(scene, file);
  return scene;
}

}  // namespace specula
