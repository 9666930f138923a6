// JSON scene files (format documented in docs/scene-format.md).
//
// A scene places meshes (OBJ / PLY / glTF files relative to the JSON's folder and confined to
// it, shared data meshes found through DataPaths, or procedural "plane" / "box" / "sphere"),
// each with a transform and an optional material override, plus named materials, lights,
// cameras, a sky and an ambient term. Unknown keys are warnings; values of the wrong type are
// errors naming the key path ("meshes[2].transform.scale: expected ...").
#include <cmath>
#include <map>
#include <set>

#include <nlohmann/json.hpp>

#include "scene/loader_internal.h"
#include "specula/error.h"
#include "specula/load.h"

namespace fs = std::filesystem;

namespace specula {
namespace {

using json = nlohmann::ordered_json;  // keeps "materials" in file order

/// Why \p p, a referenced file that is not a regular file, cannot be read: "not found" or "is
/// not a regular file" (a folder, a device).
std::string not_a_file(const fs::path& p) {
  std::error_code ec;
  return fs::exists(p, ec) ? "is not a regular file" : "not found";
}

class JsonSceneLoader {
 public:
  JsonSceneLoader(const fs::path& path, const LoadOptions& options)
      : path_(path), file_(path.string()), dir_(path.parent_path()), options_(options) {}

  Scene load() {
    const std::string text = detail::read_file(path_, options_.limits);
    json root;
    try {
      root = json::parse(text);
    } catch (const json::parse_error& e) {
      fail(position(text, e.byte) + ": JSON parse error: " + strip_prefix(e.what()));
    } catch (const std::exception& e) {
      fail(std::string("JSON parse error: ") + e.what());
    }
    if (!root.is_object()) fail("the top level must be a JSON object");
    check_keys(root, "", {"name", "materials", "meshes", "lights", "cameras", "sky", "ambient",
                          "comment", "$schema"});
    scene_.name = root.contains("name") ? get_string(root["name"], "name") : path_.stem().string();
    scene_.add_material(Material{});  // id 0: default for meshes without one
    if (root.contains("materials")) read_materials(root["materials"]);
    if (root.contains("meshes")) {
      const json& meshes = root["meshes"];
      if (!meshes.is_array()) fail("meshes: expected an array");
      for (size_t i = 0; i < meshes.size(); ++i) read_mesh(meshes[i], "meshes[" + std::to_string(i) + "]");
    }
    if (root.contains("lights")) {
      const json& lights = root["lights"];
      if (!lights.is_array()) fail("lights: expected an array");
      for (size_t i = 0; i < lights.size(); ++i) read_light(lights[i], "lights[" + std::to_string(i) + "]");
    }
    if (root.contains("cameras")) {
      const json& cams = root["cameras"];
      if (!cams.is_array()) fail("cameras: expected an array");
      for (size_t i = 0; i < cams.size(); ++i) read_camera(cams[i], "cameras[" + std::to_string(i) + "]");
    }
    if (root.contains("sky")) read_sky(root["sky"], "sky");
    if (root.contains("ambient")) scene_.ambient = get_color(root["ambient"], "ambient");
    detail::warn_dropped(options_, file_, dropped_);
    if (scene_.triangle_count() == 0) fail("the scene has no triangles (no meshes)");
    if (scene_.cameras.empty()) add_default_camera_and_light(scene_);
    detail::validate_scene(scene_, file_);
    return std::move(scene_);
  }

 private:
  [[noreturn]] void fail(const std::string& what) const { throw file_error(file_, what); }

  static std::string strip_prefix(const std::string& what) {
    // nlohmann: "[json.exception.parse_error.101] parse error at line 1, column 2: ..."
    const size_t p = what.find("] ");
    return p == std::string::npos ? what : what.substr(p + 2);
  }
  static std::string position(const std::string& text, size_t byte) {
    size_t line = 1, col = 1;
    for (size_t i = 0; i + 1 < byte && i < text.size(); ++i) {
      if (text[i] == '\n') {
        ++line;
        col = 1;
      } else {
        ++col;
      }
    }
    return "line " + std::to_string(line) + ", column " + std::to_string(col) + " (byte " +
           std::to_string(byte) + ")";
  }

  void check_keys(const json& obj, const std::string& where, const std::set<std::string>& allowed) const {
    for (const auto& [key, value] : obj.items()) {
      (void)value;
      if (!allowed.count(key))
        detail::warn(options_, file_ + ": " + (where.empty() ? "" : where + ".") + key +
                                   ": unknown key ignored");
    }
  }

  // ------------------------------------------------------------------ typed getters
  std::string get_string(const json& v, const std::string& where) const {
    if (!v.is_string()) fail(where + ": expected a string");
    return v.get<std::string>();
  }
  float get_number(const json& v, const std::string& where) const {
    if (!v.is_number()) fail(where + ": expected a number");
    const double d = v.get<double>();
    if (!std::isfinite(d) || std::fabs(d) > 3.0e38) fail(where + ": number out of range");
    return static_cast<float>(d);
  }
  int get_int(const json& v, const std::string& where, int lo, int hi) const {
    if (!v.is_number_integer()) fail(where + ": expected an integer");
    const long long x = v.get<long long>();
    if (x < lo || x > hi) fail(where + ": " + std::to_string(x) + " outside [" + std::to_string(lo) + ", " + std::to_string(hi) + "]");
    return static_cast<int>(x);
  }
  Vec3 get_vec3(const json& v, const std::string& where) const {
    if (!v.is_array() || v.size() != 3) fail(where + ": expected an array of 3 numbers");
    return {get_number(v[0], where + "[0]"), get_number(v[1], where + "[1]"), get_number(v[2], where + "[2]")};
  }
  /// A colour: [r, g, b] or one number for grey.
  Vec3 get_color(const json& v, const std::string& where) const {
    if (v.is_number()) return Vec3(get_number(v, where));
    if (!v.is_array() || v.size() != 3) fail(where + ": expected a number or an array of 3 numbers");
    return get_vec3(v, where);
  }
  /// Scale: one number or [x, y, z].
  Vec3 get_scale(const json& v, const std::string& where) const {
    if (v.is_number()) return Vec3(get_number(v, where));
    if (!v.is_array() || v.size() != 3) fail(where + ": expected a number or an array of 3 numbers");
    return get_vec3(v, where);
  }

  // ------------------------------------------------------------------ materials
  Material read_material(const json& m, const std::string& where, std::string name) const {
    if (!m.is_object()) fail(where + ": expected an object");
    check_keys(m, where, {"name", "diffuse", "specular", "phong_exponent", "reflectivity",
                          "transparency", "ior", "absorption", "emission", "comment"});
    Material out;
    out.name = m.contains("name") ? get_string(m["name"], where + ".name") : std::move(name);
    if (m.contains("diffuse")) out.diffuse = get_color(m["diffuse"], where + ".diffuse");
    if (m.contains("specular")) out.specular = get_color(m["specular"], where + ".specular");
    if (m.contains("phong_exponent")) out.phong_exponent = get_number(m["phong_exponent"], where + ".phong_exponent");
    if (m.contains("reflectivity")) out.reflectivity = get_number(m["reflectivity"], where + ".reflectivity");
    if (m.contains("transparency")) out.transparency = get_number(m["transparency"], where + ".transparency");
    if (m.contains("ior")) out.ior = get_number(m["ior"], where + ".ior");
    if (m.contains("absorption")) out.absorption = get_color(m["absorption"], where + ".absorption");
    if (m.contains("emission")) out.emission = get_color(m["emission"], where + ".emission");
    if (out.reflectivity < 0 || out.reflectivity > 1) fail(where + ".reflectivity: must be in [0, 1]");
    if (out.transparency < 0 || out.transparency > 1) fail(where + ".transparency: must be in [0, 1]");
    if (out.reflectivity + out.transparency > 1.0001f)
      fail(where + ": reflectivity + transparency must not exceed 1");
    if (out.ior <= 0) fail(where + ".ior: must be positive");
    if (out.phong_exponent < 0) fail(where + ".phong_exponent: must not be negative");
    if (min_component(out.absorption) < 0) fail(where + ".absorption: must not be negative");
    return out;
  }

  void read_materials(const json& mats) {
    if (!mats.is_object()) fail("materials: expected an object mapping names to materials");
    for (const auto& [name, m] : mats.items())
      material_ids_[name] = scene_.add_material(read_material(m, "materials." + name, name));
  }

  /// "material": a name from "materials" or an inline material object. Returns the id.
  uint32_t material_ref(const json& v, const std::string& where) {
    if (v.is_string()) {
      const auto it = material_ids_.find(v.get<std::string>());
      if (it == material_ids_.end()) fail(where + ": unknown material '" + v.get<std::string>() + "'");
      return it->second;
    }
    if (v.is_object()) return scene_.add_material(read_material(v, where, "inline"));
    fail(where + ": expected a material name or a material object");
  }

  // ------------------------------------------------------------------ transforms
  Mat4 read_transform(const json& t, const std::string& where) const {
    if (!t.is_object()) fail(where + ": expected an object");
    check_keys(t, where, {"translate", "rotate", "scale", "matrix"});
    if (t.contains("matrix")) {
      if (t.contains("translate") || t.contains("rotate") || t.contains("scale"))
        fail(where + ": use either matrix or translate/rotate/scale");
      const json& m = t["matrix"];
      Mat4 r;
      if (m.is_array() && m.size() == 16) {
        for (size_t i = 0; i < 16; ++i) r.m[i] = get_number(m[i], where + ".matrix[" + std::to_string(i) + "]");
      } else if (m.is_array() && m.size() == 4) {
        for (size_t row = 0; row < 4; ++row) {
          const std::string w = where + ".matrix[" + std::to_string(row) + "]";
          if (!m[row].is_array() || m[row].size() != 4) fail(w + ": expected an array of 4 numbers");
          for (size_t c = 0; c < 4; ++c) r.m[row * 4 + c] = get_number(m[row][c], w + "[" + std::to_string(c) + "]");
        }
      } else {
        fail(where + ".matrix: expected 16 numbers (row-major) or 4 rows of 4");
      }
      return r;
    }
    Mat4 tr, rot, sc;
    if (t.contains("translate")) tr = Mat4::translate(get_vec3(t["translate"], where + ".translate"));
    if (t.contains("rotate")) {
      const json& r = t["rotate"];
      const std::string w = where + ".rotate";
      if (!r.is_object()) fail(w + ": expected {\"axis\": [x, y, z], \"degrees\": angle}");
      check_keys(r, w, {"axis", "degrees"});
      if (!r.contains("axis") || !r.contains("degrees")) fail(w + ": needs axis and degrees");
      const Vec3 axis = get_vec3(r["axis"], w + ".axis");
      if (length(axis) == 0.0f) fail(w + ".axis: must not be zero");
      rot = Mat4::rotate(axis, get_number(r["degrees"], w + ".degrees") * kPi / 180.0f);
    }
    if (t.contains("scale")) sc = Mat4::scale(get_scale(t["scale"], where + ".scale"));
    return tr * rot * sc;
  }

  // ------------------------------------------------------------------ meshes
  void read_mesh(const json& m, const std::string& where) {
    if (!m.is_object()) fail(where + ": expected an object");
    check_keys(m, where, {"name", "file", "data", "builtin", "size", "radius", "segments",
                          "transform", "material", "comment"});
    const int sources = int(m.contains("file")) + int(m.contains("data")) + int(m.contains("builtin"));
    if (sources != 1) fail(where + ": needs exactly one of file, data or builtin");
    const Mat4 xf = m.contains("transform") ? read_transform(m["transform"], where + ".transform") : Mat4::identity();
    std::optional<uint32_t> override_id;
    if (m.contains("material")) override_id = material_ref(m["material"], where + ".material");
    std::string name = m.contains("name") ? get_string(m["name"], where + ".name") : std::string();

    detail::MeshData md;
    if (m.contains("builtin")) {
      const std::string kind = get_string(m["builtin"], where + ".builtin");
      md = make_shape(m, kind, where);
      md.name = name.empty() ? kind : name;
    } else {
      fs::path file;
      if (m.contains("file")) {
        const std::string ref = get_string(m["file"], where + ".file");
        std::string why;
        file = detail::confined_path(dir_, ref, why);
        if (file.empty()) fail(where + ".file: " + why);
        std::error_code ec;
        if (!fs::is_regular_file(file, ec))
          fail(where + ".file: '" + ref + "' " + not_a_file(file) + " in " +
               (dir_.empty() ? std::string(".") : dir_.string()));
      } else {
        const std::string ref = get_string(m["data"], where + ".data");
        if (ref.find('/') != std::string::npos || ref.find('\\') != std::string::npos || ref == "..")
          fail(where + ".data: must be a plain file name");
        file = options_.data.find(ref);
        if (file.empty()) fail(where + ".data: '" + ref + "' not found in " + options_.data.describe());
      }
      const std::string ext = detail::lower_extension(file);
      if (ext != ".obj" && ext != ".ply" && ext != ".gltf" && ext != ".glb")
        fail(where + ": unsupported mesh file extension '" + ext + "' (.obj, .ply, .gltf, .glb)");
      // Each file is loaded once, however many meshes place it.
      std::error_code ec;
      const std::string key = fs::weakly_canonical(file, ec).string();
      auto it = loaded_.find(key);
      if (it == loaded_.end()) {
        Scene sub;
        try {
          if (ext == ".obj") sub = load_obj(file, options_);
          else if (ext == ".ply") sub = load_ply(file, options_);
          else sub = load_gltf(file, options_);
        } catch (const Error& e) {
          fail(where + ": " + e.what());  // the inner message names the mesh file
        }
        it = loaded_.emplace(key, std::move(sub)).first;
      }
      const Scene& sub = it->second;
      // Geometry only: the sub-file's cameras and lights are ignored; its materials are kept
      // unless overridden.
      md.name = name.empty() ? file.stem().string() : name;
      detail::check_elements(options_.limits, file_, where + ": ", scene_.positions.size() + sub.positions.size(),
                             detail::Elements::Vertices);
      detail::check_elements(options_.limits, file_, where + ": ", scene_.indices.size() + sub.indices.size(),
                             detail::Elements::Indices);
      md.positions = sub.positions;
      md.normals = sub.normals;
      md.indices = sub.indices;
      if (!override_id) {
        auto [base_it, first_use] = material_base_.try_emplace(key, static_cast<uint32_t>(scene_.materials.size()));
        if (first_use)
          for (const Material& mat : sub.materials) scene_.add_material(mat);
        const uint32_t base = base_it->second;
        md.material_ids = sub.material_ids;
        for (uint32_t& id : md.material_ids) id += base;
      }
    }
    if (md.indices.empty()) return;
    detail::check_elements(options_.limits, file_, where + ": ", scene_.positions.size() + md.positions.size(),
                           detail::Elements::Vertices);
    detail::check_elements(options_.limits, file_, where + ": ", scene_.indices.size() + md.indices.size(),
                           detail::Elements::Indices);
    detail::append_mesh(scene_, std::move(md), override_id.value_or(0), xf, dropped_);
  }

  detail::MeshData make_shape(const json& m, const std::string& kind, const std::string& where) const {
    detail::MeshData md;
    if (kind == "plane") {
      // Square in the xz plane at y = 0, facing +y; size = [x extent, z extent] or one number.
      float sx = 1, sz = 1;
      if (m.contains("size")) {
        const json& s = m["size"];
        if (s.is_number()) sx = sz = get_number(s, where + ".size");
        else if (s.is_array() && s.size() == 2) {
          sx = get_number(s[0], where + ".size[0]");
          sz = get_number(s[1], where + ".size[1]");
        } else fail(where + ".size: expected a number or [x, z]");
      }
      const float hx = 0.5f * sx, hz = 0.5f * sz;
      md.positions = {{-hx, 0, -hz}, {-hx, 0, hz}, {hx, 0, hz}, {hx, 0, -hz}};
      md.normals.assign(4, Vec3{0, 1, 0});
      md.indices = {0, 1, 2, 0, 2, 3};
    } else if (kind == "box") {
      // Axis-aligned box centred on the origin with flat faces; size = [x, y, z] or one number.
      const Vec3 s = m.contains("size") ? get_scale(m["size"], where + ".size") : Vec3(1.0f);
      const Vec3 h = s * 0.5f;
      const Vec3 axes[3] = {{1, 0, 0}, {0, 1, 0}, {0, 0, 1}};
      for (int a = 0; a < 3; ++a) {
        for (float sign : {1.0f, -1.0f}) {
          const Vec3 n = axes[a] * sign;
          const Vec3 u = axes[(a + 1) % 3] * sign, v = axes[(a + 2) % 3];
          const uint32_t b = static_cast<uint32_t>(md.positions.size());
          for (auto [cu, cv] : {std::pair{-1.f, -1.f}, {1.f, -1.f}, {1.f, 1.f}, {-1.f, 1.f}})
            md.positions.push_back((n + u * cu + v * cv) * h);
          md.normals.insert(md.normals.end(), 4, n);
          md.indices.insert(md.indices.end(), {b, b + 1, b + 2, b, b + 2, b + 3});
        }
      }
    } else if (kind == "sphere") {
      const float r = m.contains("radius") ? get_number(m["radius"], where + ".radius") : 1.0f;
      if (!(r > 0)) fail(where + ".radius: must be positive");
      const int seg = m.contains("segments") ? get_int(m["segments"], where + ".segments", 3, 1024) : 32;
      const int rings = std::max(2, seg / 2);
      for (int i = 0; i <= rings; ++i) {
        const float th = kPi * static_cast<float>(i) / static_cast<float>(rings);
        for (int j = 0; j <= seg; ++j) {
          const float ph = 2.0f * kPi * static_cast<float>(j) / static_cast<float>(seg);
          const Vec3 n{std::sin(th) * std::cos(ph), std::cos(th), -std::sin(th) * std::sin(ph)};
          md.positions.push_back(n * r);
          md.normals.push_back(n);
        }
      }
      const uint32_t row = static_cast<uint32_t>(seg + 1);
      for (uint32_t i = 0; i < static_cast<uint32_t>(rings); ++i)
        for (uint32_t j = 0; j < static_cast<uint32_t>(seg); ++j) {
          const uint32_t a = i * row + j, b = a + row;
          md.indices.insert(md.indices.end(), {a, b, b + 1, a, b + 1, a + 1});
        }
    } else {
      fail(where + ".builtin: unknown shape '" + kind + "' (plane, box, sphere)");
    }
    return md;
  }

  // ------------------------------------------------------------------ lights, cameras, sky
  void read_light(const json& l, const std::string& where) {
    if (!l.is_object()) fail(where + ": expected an object");
    check_keys(l, where, {"type", "name", "color", "intensity", "position", "direction", "radius", "samples", "comment"});
    Light out;
    const std::string type = l.contains("type") ? get_string(l["type"], where + ".type") : "point";
    if (type == "point") out.type = LightType::Point;
    else if (type == "directional") out.type = LightType::Directional;
    else if (type == "sphere") out.type = LightType::Sphere;
    else fail(where + ".type: unknown light type '" + type + "' (point, directional, sphere)");
    out.name = l.contains("name") ? get_string(l["name"], where + ".name") : type + std::to_string(scene_.lights.size());
    if (l.contains("color")) out.color = get_color(l["color"], where + ".color");
    if (l.contains("intensity")) out.intensity = get_number(l["intensity"], where + ".intensity");
    if (out.intensity < 0) fail(where + ".intensity: must not be negative");
    if (l.contains("position")) out.position = get_vec3(l["position"], where + ".position");
    if (l.contains("direction")) {
      out.direction = normalize(get_vec3(l["direction"], where + ".direction"));
      if (out.direction == Vec3{}) fail(where + ".direction: must not be zero");
    }
    if (l.contains("radius")) out.radius = get_number(l["radius"], where + ".radius");
    if (out.radius < 0) fail(where + ".radius: must not be negative");
    if (l.contains("samples")) out.samples = get_int(l["samples"], where + ".samples", 1, 4096);
    if (out.type == LightType::Sphere && !(out.radius > 0)) fail(where + ": sphere lights need a positive radius");
    scene_.lights.push_back(out);
  }

  void read_camera(const json& c, const std::string& where) {
    if (!c.is_object()) fail(where + ": expected an object");
    check_keys(c, where, {"name", "position", "target", "up", "fov", "comment"});
    Camera out;
    if (c.contains("name")) {
      out.name = get_string(c["name"], where + ".name");
      if (const auto earlier = scene_.find_camera(out.name))
        fail(where + ".name: '" + out.name + "' is already the name of cameras[" + std::to_string(*earlier) +
             "] (--camera selects cameras by name)");
    } else {
      out.name = detail::unique_camera_name(
          scene_, scene_.cameras.empty() ? std::string("default") : "camera" + std::to_string(scene_.cameras.size()));
    }
    if (c.contains("position")) out.position = get_vec3(c["position"], where + ".position");
    if (c.contains("target")) out.target = get_vec3(c["target"], where + ".target");
    if (c.contains("up")) out.up = get_vec3(c["up"], where + ".up");
    if (c.contains("fov")) out.vfov_degrees = get_number(c["fov"], where + ".fov");
    if (!(out.vfov_degrees > 0 && out.vfov_degrees < 180)) fail(where + ".fov: must be in (0, 180) degrees");
    if (length(out.target - out.position) == 0.0f) fail(where + ": position and target coincide");
    if (length(cross(out.target - out.position, out.up)) == 0.0f) fail(where + ".up: parallel to the view direction or zero");
    scene_.cameras.push_back(out);
  }

  void read_sky(const json& s, const std::string& where) {
    if (!s.is_object()) fail(where + ": expected an object");
    check_keys(s, where, {"type", "color", "horizon", "image", "intensity", "comment"});
    Sky& sky = scene_.sky;
    const std::string type = s.contains("type") ? get_string(s["type"], where + ".type") : "gradient";
    if (type == "constant") sky.type = SkyType::Constant;
    else if (type == "gradient") sky.type = SkyType::Gradient;
    else if (type == "image") sky.type = SkyType::Image;
    else fail(where + ".type: unknown sky type '" + type + "' (constant, gradient, image)");
    if (s.contains("color")) sky.color = get_color(s["color"], where + ".color");
    if (s.contains("horizon")) sky.horizon = get_color(s["horizon"], where + ".horizon");
    if (s.contains("intensity")) sky.intensity = get_number(s["intensity"], where + ".intensity");
    if (sky.type == SkyType::Image) {
      if (!s.contains("image")) fail(where + ": an image sky needs \"image\"");
      const std::string ref = get_string(s["image"], where + ".image");
      std::string why;
      const fs::path p = detail::confined_path(dir_, ref, why);
      if (p.empty()) fail(where + ".image: " + why);
      std::error_code ec;
      if (!fs::is_regular_file(p, ec)) fail(where + ".image: '" + ref + "' " + not_a_file(p));
      sky.image_path = p.string();
    } else if (s.contains("image")) {
      detail::warn(options_, file_ + ": " + where + ".image: ignored for a " + type + " sky");
    }
  }

  fs::path path_;
  std::string file_;
  fs::path dir_;
  const LoadOptions& options_;
  Scene scene_;
  std::map<std::string, uint32_t> material_ids_;
  std::map<std::string, Scene> loaded_;  ///< mesh files by canonical path
  std::map<std::string, uint32_t> material_base_;  ///< first material id of each file's materials
  size_t dropped_ = 0;
};

}  // namespace

Scene load_json_scene(const fs::path& path, const LoadOptions& options) {
  JsonSceneLoader loader(path, options);
  return loader.load();
}

}  // namespace specula
