// Stanford PLY reader: ascii, binary_little_endian and binary_big_endian.
//
// Reads element "vertex" (x, y, z and optional nx, ny, nz, any scalar type), element "face"
// (list "vertex_indices" or "vertex_index", any count / index type; polygons are fanned in
// order as (0,1,2), (0,2,3), ...) and element "tristrips" (list "vertex_indices", -1 restarts a
// strip, odd triangles of a strip have their first two vertices swapped to keep the winding).
// Every other element and property, lists included, is skipped. The whole file is in memory and
// every read is bounds-checked; element counts are checked against the bytes left in the file
// (64-bit arithmetic) before anything is reserved, and vertex / index counts are limited
// (InputLimits::max_elements, 2^31 by default).
// Errors name the file, the element, the element's index and a line (ascii) or byte offset.
#include <algorithm>
#include <array>
#include <charconv>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <limits>
#include <optional>

#include "scene/loader_internal.h"
#include "specula/error.h"
#include "specula/load.h"

namespace fs = std::filesystem;

namespace specula {
namespace {

enum class Format { Ascii, BinaryLE, BinaryBE };
enum class Type : uint8_t { I8, U8, I16, U16, I32, U32, F32, F64 };

size_t type_size(Type t) {
  switch (t) {
    case Type::I8: case Type::U8: return 1;
    case Type::I16: case Type::U16: return 2;
    case Type::I32: case Type::U32: case Type::F32: return 4;
    case Type::F64: return 8;
  }
  return 1;
}

std::optional<Type> parse_type(const std::string& s) {
  if (s == "char" || s == "int8") return Type::I8;
  if (s == "uchar" || s == "uint8") return Type::U8;
  if (s == "short" || s == "int16") return Type::I16;
  if (s == "ushort" || s == "uint16") return Type::U16;
  if (s == "int" || s == "int32") return Type::I32;
  if (s == "uint" || s == "uint32") return Type::U32;
  if (s == "float" || s == "float32") return Type::F32;
  if (s == "double" || s == "float64") return Type::F64;
  return std::nullopt;
}

bool is_integer_type(Type t) { return t != Type::F32 && t != Type::F64; }

struct Property {
  std::string name;
  Type type = Type::F32;
  bool is_list = false;
  Type count_type = Type::U8;
};

struct Element {
  std::string name;
  uint64_t count = 0;
  std::vector<Property> props;
  int header_line = 0;
};

/// Splits a header line into whitespace-separated words.
std::vector<std::string> words(const std::string& line) {
  std::vector<std::string> out;
  size_t i = 0;
  while (i < line.size()) {
    while (i < line.size() && (line[i] == ' ' || line[i] == '\t' || line[i] == '\r')) ++i;
    size_t j = i;
    while (j < line.size() && line[j] != ' ' && line[j] != '\t' && line[j] != '\r') ++j;
    if (j > i) out.push_back(line.substr(i, j - i));
    i = j;
  }
  return out;
}

class PlyReader {
 public:
  PlyReader(const fs::path& path, const LoadOptions& options)
      : path_(path), file_(path.string()), options_(options) {}

  Scene load() {
    data_ = detail::read_file(path_, options_.limits);
    parse_header();
    read_body();
    if (polygons_skipped_ > 0)
      detail::warn(options_, file_ + ": skipped " + with_thousands(polygons_skipped_) +
                                 " face(s) with fewer than 3 vertices");
    Scene scene;
    scene.name = path_.stem().string();
    const uint32_t mat = scene.add_material(Material{});
    if (mesh_.indices.empty()) throw file_error(file_, "no triangles (no faces or tristrips)");
    if (has_normals_) mesh_.normals = std::move(normals_);
    mesh_.name = scene.name;
    size_t dropped = 0;
    detail::append_mesh(scene, std::move(mesh_), mat, Mat4::identity(), dropped);
    detail::warn_dropped(options_, file_, dropped);
    if (scene.triangle_count() == 0)
      throw file_error(file_, "no triangles left after dropping those with non-finite vertices");
    add_default_camera_and_light(scene);
    detail::validate_scene(scene, file_);
    return scene;
  }

 private:
  [[noreturn]] void fail(const std::string& what) const { throw file_error(file_, what); }

  // ------------------------------------------------------------------------------- header
  void parse_header() {
    size_t pos = 0;
    int line_no = 0;
    auto next_line = [&](std::string& line) {
      if (pos >= data_.size()) return false;
      size_t end = data_.find('\n', pos);
      if (end == std::string::npos) end = data_.size();
      if (end - pos > 4096) fail("line " + std::to_string(line_no + 1) + ": header line too long");
      line.assign(data_, pos, end - pos);
      if (!line.empty() && line.back() == '\r') line.pop_back();
      pos = std::min(end + 1, data_.size());
      ++line_no;
      return true;
    };
    std::string line;
    if (!next_line(line) || line != "ply") fail("not a PLY file (missing 'ply' magic)");
    bool have_format = false, ended = false;
    while (next_line(line)) {
      const std::vector<std::string> w = words(line);
      const std::string where = "line " + std::to_string(line_no) + ": ";
      if (w.empty()) continue;
      if (w[0] == "end_header") {
        ended = true;
        break;
      }
      if (w[0] == "comment" || w[0] == "obj_info") continue;
      if (w[0] == "format") {
        if (w.size() < 3) fail(where + "malformed format line");
        if (w[1] == "ascii") format_ = Format::Ascii;
        else if (w[1] == "binary_little_endian") format_ = Format::BinaryLE;
        else if (w[1] == "binary_big_endian") format_ = Format::BinaryBE;
        else fail(where + "unknown format '" + w[1] + "'");
        if (w[2] != "1.0" && w[2] != "1") fail(where + "unsupported PLY version '" + w[2] + "'");
        have_format = true;
      } else if (w[0] == "element") {
        if (w.size() != 3) fail(where + "malformed element line");
        Element e;
        e.name = w[1];
        e.header_line = line_no;
        const char* b = w[2].data();
        const auto [p, ec] = std::from_chars(b, b + w[2].size(), e.count);
        if (ec != std::errc() || p != b + w[2].size())
          fail(where + "element '" + e.name + "': bad count '" + w[2] + "'");
        elements_.push_back(std::move(e));
      } else if (w[0] == "property") {
        if (elements_.empty()) fail(where + "property before any element");
        Property prop;
        if (w.size() >= 2 && w[1] == "list") {
          if (w.size() != 5) fail(where + "malformed list property");
          const auto ct = parse_type(w[2]), it = parse_type(w[3]);
          if (!ct || !it) fail(where + "unknown property type in '" + line + "'");
          if (!is_integer_type(*ct)) fail(where + "list count type must be an integer type");
          prop.is_list = true;
          prop.count_type = *ct;
          prop.type = *it;
          prop.name = w[4];
        } else {
          if (w.size() != 3) fail(where + "malformed property line");
          const auto t = parse_type(w[1]);
          if (!t) fail(where + "unknown property type '" + w[1] + "'");
          prop.type = *t;
          prop.name = w[2];
        }
        elements_.back().props.push_back(std::move(prop));
      } else {
        // Some exporters write free text into the header (e.g. "Created by Blender3D 247").
        if (unknown_header_lines_++ == 0)
          detail::warn(options_, file_ + ": " + where + "unknown header line ignored: '" +
                                     line.substr(0, 60) + "'");
      }
    }
    if (!ended) fail("header has no end_header");
    if (!have_format) fail("header has no format line");
    body_ = pos;
    check_counts();
  }

  /// Enforces the size limits from the header alone, before any allocation.
  void check_counts() {
    const uint64_t available = data_.size() - body_;
    uint64_t needed = 0;  // minimum bytes the body must have
    bool have_vertex = false;
    for (const Element& e : elements_) {
      if (e.name == "vertex") {
        if (have_vertex) fail("element 'vertex' declared twice");
        have_vertex = true;
        detail::check_elements(options_.limits, file_, "element 'vertex': ", e.count, detail::Elements::Vertices);
        vertex_count_ = e.count;
        const auto find = [&](const char* n) -> int {
          for (size_t i = 0; i < e.props.size(); ++i)
            if (e.props[i].name == n && !e.props[i].is_list) return static_cast<int>(i);
          return -1;
        };
        xyz_ = {find("x"), find("y"), find("z")};
        nxyz_ = {find("nx"), find("ny"), find("nz")};
        if (xyz_[0] < 0 || xyz_[1] < 0 || xyz_[2] < 0)
          fail("element 'vertex' (line " + std::to_string(e.header_line) +
               "): needs scalar properties x, y and z");
        has_normals_ = nxyz_[0] >= 0 && nxyz_[1] >= 0 && nxyz_[2] >= 0;
      }
      if (e.count > 0 && e.props.empty())
        fail("element '" + e.name + "' has " + with_thousands(e.count) + " entries but no properties");
      // Minimum bytes per entry: binary = scalar sizes + list count sizes; ascii = one
      // character plus one separator per value (the last value may omit the separator).
      uint64_t per = 0;
      for (const Property& p : e.props)
        per += format_ == Format::Ascii ? 2 : type_size(p.is_list ? p.count_type : p.type);
      const uint64_t slack = format_ == Format::Ascii ? 1 : 0;  // see read_count
      if (e.count > 0) {
        if (per > 0 && e.count > (available + slack) / per)
          fail("element '" + e.name + "' claims " + with_thousands(e.count) +
               " entries, more than the " + with_thousands(available) +
               " bytes after the header can hold");
        needed += e.count * per;
        if (needed > available + slack)
          fail("element '" + e.name + "': the declared element counts need at least " +
               with_thousands(needed) + " bytes but only " + with_thousands(available) +
               " follow the header");
      }
    }
    if (!have_vertex) fail("no 'vertex' element");
  }

  // ------------------------------------------------------------------------------- body
  void read_body() {
    cur_ = body_;
    // Line number of the first body line (ascii messages).
    line_ = 1 + static_cast<int64_t>(std::count(data_.begin(), data_.begin() + static_cast<std::ptrdiff_t>(body_), '\n'));
    for (const Element& e : elements_) {
      if (e.name == "vertex") {
        read_vertices(e);
      } else if (e.name == "face" || e.name == "tristrips") {
        read_faces(e, e.name == "tristrips");
      } else {
        for (uint64_t i = 0; i < e.count; ++i)
          for (const Property& p : e.props) skip_property(e, i, p);
      }
    }
  }

  std::string where(const Element& e, uint64_t i) const {
    std::string s = format_ == Format::Ascii ? "line " + std::to_string(line_)
                                             : "byte " + std::to_string(cur_);
    return s + ": element '" + e.name + "' " + std::to_string(i) + ": ";
  }

  /// Reads one scalar of type \p t at the cursor.
  double read_value(Type t, const Element& e, uint64_t i) {
    if (format_ == Format::Ascii) return read_ascii(t, e, i);
    const size_t n = type_size(t);
    if (cur_ > data_.size() || data_.size() - cur_ < n)
      fail(where(e, i) + "unexpected end of file (truncated data)");
    unsigned char b[8];
    std::memcpy(b, data_.data() + cur_, n);
    cur_ += n;
    const bool little = format_ == Format::BinaryLE;
    if (!little) std::reverse(b, b + n);  // host is little-endian (x86-64 / arm64)
    switch (t) {
      case Type::I8: { int8_t v; std::memcpy(&v, b, 1); return v; }
      case Type::U8: return b[0];
      case Type::I16: { int16_t v; std::memcpy(&v, b, 2); return v; }
      case Type::U16: { uint16_t v; std::memcpy(&v, b, 2); return v; }
      case Type::I32: { int32_t v; std::memcpy(&v, b, 4); return v; }
      case Type::U32: { uint32_t v; std::memcpy(&v, b, 4); return v; }
      case Type::F32: { float v; std::memcpy(&v, b, 4); return static_cast<double>(v); }
      case Type::F64: { double v; std::memcpy(&v, b, 8); return v; }
    }
    return 0.0;
  }

  double read_ascii(Type t, const Element& e, uint64_t i) {
    while (cur_ < data_.size()) {
      const char c = data_[cur_];
      if (c == '\n') ++line_;
      if (c != ' ' && c != '\t' && c != '\r' && c != '\n') break;
      ++cur_;
    }
    if (cur_ >= data_.size()) fail(where(e, i) + "unexpected end of file (truncated data)");
    size_t end = cur_;
    while (end < data_.size() && data_[end] != ' ' && data_[end] != '\t' && data_[end] != '\r' &&
           data_[end] != '\n')
      ++end;
    const char* b = data_.data() + cur_;
    const char* e_ptr = data_.data() + end;
    double v = 0.0;
    const char* p = b;
    if (p < e_ptr && *p == '+') ++p;
    const auto res = std::from_chars(p, e_ptr, v);
    if (res.ec == std::errc::result_out_of_range) {
      v = (*p == '-') ? -std::numeric_limits<double>::infinity()
                      : std::numeric_limits<double>::infinity();
    } else if (res.ec != std::errc() || res.ptr != e_ptr) {
      fail(where(e, i) + "bad number '" + std::string(b, std::min<size_t>(end - cur_, 40)) + "'");
    }
    if (is_integer_type(t) && std::isfinite(v) && v != std::floor(v))
      fail(where(e, i) + "'" + std::string(b, end - cur_) + "' is not an integer");
    cur_ = end;
    return v;
  }

  /// Reads a list count and checks it against the bytes left.
  uint64_t read_count(const Property& p, const Element& e, uint64_t i) {
    const double c = read_value(p.count_type, e, i);
    if (!(c >= 0.0)) fail(where(e, i) + "negative list count for '" + p.name + "'");
    const uint64_t left = data_.size() - cur_;
    // Binary: exact byte count. Ascii: one character plus a separator per value, except that
    // the very last value of the file may end without a separator.
    const bool ascii = format_ == Format::Ascii;
    const uint64_t per = ascii ? 2 : type_size(p.type);
    const uint64_t most = ascii ? (left + 1) / per : left / per;
    // Compared as a double before the conversion: an ascii count may be any number (1e308 or
    // inf), and converting one beyond 2^64 to an integer is undefined behaviour.
    if (c > static_cast<double>(most)) {
      char huge[32];
      std::snprintf(huge, sizeof huge, "%g", c);
      fail(where(e, i) + "list '" + p.name + "' claims " +
           (c < 1.8e19 ? with_thousands(static_cast<uint64_t>(c)) : std::string(huge)) +
           " entries, more than the rest of the file holds (truncated data?)");
    }
    return static_cast<uint64_t>(c);
  }

  void skip_property(const Element& e, uint64_t i, const Property& p) {
    if (!p.is_list) {
      read_value(p.type, e, i);
      return;
    }
    const uint64_t n = read_count(p, e, i);
    if (format_ != Format::Ascii) {
      cur_ += n * type_size(p.type);  // read_count checked the bytes are there
    } else {
      for (uint64_t k = 0; k < n; ++k) read_value(p.type, e, i);
    }
  }

  void read_vertices(const Element& e) {
    mesh_.positions.reserve(e.count);
    if (has_normals_) normals_.reserve(e.count);
    std::vector<double> values(e.props.size(), 0.0);
    for (uint64_t i = 0; i < e.count; ++i) {
      for (size_t k = 0; k < e.props.size(); ++k) {
        if (e.props[k].is_list) {
          skip_property(e, i, e.props[k]);
        } else {
          values[k] = read_value(e.props[k].type, e, i);
        }
      }
      auto f = [&](int k) { return static_cast<float>(values[static_cast<size_t>(k)]); };
      mesh_.positions.push_back({f(xyz_[0]), f(xyz_[1]), f(xyz_[2])});
      if (has_normals_) normals_.push_back({f(nxyz_[0]), f(nxyz_[1]), f(nxyz_[2])});
    }
  }

  void read_faces(const Element& e, bool strips) {
    int list = -1;
    for (size_t k = 0; k < e.props.size(); ++k)
      if (e.props[k].is_list && (e.props[k].name == "vertex_indices" ||
                                 (!strips && e.props[k].name == "vertex_index")))
        list = static_cast<int>(k);
    if (list < 0) {
      detail::warn(options_, file_ + ": element '" + e.name +
                                 "' has no vertex_indices list; skipped");
      for (uint64_t i = 0; i < e.count; ++i)
        for (const Property& p : e.props) skip_property(e, i, p);
      return;
    }
    std::vector<uint32_t> poly;
    for (uint64_t i = 0; i < e.count; ++i) {
      for (size_t k = 0; k < e.props.size(); ++k) {
        const Property& p = e.props[k];
        if (static_cast<int>(k) != list) {
          skip_property(e, i, p);
          continue;
        }
        const uint64_t n = read_count(p, e, i);
        poly.clear();
        // Emits the strip triangles gathered so far (strips) or the polygon fan (faces).
        auto flush_strip = [&]() {
          for (size_t s = 2; s < poly.size(); ++s) {
            if (s % 2 == 0) add_triangle(poly[s - 2], poly[s - 1], poly[s], e, i);
            else add_triangle(poly[s - 1], poly[s - 2], poly[s], e, i);
          }
          poly.clear();
        };
        for (uint64_t m = 0; m < n; ++m) {
          const double v = read_value(p.type, e, i);
          if (strips && v == -1.0) {
            flush_strip();
            continue;
          }
          if (!(v >= 0.0) || v >= static_cast<double>(vertex_count_) || v != std::floor(v))
            fail(where(e, i) + "vertex index " + format_index(v) + " out of range (" +
                 with_thousands(vertex_count_) + " vertices)");
          poly.push_back(static_cast<uint32_t>(v));
        }
        if (strips) {
          flush_strip();
        } else if (poly.size() < 3) {
          ++polygons_skipped_;
        } else {
          for (size_t s = 1; s + 1 < poly.size(); ++s) add_triangle(poly[0], poly[s], poly[s + 1], e, i);
        }
      }
    }
  }

  static std::string format_index(double v) {
    if (std::isfinite(v) && std::fabs(v) < 1e18 && v == std::floor(v))
      return std::to_string(static_cast<long long>(v));
    return std::to_string(v);
  }

  void add_triangle(uint32_t a, uint32_t b, uint32_t c, const Element& e, uint64_t i) {
    detail::check_elements(options_.limits, file_, where(e, i), mesh_.indices.size() + 3, detail::Elements::Indices);
    mesh_.indices.push_back(a);
    mesh_.indices.push_back(b);
    mesh_.indices.push_back(c);
  }

  fs::path path_;
  std::string file_;
  const LoadOptions& options_;
  std::string data_;
  Format format_ = Format::Ascii;
  std::vector<Element> elements_;
  size_t body_ = 0;
  size_t cur_ = 0;
  int64_t line_ = 0;
  uint64_t vertex_count_ = 0;
  std::array<int, 3> xyz_{-1, -1, -1}, nxyz_{-1, -1, -1};
  bool has_normals_ = false;
  detail::MeshData mesh_;
  std::vector<Vec3> normals_;
  uint64_t polygons_skipped_ = 0;
  int unknown_header_lines_ = 0;
};

}  // namespace

Scene load_ply(const fs::path& path, const LoadOptions& options) {
  PlyReader reader(path, options);
  return reader.load();
}

}  // namespace specula
