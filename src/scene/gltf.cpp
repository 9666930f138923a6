// glTF 2.0 (.gltf / .glb) loader on top of tinygltf (prebuilt libtinygltf; no
// TINYGLTF_IMPLEMENTATION here).
//
// Safety: before tinygltf sees the file we check the GLB container ourselves and parse the JSON
// with nlohmann_json (errors carry the byte offset). Every buffer / image URI must be a data:
// URI (its declared byteLength must fit what the URI can decode to) or a relative path that
// stays inside the scene's folder: absolute paths, drive letters, other URI schemes and '..'
// (also percent-encoded) are refused. tinygltf then reads files only through FsCallbacks that
// repeat that confinement check and the size limit; images are never decoded. After loading,
// every index (nodes, meshes, materials, accessors, buffer views, buffers, cameras, lights) and
// every accessor range (offset, stride, count, component type) is validated before it is read.
//
// Material mapping (also in docs/scene-format.md), with base colour b, metallic m, roughness r:
//   diffuse        = b.rgb * (1 - m)
//   specular       = lerp(0.04, b.rgb, m)                       (Schlick F0)
//   phong_exponent = clamp(2 / alpha^2 - 2, 1, 10000), alpha = r^2  (Walter et al. 2007)
//   reflectivity   = m * (1 - r)^2, clamped so reflectivity + transparency <= 1
//   transparency   = KHR_materials_transmission.transmissionFactor; for alphaMode BLEND at
//                    least 1 - b.alpha
//   ior            = KHR_materials_ior.ior; default 1.5 for transmissive materials, else 1
//   absorption     = -ln(attenuationColor) / attenuationDistance (KHR_materials_volume; zero
//                    when the distance is infinite / absent)
//   emission       = emissiveFactor * KHR_materials_emissive_strength.emissiveStrength
// Cameras: perspective yfov -> vfov_degrees; the node's world transform gives position (origin),
// target (position + forward -z) and up (+y). Orthographic cameras are skipped with a warning.
// KHR_lights_punctual: point and spot -> Point light at the node position (spot cone ignored,
// warned once), directional -> Directional along the node's -z; colour and intensity copied
// (candela for point = W/sr here, lux for directional = irradiance).
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <unordered_set>

#pragma GCC diagnostic push
#pragma GCC diagnostic ignored "-Wconversion"
#pragma GCC diagnostic ignored "-Wshadow"
#pragma GCC diagnostic ignored "-Wsign-conversion"
#pragma GCC diagnostic ignored "-Wunused-parameter"
#include <tiny_gltf.h>
#pragma GCC diagnostic pop
#include <nlohmann/json.hpp>

#include "scene/loader_internal.h"
#include "specula/error.h"
#include "specula/load.h"

namespace fs = std::filesystem;

namespace specula {
namespace {

using json = nlohmann::json;

/// Percent-decoding as tinygltf does (dlib::urldecode) so the checks see the real path.
std::string url_decode(const std::string& s) {
  std::string out;
  for (size_t i = 0; i < s.size(); ++i) {
    if (s[i] == '%' && i + 2 < s.size() && std::isxdigit(static_cast<unsigned char>(s[i + 1])) &&
        std::isxdigit(static_cast<unsigned char>(s[i + 2]))) {
      out += static_cast<char>(std::stoi(s.substr(i + 1, 2), nullptr, 16));
      i += 2;
    } else if (s[i] == '+') {
      out += ' ';
    } else {
      out += s[i];
    }
  }
  return out;
}

uint32_t read_u32le(const std::string& d, size_t at) {
  uint32_t v = 0;
  for (int i = 3; i >= 0; --i) v = (v << 8) | static_cast<unsigned char>(d[at + static_cast<size_t>(i)]);
  return v;
}

/// State for the confined file-system callbacks.
struct FsGuard {
  fs::path dir;          ///< canonical scene folder
  InputLimits limits;    ///< max_file_bytes applies to every buffer read
  std::string refusal;   ///< first refusal, reported by the loader
};

bool inside(const FsGuard& g, const std::string& path, fs::path& out) {
  std::error_code ec;
  const fs::path p = fs::weakly_canonical(fs::path(path), ec);
  if (ec) return false;
  const std::string d = g.dir.string(), s = p.string();
  if (s.size() <= d.size() || s.compare(0, d.size(), d) != 0 ||
      (d.back() != '/' && s[d.size()] != '/'))
    return false;
  out = p;
  return true;
}

bool fs_exists(const std::string& path, void* user) {
  auto* g = static_cast<FsGuard*>(user);
  fs::path p;
  std::error_code ec;
  return inside(*g, path, p) && fs::is_regular_file(p, ec);
}

std::string fs_expand(const std::string& path, void*) { return path; }  // no ~ / $VAR expansion

bool fs_read(std::vector<unsigned char>* out, std::string* err, const std::string& path,
             void* user) {
  auto* g = static_cast<FsGuard*>(user);
  fs::path p;
  if (!inside(*g, path, p)) {
    if (g->refusal.empty()) g->refusal = "'" + path + "' is outside " + g->dir.string();
    if (err) *err = "refused";
    return false;
  }
  std::error_code ec;
  const uintmax_t size = fs::file_size(p, ec);
  if (ec) {
    if (err) *err = "cannot read the file size";
    return false;
  }
  if (size > g->limits.max_file_bytes || size >= (uintmax_t{1} << 32)) {
    // tinygltf holds buffers with 32-bit sizes: 4 GiB is a hard ceiling.
    if (g->refusal.empty())
      g->refusal = "'" + path + "': " +
                   (size > g->limits.max_file_bytes ? file_size_refusal(size, g->limits)
                                                    : "buffers of 4 GiB or more are not supported");
    if (err) *err = "refused";
    return false;
  }
  std::ifstream in(p, std::ios::binary);
  if (!in) {
    if (err) *err = "cannot open";
    return false;
  }
  out->resize(static_cast<size_t>(size));
  if (size > 0 && !in.read(reinterpret_cast<char*>(out->data()), static_cast<std::streamsize>(size))) {
    if (err) *err = "read error";
    return false;
  }
  return true;
}

bool fs_write(std::string* err, const std::string&, const std::vector<unsigned char>&, void*) {
  if (err) *err = "writing is disabled";
  return false;
}

bool skip_image(tinygltf::Image*, const int, std::string*, std::string*, int, int,
                const unsigned char*, int, void*) {
  return true;  // textures are not used; never decode untrusted image data
}

class GltfLoader {
 public:
  GltfLoader(const fs::path& path, const LoadOptions& options)
      : path_(path), file_(path.string()), options_(options) {}

  Scene load() {
    const std::string data = detail::read_file(path_, options_.limits);
    if (data.size() >= (uint64_t{1} << 32)) fail("glTF files of 4 GiB or more are not supported");
    const bool binary = data.size() >= 4 && data.compare(0, 4, "glTF") == 0;
    if (detail::lower_extension(path_) == ".glb" && !binary)
      fail("not a binary glTF file (missing 'glTF' magic)");
    std::string json_text;
    if (binary) {
      json_text = check_glb(data);
    } else {
      json_text = data;
    }
    prescan_json(json_text);

    guard_.limits = options_.limits;
    guard_.dir = fs::weakly_canonical(path_.parent_path().empty() ? fs::path(".") : path_.parent_path());
    tinygltf::TinyGLTF ctx;
    ctx.SetFsCallbacks({&fs_exists, &fs_expand, &fs_read, &fs_write, &guard_});
    ctx.SetImageLoader(&skip_image, nullptr);
    std::string err, warn;
    bool ok = false;
    const std::string base_dir = guard_.dir.string();
    try {
      if (binary) {
        ok = ctx.LoadBinaryFromMemory(&model_, &err, &warn,
                                      reinterpret_cast<const unsigned char*>(data.data()),
                                      static_cast<unsigned int>(data.size()), base_dir);
      } else {
        ok = ctx.LoadASCIIFromString(&model_, &err, &warn, data.data(),
                                     static_cast<unsigned int>(data.size()), base_dir);
      }
    } catch (const std::exception& e) {
      fail(std::string("invalid glTF: ") + e.what());
    }
    if (!guard_.refusal.empty()) fail("file reference " + guard_.refusal);
    if (!ok) fail(first_line(err.empty() ? std::string("invalid glTF") : err));
    if (!warn.empty()) detail::warn(options_, file_ + ": " + first_line(warn));

    Scene scene;
    scene.name = path_.stem().string();
    convert(scene);
    return scene;
  }

 private:
  [[noreturn]] void fail(const std::string& what) const { throw file_error(file_, what); }

  static std::string first_line(const std::string& s) {
    std::string line = s.substr(0, s.find('\n'));
    while (!line.empty() && (line.back() == '\r' || line.back() == ' ')) line.pop_back();
    return line.size() > 300 ? line.substr(0, 300) + "..." : line;
  }

  // ------------------------------------------------------------------ container + JSON checks
  std::string check_glb(const std::string& d) const {
    if (d.size() < 20) fail("GLB: " + std::to_string(d.size()) + " bytes, shorter than the 20-byte header");
    const uint32_t version = read_u32le(d, 4), length = read_u32le(d, 8);
    if (version != 2) fail("GLB: version " + std::to_string(version) + " (only 2 is supported)");
    if (length != d.size())
      fail("byte 8: GLB length field " + std::to_string(length) + " differs from the file size " +
           std::to_string(d.size()));
    const uint64_t json_len = read_u32le(d, 12), json_type = read_u32le(d, 16);
    if (json_type != 0x4E4F534Au) fail("byte 16: first GLB chunk is not JSON");
    if (json_len == 0 || 20 + json_len > d.size())
      fail("byte 12: JSON chunk length " + std::to_string(json_len) + " exceeds the file (" +
           std::to_string(d.size()) + " bytes)");
    uint64_t at = 20 + json_len;
    while (at < d.size()) {  // further chunks: length + type + payload must fit
      if (d.size() - at < 8) fail("byte " + std::to_string(at) + ": truncated GLB chunk header");
      const uint64_t len = read_u32le(d, static_cast<size_t>(at));
      if (len > d.size() - at - 8)
        fail("byte " + std::to_string(at) + ": GLB chunk length " + std::to_string(len) +
             " exceeds the file");
      at += 8 + len;
    }
    return d.substr(20, static_cast<size_t>(json_len));
  }

  /// tinygltf converts JSON (extras, extensions) to its Value type recursively, so deeply
  /// nested input would overflow the stack inside the library: refuse it up front.
  void check_nesting(const std::string& text) const {
    constexpr int kMaxDepth = 64;
    int depth = 0;
    bool in_string = false, escaped = false;
    for (size_t i = 0; i < text.size(); ++i) {
      const char c = text[i];
      if (in_string) {
        if (escaped) escaped = false;
        else if (c == '\\') escaped = true;
        else if (c == '"') in_string = false;
      } else if (c == '"') {
        in_string = true;
      } else if (c == '[' || c == '{') {
        if (++depth > kMaxDepth)
          fail("byte " + std::to_string(i) + ": JSON nested deeper than " + std::to_string(kMaxDepth) + " levels");
      } else if (c == ']' || c == '}') {
        --depth;
      }
    }
  }

  void prescan_json(const std::string& text) const {
    check_nesting(text);
    json j;
    try {
      j = json::parse(text);
    } catch (const json::parse_error& e) {
      fail("byte " + std::to_string(e.byte) + ": JSON parse error: " + e.what());
    } catch (const std::exception& e) {
      fail(std::string("JSON parse error: ") + e.what());
    }
    if (!j.is_object()) fail("glTF JSON must be an object");
    if (j.contains("asset") && j["asset"].is_object() && j["asset"].contains("version") &&
        j["asset"]["version"].is_string() && j["asset"]["version"].get<std::string>().rfind("2", 0) != 0)
      fail("glTF version " + j["asset"]["version"].get<std::string>() + " is not supported (only 2.0)");
    const fs::path dir = path_.parent_path();
    auto check_uris = [&](const char* key, bool is_buffer) {
      if (!j.contains(key)) return;
      const json& arr = j[key];
      if (!arr.is_array()) fail(std::string("'") + key + "' must be an array");
      for (size_t i = 0; i < arr.size(); ++i) {
        const json& item = arr[i];
        if (!item.is_object() || !item.contains("uri")) continue;
        const std::string where = std::string(key) + "[" + std::to_string(i) + "].uri: ";
        if (!item["uri"].is_string()) fail(where + "must be a string");
        const std::string uri = item["uri"].get<std::string>();
        if (uri.compare(0, 5, "data:") == 0) {
          const size_t comma = uri.find(',');
          if (comma == std::string::npos || uri.find(";base64", 5) > comma)
            fail(where + "data URI is not base64");
          if (is_buffer && item.contains("byteLength") && item["byteLength"].is_number()) {
            const double want = item["byteLength"].get<double>();
            const double can = static_cast<double>(uri.size() - comma - 1) * 0.75 + 3.0;
            if (!(want >= 0) || want > can) {
              // JSON numbers may be far beyond any integer type (1e47): printed as a double, never
              // converted to one.
              char shown[40];
              std::snprintf(shown, sizeof shown, want < 9007199254740992.0 ? "%.0f" : "%.6g", want);
              fail(where + "byteLength " + shown + " exceeds what the data URI holds (" +
                   std::to_string(static_cast<uint64_t>(can)) + " bytes at most)");
            }
          }
          continue;
        }
        std::string why;
        if (detail::confined_path(dir, url_decode(uri), why).empty()) fail(where + why);
      }
    };
    if (j.contains("extensionsRequired") && j["extensionsRequired"].is_array()) {
      for (const json& e : j["extensionsRequired"]) {
        if (!e.is_string()) continue;
        const std::string name = e.get<std::string>();
        if (name == "KHR_draco_mesh_compression" || name == "EXT_meshopt_compression" ||
            name == "KHR_meshopt_compression")
          fail("requires the unsupported geometry compression extension " + name);
        static const char* const known[] = {
            "KHR_lights_punctual", "KHR_materials_transmission", "KHR_materials_ior",
            "KHR_materials_volume", "KHR_materials_emissive_strength", "KHR_mesh_quantization",
            "KHR_texture_transform", "KHR_materials_unlit"};
        if (std::find(std::begin(known), std::end(known), name) == std::end(known))
          detail::warn(options_, file_ + ": required extension " + name + " is not supported; ignored");
      }
    }
    check_uris("buffers", true);
    check_uris("images", false);
  }

  // ------------------------------------------------------------------ accessors
  struct View {
    const unsigned char* base = nullptr;
    size_t stride = 0;
    size_t count = 0;
    int comp = 0;
    int ncomp = 0;
    bool normalized = false;
  };

  static size_t comp_size(int c) {
    switch (c) {
      case TINYGLTF_COMPONENT_TYPE_BYTE: case TINYGLTF_COMPONENT_TYPE_UNSIGNED_BYTE: return 1;
      case TINYGLTF_COMPONENT_TYPE_SHORT: case TINYGLTF_COMPONENT_TYPE_UNSIGNED_SHORT: return 2;
      case TINYGLTF_COMPONENT_TYPE_INT: case TINYGLTF_COMPONENT_TYPE_UNSIGNED_INT:
      case TINYGLTF_COMPONENT_TYPE_FLOAT: return 4;
      case TINYGLTF_COMPONENT_TYPE_DOUBLE: return 8;
      default: return 0;
    }
  }

  View view(int index, int want_type, const std::string& what) const {
    const std::string w = what + " accessor " + std::to_string(index) + ": ";
    if (index < 0 || static_cast<size_t>(index) >= model_.accessors.size())
      fail(what + ": accessor index " + std::to_string(index) + " out of range (" +
           std::to_string(model_.accessors.size()) + " accessors)");
    const tinygltf::Accessor& a = model_.accessors[static_cast<size_t>(index)];
    if (a.sparse.isSparse) fail(w + "sparse accessors are not supported");
    if (a.type != want_type)
      fail(w + "has type " + std::to_string(a.type) + ", expected " + std::to_string(want_type));
    const size_t cs = comp_size(a.componentType);
    if (cs == 0) fail(w + "invalid componentType " + std::to_string(a.componentType));
    View v;
    v.comp = a.componentType;
    v.ncomp = want_type == TINYGLTF_TYPE_SCALAR ? 1 : want_type;  // VEC2/3/4 == 2/3/4
    v.normalized = a.normalized;
    v.count = a.count;
    detail::check_elements(options_.limits, file_, w + "count: ", a.count,
                           want_type == TINYGLTF_TYPE_SCALAR ? detail::Elements::Indices : detail::Elements::Vertices);
    if (a.count == 0) return v;
    if (a.bufferView < 0 || static_cast<size_t>(a.bufferView) >= model_.bufferViews.size())
      fail(w + "bufferView " + std::to_string(a.bufferView) + " out of range");
    const tinygltf::BufferView& bv = model_.bufferViews[static_cast<size_t>(a.bufferView)];
    if (bv.buffer < 0 || static_cast<size_t>(bv.buffer) >= model_.buffers.size())
      fail(w + "bufferView " + std::to_string(a.bufferView) + ": buffer " +
           std::to_string(bv.buffer) + " out of range");
    const tinygltf::Buffer& buf = model_.buffers[static_cast<size_t>(bv.buffer)];
    const uint64_t buf_size = buf.data.size();
    if (bv.byteOffset > buf_size || bv.byteLength > buf_size - bv.byteOffset)
      fail(w + "bufferView " + std::to_string(a.bufferView) + " (offset " +
           std::to_string(bv.byteOffset) + ", length " + std::to_string(bv.byteLength) +
           ") exceeds buffer " + std::to_string(bv.buffer) + " (" + std::to_string(buf_size) +
           " bytes)");
    const uint64_t elem = cs * static_cast<uint64_t>(v.ncomp);
    const uint64_t stride = bv.byteStride ? bv.byteStride : elem;
    if (stride < elem) fail(w + "byteStride " + std::to_string(bv.byteStride) + " smaller than the element size " + std::to_string(elem));
    if (a.byteOffset > bv.byteLength || bv.byteLength - a.byteOffset < elem ||
        (a.count - 1) > (bv.byteLength - a.byteOffset - elem) / stride)
      fail(w + std::to_string(a.count) + " elements at offset " + std::to_string(a.byteOffset) +
           " with stride " + std::to_string(stride) + " exceed bufferView " +
           std::to_string(a.bufferView) + " (" + std::to_string(bv.byteLength) + " bytes)");
    v.base = buf.data.data() + bv.byteOffset + a.byteOffset;
    v.stride = static_cast<size_t>(stride);
    return v;
  }

  static double component(const View& v, size_t i, int c) {
    const unsigned char* p = v.base + i * v.stride + static_cast<size_t>(c) * comp_size(v.comp);
    switch (v.comp) {
      case TINYGLTF_COMPONENT_TYPE_BYTE: { int8_t x; std::memcpy(&x, p, 1); return v.normalized ? std::max(x / 127.0, -1.0) : x; }
      case TINYGLTF_COMPONENT_TYPE_UNSIGNED_BYTE: { uint8_t x = *p; return v.normalized ? x / 255.0 : x; }
      case TINYGLTF_COMPONENT_TYPE_SHORT: { int16_t x; std::memcpy(&x, p, 2); return v.normalized ? std::max(x / 32767.0, -1.0) : x; }
      case TINYGLTF_COMPONENT_TYPE_UNSIGNED_SHORT: { uint16_t x; std::memcpy(&x, p, 2); return v.normalized ? x / 65535.0 : x; }
      case TINYGLTF_COMPONENT_TYPE_INT: { int32_t x; std::memcpy(&x, p, 4); return x; }
      case TINYGLTF_COMPONENT_TYPE_UNSIGNED_INT: { uint32_t x; std::memcpy(&x, p, 4); return x; }
      case TINYGLTF_COMPONENT_TYPE_FLOAT: { float x; std::memcpy(&x, p, 4); return static_cast<double>(x); }
      case TINYGLTF_COMPONENT_TYPE_DOUBLE: { double x; std::memcpy(&x, p, 8); return x; }
      default: return 0.0;
    }
  }

  std::vector<Vec3> read_vec3(int index, const std::string& what) const {
    const View v = view(index, TINYGLTF_TYPE_VEC3, what);
    std::vector<Vec3> out(v.count);
    for (size_t i = 0; i < v.count; ++i)
      out[i] = {static_cast<float>(component(v, i, 0)), static_cast<float>(component(v, i, 1)),
                static_cast<float>(component(v, i, 2))};
    return out;
  }

  // ------------------------------------------------------------------ materials
  static const tinygltf::Value* ext(const tinygltf::ExtensionMap& m, const char* name) {
    const auto it = m.find(name);
    return (it != m.end() && it->second.IsObject()) ? &it->second : nullptr;
  }
  static bool number(const tinygltf::Value* obj, const char* key, double& out) {
    if (!obj || !obj->Has(key)) return false;
    const tinygltf::Value& v = obj->Get(key);
    if (!v.IsNumber()) return false;
    const double d = v.GetNumberAsDouble();
    if (!std::isfinite(d)) return false;
    out = d;
    return true;
  }
  static bool color3(const tinygltf::Value* obj, const char* key, Vec3& out) {
    if (!obj || !obj->Has(key)) return false;
    const tinygltf::Value& v = obj->Get(key);
    if (!v.IsArray() || v.ArrayLen() < 3) return false;
    for (int i = 0; i < 3; ++i) {
      if (!v.Get(i).IsNumber()) return false;
      out[i] = static_cast<float>(v.Get(i).GetNumberAsDouble());
    }
    return is_finite(out);
  }
  static float fin(double v, double fallback) {
    return static_cast<float>(std::isfinite(v) ? v : fallback);
  }

  Material convert_material(const tinygltf::Material& gm, size_t index) const {
    Material m;
    m.name = gm.name.empty() ? "material" + std::to_string(index) : gm.name;
    const auto& pbr = gm.pbrMetallicRoughness;
    Vec3 base{0.8f, 0.8f, 0.8f};
    float alpha = 1.0f;
    if (pbr.baseColorFactor.size() == 4) {
      base = {fin(pbr.baseColorFactor[0], 1), fin(pbr.baseColorFactor[1], 1), fin(pbr.baseColorFactor[2], 1)};
      alpha = std::clamp(fin(pbr.baseColorFactor[3], 1), 0.0f, 1.0f);
    }
    const float metal = std::clamp(fin(pbr.metallicFactor, 1), 0.0f, 1.0f);
    const float rough = std::clamp(fin(pbr.roughnessFactor, 1), 0.0f, 1.0f);
    m.diffuse = base * (1.0f - metal);
    m.specular = lerp(Vec3(0.04f), base, metal);
    const float a = std::max(rough * rough, 1e-4f);
    m.phong_exponent = std::clamp(2.0f / (a * a) - 2.0f, 1.0f, 10000.0f);
    float reflectivity = metal * (1.0f - rough) * (1.0f - rough);

    double v = 0.0;
    float transparency = 0.0f;
    if (number(ext(gm.extensions, "KHR_materials_transmission"), "transmissionFactor", v))
      transparency = std::clamp(static_cast<float>(v), 0.0f, 1.0f);
    if (gm.alphaMode == "BLEND") transparency = std::max(transparency, 1.0f - alpha);
    m.transparency = transparency;
    m.reflectivity = std::min(reflectivity, 1.0f - transparency);
    m.ior = transparency > 0.0f ? 1.5f : 1.0f;
    if (number(ext(gm.extensions, "KHR_materials_ior"), "ior", v) && v > 0.0)
      m.ior = static_cast<float>(v);
    if (const tinygltf::Value* vol = ext(gm.extensions, "KHR_materials_volume")) {
      Vec3 color{1, 1, 1};
      double dist = 0.0;
      color3(vol, "attenuationColor", color);
      if (number(vol, "attenuationDistance", dist) && dist > 0.0) {
        for (int i = 0; i < 3; ++i)
          m.absorption[i] = static_cast<float>(
              -std::log(std::clamp(static_cast<double>(color[i]), 1e-6, 1.0)) / dist);
      }
    }
    if (gm.emissiveFactor.size() == 3)
      m.emission = {fin(gm.emissiveFactor[0], 0), fin(gm.emissiveFactor[1], 0), fin(gm.emissiveFactor[2], 0)};
    if (number(ext(gm.extensions, "KHR_materials_emissive_strength"), "emissiveStrength", v) && v >= 0.0)
      m.emission *= static_cast<float>(v);
    return m;
  }

  // ------------------------------------------------------------------ nodes
  static Mat4 local_transform(const tinygltf::Node& n) {
    if (n.matrix.size() == 16) {
      Mat4 r;
      for (size_t row = 0; row < 4; ++row)
        for (size_t col = 0; col < 4; ++col)  // glTF matrices are column-major
          r.m[row * 4 + col] = static_cast<float>(n.matrix[col * 4 + row]);
      return r;
    }
    Mat4 t, r, s;
    if (n.translation.size() == 3)
      t = Mat4::translate({static_cast<float>(n.translation[0]), static_cast<float>(n.translation[1]),
                           static_cast<float>(n.translation[2])});
    if (n.rotation.size() == 4) {
      double q[4] = {n.rotation[0], n.rotation[1], n.rotation[2], n.rotation[3]};
      const double len = std::sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]);
      if (len > 0 && std::isfinite(len)) {
        for (double& c : q) c /= len;
        r = Mat4::from_quaternion(static_cast<float>(q[0]), static_cast<float>(q[1]),
                                  static_cast<float>(q[2]), static_cast<float>(q[3]));
      }
    }
    if (n.scale.size() == 3)
      s = Mat4::scale({static_cast<float>(n.scale[0]), static_cast<float>(n.scale[1]),
                       static_cast<float>(n.scale[2])});
    return t * r * s;
  }

  void convert(Scene& scene) {
    const size_t nn = model_.nodes.size();
    for (size_t i = 0; i < model_.materials.size(); ++i)
      scene.add_material(convert_material(model_.materials[i], i));
    const uint32_t default_material = scene.add_material(Material{});

    // Validate the node graph and pick the roots.
    for (size_t i = 0; i < nn; ++i)
      for (int c : model_.nodes[i].children)
        if (c < 0 || static_cast<size_t>(c) >= nn)
          fail("node " + std::to_string(i) + ": child " + std::to_string(c) + " out of range (" +
               std::to_string(nn) + " nodes)");
    std::vector<int> roots;
    if (!model_.scenes.empty()) {
      int si = model_.defaultScene;
      if (si < 0 || static_cast<size_t>(si) >= model_.scenes.size()) si = 0;
      roots = model_.scenes[static_cast<size_t>(si)].nodes;
      for (int r : roots)
        if (r < 0 || static_cast<size_t>(r) >= nn)
          fail("scene " + std::to_string(si) + ": node " + std::to_string(r) + " out of range (" +
               std::to_string(nn) + " nodes)");
    } else {
      std::vector<uint8_t> is_child(nn, 0);
      for (const auto& n : model_.nodes)
        for (int c : n.children) is_child[static_cast<size_t>(c)] = 1;
      for (size_t i = 0; i < nn; ++i)
        if (!is_child[i]) roots.push_back(static_cast<int>(i));
      if (roots.empty() && nn > 0) fail("node hierarchy is cyclic (no root node)");
    }

    // Iterative depth-first walk; on_path detects cycles, the visit cap bounds instancing.
    struct Item { int node; Mat4 parent; bool leave; };
    std::vector<uint8_t> on_path(nn, 0);
    std::vector<Item> stack;
    for (auto it = roots.rbegin(); it != roots.rend(); ++it) stack.push_back({*it, Mat4::identity(), false});
    size_t visits = 0, dropped = 0;
    bool warned_spot = false;
    while (!stack.empty()) {
      const Item item = stack.back();
      stack.pop_back();
      const size_t ni = static_cast<size_t>(item.node);
      if (item.leave) {
        on_path[ni] = 0;
        continue;
      }
      if (on_path[ni]) fail("node " + std::to_string(ni) + ": cyclic node hierarchy");
      if (++visits > (size_t{1} << 20)) fail("node hierarchy instantiates more than 2^20 nodes");
      on_path[ni] = 1;
      const tinygltf::Node& node = model_.nodes[ni];
      const Mat4 world = item.parent * local_transform(node);
      stack.push_back({item.node, Mat4::identity(), true});
      for (auto c = node.children.rbegin(); c != node.children.rend(); ++c)
        stack.push_back({*c, world, false});

      if (node.mesh >= 0) add_mesh(scene, node, ni, world, default_material, dropped);
      else if (node.mesh < -1) fail("node " + std::to_string(ni) + ": mesh index " + std::to_string(node.mesh) + " out of range");
      if (node.camera >= 0) add_camera(scene, node, ni, world);
      if (const tinygltf::Value* lp = ext(node.extensions, "KHR_lights_punctual")) {
        double li = -1;
        if (!number(lp, "light", li) || li < 0 || li >= static_cast<double>(model_.lights.size()))
          fail("node " + std::to_string(ni) + ": KHR_lights_punctual light index out of range");
        const tinygltf::Light& gl = model_.lights[static_cast<size_t>(li)];
        Light l;
        l.name = !gl.name.empty() ? gl.name : (!node.name.empty() ? node.name : "light" + std::to_string(static_cast<int>(li)));
        if (gl.color.size() == 3) l.color = {fin(gl.color[0], 1), fin(gl.color[1], 1), fin(gl.color[2], 1)};
        l.intensity = std::max(fin(gl.intensity, 1), 0.0f);
        l.position = world.transform_point({0, 0, 0});
        if (gl.type == "directional") {
          l.type = LightType::Directional;
          const Vec3 d = normalize(world.transform_vector({0, 0, -1}));
          l.direction = d == Vec3{} ? Vec3{0, -1, 0} : d;
        } else {
          if (gl.type == "spot" && !warned_spot) {
            detail::warn(options_, file_ + ": spot lights are approximated by point lights");
            warned_spot = true;
          } else if (gl.type != "point" && gl.type != "spot") {
            detail::warn(options_, file_ + ": unknown light type '" + gl.type + "' treated as point");
          }
          l.type = LightType::Point;
        }
        if (is_finite(l.position) && is_finite(l.direction)) scene.lights.push_back(l);
      }
    }
    if (skipped_modes_ > 0)
      detail::warn(options_, file_ + ": skipped " + std::to_string(skipped_modes_) +
                                 " primitive(s) that are not triangles (points/lines)");
    detail::warn_dropped(options_, file_, dropped);
    if (scene.triangle_count() == 0)
      fail(model_.meshes.empty() ? "no meshes (empty glTF scene)"
           : skipped_modes_ > 0  ? "no triangles (only point / line primitives)"
           : dropped > 0         ? "no triangles left after dropping those with non-finite vertices"
                                 : "no triangles in the scene");
    add_default_camera_and_light(scene);
    detail::validate_scene(scene, file_);
  }

  void add_mesh(Scene& scene, const tinygltf::Node& node, size_t ni, const Mat4& world,
                uint32_t default_material, size_t& dropped) {
    if (static_cast<size_t>(node.mesh) >= model_.meshes.size())
      fail("node " + std::to_string(ni) + ": mesh " + std::to_string(node.mesh) +
           " out of range (" + std::to_string(model_.meshes.size()) + " meshes)");
    const tinygltf::Mesh& mesh = model_.meshes[static_cast<size_t>(node.mesh)];
    for (size_t pi = 0; pi < mesh.primitives.size(); ++pi) {
      const tinygltf::Primitive& prim = mesh.primitives[pi];
      const std::string what = "mesh " + std::to_string(node.mesh) + " primitive " + std::to_string(pi);
      if (prim.mode != TINYGLTF_MODE_TRIANGLES && prim.mode != TINYGLTF_MODE_TRIANGLE_STRIP &&
          prim.mode != TINYGLTF_MODE_TRIANGLE_FAN && prim.mode != -1) {
        ++skipped_modes_;
        continue;
      }
      const auto pos_it = prim.attributes.find("POSITION");
      if (pos_it == prim.attributes.end()) fail(what + ": no POSITION attribute");
      detail::MeshData md;
      md.name = (mesh.name.empty() ? "mesh" + std::to_string(node.mesh) : mesh.name) +
                (mesh.primitives.size() > 1 ? "/" + std::to_string(pi) : "");
      // Bound the output before reading: node instancing could otherwise multiply memory.
      {
        const auto& acc = model_.accessors;
        const int pa = pos_it->second;
        const uint64_t nv_in = (pa >= 0 && static_cast<size_t>(pa) < acc.size()) ? acc[static_cast<size_t>(pa)].count : 0;
        const uint64_t ni_in = (prim.indices >= 0 && static_cast<size_t>(prim.indices) < acc.size())
                                   ? acc[static_cast<size_t>(prim.indices)].count : nv_in;
        const bool fanned = prim.mode == TINYGLTF_MODE_TRIANGLE_STRIP || prim.mode == TINYGLTF_MODE_TRIANGLE_FAN;
        const uint64_t ni_out = fanned ? (ni_in >= 3 ? 3 * (ni_in - 2) : 0) : ni_in / 3 * 3;  // as converted below
        detail::check_elements(options_.limits, file_, what + ": ", scene.positions.size() + nv_in,
                               detail::Elements::Vertices);
        detail::check_elements(options_.limits, file_, what + ": ", scene.indices.size() + ni_out,
                               detail::Elements::Indices);
      }
      md.positions = read_vec3(pos_it->second, what + " POSITION");
      const auto nrm_it = prim.attributes.find("NORMAL");
      if (nrm_it != prim.attributes.end()) {
        md.normals = read_vec3(nrm_it->second, what + " NORMAL");
        if (md.normals.size() != md.positions.size()) {
          detail::warn(options_, file_ + ": " + what + ": NORMAL count differs from POSITION count; normals computed");
          md.normals.clear();
        }
      }
      std::vector<uint32_t> idx;
      const size_t nv = md.positions.size();
      if (prim.indices >= 0) {
        const View v = view(prim.indices, TINYGLTF_TYPE_SCALAR, what + " indices");
        if (v.comp == TINYGLTF_COMPONENT_TYPE_FLOAT || v.comp == TINYGLTF_COMPONENT_TYPE_DOUBLE)
          fail(what + ": indices must have an integer component type");
        idx.resize(v.count);
        for (size_t i = 0; i < v.count; ++i) {
          const double x = component(v, i, 0);
          if (x < 0 || x >= static_cast<double>(nv))
            fail(what + ": index " + std::to_string(i) + " = " + std::to_string(static_cast<long long>(x)) +
                 " out of range (" + std::to_string(nv) + " vertices)");
          idx[i] = static_cast<uint32_t>(x);
        }
      } else if (prim.indices < -1) {
        fail(what + ": indices accessor " + std::to_string(prim.indices) + " out of range");
      } else {
        idx.resize(nv);
        for (size_t i = 0; i < nv; ++i) idx[i] = static_cast<uint32_t>(i);
      }
      if (prim.mode == TINYGLTF_MODE_TRIANGLE_STRIP) {
        for (size_t i = 2; i < idx.size(); ++i) {
          if (i % 2 == 0) md.indices.insert(md.indices.end(), {idx[i - 2], idx[i - 1], idx[i]});
          else md.indices.insert(md.indices.end(), {idx[i - 1], idx[i - 2], idx[i]});
        }
      } else if (prim.mode == TINYGLTF_MODE_TRIANGLE_FAN) {
        for (size_t i = 2; i < idx.size(); ++i) md.indices.insert(md.indices.end(), {idx[0], idx[i - 1], idx[i]});
      } else {
        idx.resize(idx.size() / 3 * 3);
        md.indices = std::move(idx);
      }
      if (md.indices.empty()) continue;
      uint32_t mat = default_material;
      if (prim.material >= 0) {
        if (static_cast<size_t>(prim.material) >= model_.materials.size())
          fail(what + ": material " + std::to_string(prim.material) + " out of range (" +
               std::to_string(model_.materials.size()) + " materials)");
        mat = static_cast<uint32_t>(prim.material);
      }
      detail::check_elements(options_.limits, file_, what + ": ", scene.indices.size() + md.indices.size(),
                             detail::Elements::Indices);
      detail::append_mesh(scene, std::move(md), mat, world, dropped);
    }
  }

  void add_camera(Scene& scene, const tinygltf::Node& node, size_t ni, const Mat4& world) {
    if (static_cast<size_t>(node.camera) >= model_.cameras.size())
      fail("node " + std::to_string(ni) + ": camera " + std::to_string(node.camera) +
           " out of range (" + std::to_string(model_.cameras.size()) + " cameras)");
    const tinygltf::Camera& gc = model_.cameras[static_cast<size_t>(node.camera)];
    if (gc.type != "perspective") {
      detail::warn(options_, file_ + ": camera " + std::to_string(node.camera) + " is " + gc.type +
                                 "; only perspective cameras are supported, skipped");
      return;
    }
    Camera c;
    const std::string given = !gc.name.empty() ? gc.name
                                               : (!node.name.empty() ? node.name : "camera" + std::to_string(node.camera));
    c.name = detail::unique_camera_name(scene, given);
    if (c.name != given)
      detail::warn(options_, file_ + ": node " + std::to_string(ni) + ": camera name '" + given +
                                 "' is taken by an earlier camera; this one is '" + c.name + "'");
    const double yfov = gc.perspective.yfov;
    c.vfov_degrees = (std::isfinite(yfov) && yfov > 0 && yfov < kPi)
                         ? static_cast<float>(yfov * 180.0 / 3.14159265358979323846)
                         : 45.0f;
    c.position = world.transform_point({0, 0, 0});
    const Vec3 fwd = normalize(world.transform_vector({0, 0, -1}));
    const Vec3 up = normalize(world.transform_vector({0, 1, 0}));
    c.target = c.position + (fwd == Vec3{} ? Vec3{0, 0, -1} : fwd);
    c.up = up == Vec3{} ? Vec3{0, 1, 0} : up;
    if (is_finite(c.position) && is_finite(c.target)) scene.cameras.push_back(c);
  }

  fs::path path_;
  std::string file_;
  const LoadOptions& options_;
  tinygltf::Model model_;
  FsGuard guard_;
  size_t skipped_modes_ = 0;
};

}  // namespace

Scene load_gltf(const fs::path& path, const LoadOptions& options) {
  GltfLoader loader(path, options);
  return loader.load();
}

}  // namespace specula
