// Loader tests: shipped meshes, format round trips, material mapping, DataPaths, load_scene.
#include <gtest/gtest.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstring>
#include <functional>
#include <cstdlib>
#include <fstream>
#include <map>
#include <sstream>
#include <string>

#include "specula/error.h"
#include "specula/load.h"
#include "test_util.h"

using namespace specula;
namespace fs = std::filesystem;

namespace {

LoadOptions quiet(std::vector<std::string>* sink = nullptr) {
  LoadOptions o;
  o.warn = [sink](const std::string& w) {
    if (sink) sink->push_back(w);
  };
  return o;
}

}  // namespace

TEST(ObjShared, EachShippedMeshHasTheDocumentedTriangleCount) {
  const std::map<std::string, size_t> expected{
      {"stanford-bunny.obj", 69451}, {"teapot.obj", 6320},  {"spot.obj", 5856},
      {"cow.obj", 5804},            {"fandisk.obj", 12946}, {"homer.obj", 12000},
      {"rocker-arm.obj", 20088}};
  for (const char* name : test::kSharedMeshes) {
    SPECULA_REQUIRE_MESH(path, name);
    const auto t0 = std::chrono::steady_clock::now();
    const Scene s = load_obj(path, quiet());
    const double ms =
        std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
    ASSERT_TRUE(expected.count(name)) << name;
    EXPECT_EQ(s.triangle_count(), expected.at(name)) << name;
    EXPECT_EQ(s.normals.size(), s.positions.size());
    EXPECT_FALSE(s.cameras.empty());
    EXPECT_FALSE(s.lights.empty());
    EXPECT_NO_THROW(s.validate());
    std::printf("  %-20s %7zu triangles %7zu vertices  %.1f ms\n", name, s.triangle_count(),
                s.positions.size(), ms);
  }
}

// ---------------------------------------------------------------------------------------------
// Helpers that write the same small mesh in every format.

namespace {

// A small open mesh: a bent strip of 4 triangles over 6 vertices, exactly representable floats.
const std::vector<Vec3> kPos{{0, 0, 0}, {1, 0, 0}, {0, 1, 0}, {1, 1, 0.5f}, {0, 2, 1}, {1, 2, 1.25f}};
const std::vector<uint32_t> kIdx{0, 1, 2, 2, 1, 3, 2, 3, 4, 4, 3, 5};

void write_text(const fs::path& p, const std::string& s) {
  std::ofstream(p, std::ios::binary) << s;
}
void write_bytes(const fs::path& p, const std::vector<uint8_t>& b) {
  std::ofstream(p, std::ios::binary).write(reinterpret_cast<const char*>(b.data()),
                                           static_cast<std::streamsize>(b.size()));
}
template <typename T>
void put(std::vector<uint8_t>& out, T v, bool big_endian = false) {
  uint8_t b[sizeof(T)];
  std::memcpy(b, &v, sizeof(T));
  if (big_endian) std::reverse(b, b + sizeof(T));
  out.insert(out.end(), b, b + sizeof(T));
}

std::string obj_text() {
  std::ostringstream s;
  s << "# test mesh\n";
  for (const Vec3& p : kPos) s << "v " << p.x << ' ' << p.y << ' ' << p.z << '\n';
  for (size_t i = 0; i < kIdx.size(); i += 3)
    s << "f " << kIdx[i] + 1 << ' ' << kIdx[i + 1] + 1 << ' ' << kIdx[i + 2] + 1 << '\n';
  return s.str();
}

std::string ply_header(const std::string& format, bool doubles, const std::string& faces) {
  std::string t = doubles ? "double" : "float";
  return "ply\nformat " + format + " 1.0\ncomment test\nelement vertex " + std::to_string(kPos.size()) +
         "\nproperty " + t + " x\nproperty " + t + " y\nproperty uchar flags\nproperty " + t +
         " z\nproperty list uchar float uvs\n" + faces + "element material 1\nproperty float shine\nend_header\n";
}

std::string ply_ascii() {
  std::ostringstream s;
  s << ply_header("ascii", false, "element face 4\nproperty list uchar int vertex_indices\nproperty int tag\n");
  for (const Vec3& p : kPos) s << p.x << ' ' << p.y << " 7 " << p.z << " 2 0.5 0.25\n";
  for (size_t i = 0; i < kIdx.size(); i += 3) s << "3 " << kIdx[i] << ' ' << kIdx[i + 1] << ' ' << kIdx[i + 2] << " 42\n";
  s << "3.5\n";
  return s.str();
}

std::vector<uint8_t> ply_binary(bool be) {
  const std::string h = ply_header(be ? "binary_big_endian" : "binary_little_endian", true,
                                   "element face 4\nproperty list ushort uint vertex_index\n");
  std::vector<uint8_t> out(h.begin(), h.end());
  for (const Vec3& p : kPos) {
    put<double>(out, p.x, be);
    put<double>(out, p.y, be);
    put<uint8_t>(out, 7);
    put<double>(out, p.z, be);
    put<uint8_t>(out, 1);
    put<float>(out, 0.5f, be);
  }
  for (size_t i = 0; i < kIdx.size(); i += 3) {
    put<uint16_t>(out, 3, be);
    for (int k = 0; k < 3; ++k) put<uint32_t>(out, kIdx[i + static_cast<size_t>(k)], be);
  }
  put<float>(out, 3.5f, be);
  return out;
}

/// Each triangle as its own strip, separated by -1 restarts (odd strips have 4 entries so the
/// first triangle of the next strip is still "even").
std::string ply_tristrips() {
  std::ostringstream s;
  s << "ply\nformat ascii 1.0\nelement vertex 6\nproperty float x\nproperty float y\nproperty float z\n"
       "element tristrips 1\nproperty list int int vertex_indices\nend_header\n";
  for (const Vec3& p : kPos) s << p.x << ' ' << p.y << ' ' << p.z << '\n';
  s << kIdx.size() / 3 * 4;
  for (size_t i = 0; i < kIdx.size(); i += 3) s << ' ' << kIdx[i] << ' ' << kIdx[i + 1] << ' ' << kIdx[i + 2] << " -1";
  s << '\n';
  return s.str();
}

std::string base64(const std::vector<uint8_t>& in) {
  static const char* t = "ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
  std::string out;
  for (size_t i = 0; i < in.size(); i += 3) {
    uint32_t v = static_cast<uint32_t>(in[i]) << 16;
    if (i + 1 < in.size()) v |= static_cast<uint32_t>(in[i + 1]) << 8;
    if (i + 2 < in.size()) v |= in[i + 2];
    out += t[(v >> 18) & 63];
    out += t[(v >> 12) & 63];
    out += i + 1 < in.size() ? t[(v >> 6) & 63] : '=';
    out += i + 2 < in.size() ? t[v & 63] : '=';
  }
  return out;
}

std::vector<uint8_t> gltf_buffer() {
  std::vector<uint8_t> b;
  for (const Vec3& p : kPos) {
    put<float>(b, p.x);
    put<float>(b, p.y);
    put<float>(b, p.z);
  }
  for (uint32_t i : kIdx) put<uint16_t>(b, static_cast<uint16_t>(i));
  return b;  // 72 + 24 bytes
}

std::string gltf_json(const std::string& buffer_uri, size_t byte_length,
                      const std::string& extra_top = "", const std::string& material = "") {
  return std::string("{\"asset\":{\"version\":\"2.0\"},\"scene\":0,\"scenes\":[{\"nodes\":[0]}],") +
         "\"nodes\":[{\"mesh\":0}],\"meshes\":[{\"primitives\":[{\"attributes\":{\"POSITION\":0},\"indices\":1" +
         material + "}]}]," + "\"buffers\":[{\"byteLength\":" + std::to_string(byte_length) +
         (buffer_uri.empty() ? "" : ",\"uri\":\"" + buffer_uri + "\"") + "}]," +
         "\"bufferViews\":[{\"buffer\":0,\"byteOffset\":0,\"byteLength\":72},{\"buffer\":0,\"byteOffset\":72,\"byteLength\":24}]," +
         "\"accessors\":[{\"bufferView\":0,\"componentType\":5126,\"count\":6,\"type\":\"VEC3\",\"min\":[0,0,0],\"max\":[1,2,1.25]}," +
         "{\"bufferView\":1,\"componentType\":5123,\"count\":12,\"type\":\"SCALAR\"}]" + extra_top + "}";
}

std::vector<uint8_t> glb_bytes() {
  std::string js = gltf_json("", 96);
  while (js.size() % 4) js += ' ';
  const std::vector<uint8_t> bin = gltf_buffer();
  std::vector<uint8_t> out{'g', 'l', 'T', 'F'};
  put<uint32_t>(out, 2);
  put<uint32_t>(out, static_cast<uint32_t>(12 + 8 + js.size() + 8 + bin.size()));
  put<uint32_t>(out, static_cast<uint32_t>(js.size()));
  put<uint32_t>(out, 0x4E4F534Au);
  out.insert(out.end(), js.begin(), js.end());
  put<uint32_t>(out, static_cast<uint32_t>(bin.size()));
  put<uint32_t>(out, 0x004E4942u);
  out.insert(out.end(), bin.begin(), bin.end());
  return out;
}

std::string data_uri(const std::vector<uint8_t>& b) {
  return "data:application/octet-stream;base64," + base64(b);
}

void expect_test_mesh(const Scene& s, const std::string& what) {
  ASSERT_EQ(s.positions.size(), kPos.size()) << what;
  ASSERT_EQ(s.indices.size(), kIdx.size()) << what;
  for (size_t i = 0; i < kPos.size(); ++i) EXPECT_EQ(s.positions[i], kPos[i]) << what << " vertex " << i;
  for (size_t i = 0; i < kIdx.size(); ++i) EXPECT_EQ(s.indices[i], kIdx[i]) << what << " index " << i;
  EXPECT_EQ(s.normals.size(), s.positions.size()) << what;
  EXPECT_NO_THROW(s.validate()) << what;
}

}  // namespace

TEST(LoadFormats, SameMeshInEveryFormatLoadsIdentically) {
  const fs::path d = test::temp_dir("formats");
  write_text(d / "m.obj", obj_text());
  write_text(d / "m_ascii.ply", ply_ascii());
  write_bytes(d / "m_le.ply", ply_binary(false));
  write_bytes(d / "m_be.ply", ply_binary(true));
  write_text(d / "m_strips.ply", ply_tristrips());
  write_text(d / "m_embedded.gltf", gltf_json(data_uri(gltf_buffer()), 96));
  write_bytes(d / "m_external.bin", gltf_buffer());
  write_text(d / "m_external.gltf", gltf_json("m_external.bin", 96));
  write_bytes(d / "m.glb", glb_bytes());
  for (const char* f : {"m.obj", "m_ascii.ply", "m_le.ply", "m_be.ply", "m_strips.ply",
                        "m_embedded.gltf", "m_external.gltf", "m.glb"}) {
    std::vector<std::string> warnings;
    const Scene s = load_scene((d / f).string(), quiet(&warnings));
    expect_test_mesh(s, f);
    EXPECT_TRUE(warnings.empty()) << f << ": " << (warnings.empty() ? "" : warnings[0]);
    EXPECT_FALSE(s.cameras.empty()) << f;
    EXPECT_FALSE(s.lights.empty()) << f;
  }
  fs::remove_all(d);
}

TEST(ObjLoader, PolygonsAreFannedInFileOrderWithPerFaceMaterials) {
  const fs::path d = test::temp_dir("objfan");
  write_text(d / "a.mtl", "newmtl red\nKd 1 0 0\nnewmtl blue\nKd 0 0 1\n");
  write_text(d / "p.obj",
             "mtllib a.mtl\nv 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv -1 0.5 0\n"
             "usemtl blue\nf 1 2 3 4\nusemtl red\nf 1 2 3 4 5\nusemtl nothing\nf 3 2 1\n");
  std::vector<std::string> w;
  const Scene s = load_obj(d / "p.obj", quiet(&w));
  const std::vector<uint32_t> want{0, 1, 2, 0, 2, 3, 0, 1, 2, 0, 2, 3, 0, 3, 4, 2, 1, 0};
  EXPECT_EQ(s.indices, want);
  ASSERT_EQ(s.material_ids.size(), 6u);
  EXPECT_EQ(s.materials[s.material_ids[0]].name, "blue");
  EXPECT_EQ(s.materials[s.material_ids[1]].name, "blue");
  for (int t = 2; t < 5; ++t) EXPECT_EQ(s.materials[s.material_ids[static_cast<size_t>(t)]].name, "red");
  EXPECT_EQ(s.materials[s.material_ids[5]].name, "default");
  fs::remove_all(d);
}

TEST(ObjLoader, FileNormalsAreUsedPerCorner) {
  const fs::path d = test::temp_dir("objn");
  // Two triangles share position 2 and 3 but use different normals there: 6 distinct pairs.
  write_text(d / "n.obj",
             "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nvn 0 0 1\nvn 0 1 0\n"
             "f 1//1 2//1 3//1\nf 3//2 2//2 4//2\n");
  const Scene s = load_obj(d / "n.obj", quiet());
  ASSERT_EQ(s.triangle_count(), 2u);
  ASSERT_EQ(s.positions.size(), 6u);
  for (int c = 0; c < 3; ++c) EXPECT_EQ(s.normals[s.indices[static_cast<size_t>(c)]], (Vec3{0, 0, 1}));
  for (int c = 3; c < 6; ++c) EXPECT_EQ(s.normals[s.indices[static_cast<size_t>(c)]], (Vec3{0, 1, 0}));
  EXPECT_EQ(s.positions[s.indices[3]], (Vec3{0, 1, 0}));
  EXPECT_EQ(s.positions[s.indices[5]], (Vec3{1, 1, 0}));
  fs::remove_all(d);
}

TEST(ObjLoader, MtlMappingFieldByField) {
  const fs::path d = test::temp_dir("mtl");
  write_text(d / "m.mtl",
             "newmtl plastic\nKd 0.5 0.25 0.125\nKs 0.2 0.3 0.4\nNs 64\nillum 2\n"
             "newmtl mirror\nKd 0 0 0\nKs 0.9 0.8 0.7\nillum 3\n"
             "newmtl glass\nKd 0 0 0\nNi 1.45\nd 0.25\nTf 0.5 1 0.25\nillum 4\n"
             "newmtl water\nNi 1.33\nillum 7\n"
             "newmtl fresnel\nKs 0 0 0\nillum 5\n"
             "newmtl lamp\nKe 2 3 4\nTr 0.5\n");
  std::string obj = "mtllib m.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\n";
  for (const char* m : {"plastic", "mirror", "glass", "water", "fresnel", "lamp"})
    obj += std::string("usemtl ") + m + "\nf 1 2 3\n";
  write_text(d / "m.obj", obj);
  const Scene s = load_obj(d / "m.obj", quiet());
  ASSERT_EQ(s.triangle_count(), 6u);
  auto mat = [&](size_t t) { return s.materials[s.material_ids[t]]; };
  const Material plastic = mat(0), mirror = mat(1), glass = mat(2), water = mat(3), fres = mat(4), lamp = mat(5);
  EXPECT_EQ(plastic.name, "plastic");
  EXPECT_EQ(plastic.diffuse, (Vec3{0.5f, 0.25f, 0.125f}));
  EXPECT_EQ(plastic.specular, (Vec3{0.2f, 0.3f, 0.4f}));
  EXPECT_FLOAT_EQ(plastic.phong_exponent, 64.0f);
  EXPECT_EQ(plastic.reflectivity, 0.0f);
  EXPECT_EQ(plastic.transparency, 0.0f);
  EXPECT_FLOAT_EQ(mirror.reflectivity, 0.9f);
  EXPECT_EQ(mirror.transparency, 0.0f);
  EXPECT_FLOAT_EQ(glass.transparency, 0.75f);
  EXPECT_FLOAT_EQ(glass.ior, 1.45f);
  EXPECT_NEAR(glass.absorption.x, -std::log(0.5f), 1e-6f);
  EXPECT_NEAR(glass.absorption.y, 0.0f, 1e-6f);
  EXPECT_NEAR(glass.absorption.z, -std::log(0.25f), 1e-6f);
  EXPECT_TRUE(glass.dielectric());
  EXPECT_FLOAT_EQ(water.transparency, 1.0f);
  EXPECT_FLOAT_EQ(water.ior, 1.33f);
  EXPECT_EQ(water.absorption, Vec3{});
  EXPECT_FLOAT_EQ(fres.reflectivity, 1.0f);
  EXPECT_EQ(lamp.emission, (Vec3{2, 3, 4}));
  EXPECT_FLOAT_EQ(lamp.transparency, 0.5f);
  fs::remove_all(d);
}

TEST(ObjLoader, MissingMtlWarnsButLoads) {
  const fs::path d = test::temp_dir("mtlmissing");
  write_text(d / "m.obj", "mtllib nothere.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n");
  std::vector<std::string> w;
  const Scene s = load_obj(d / "m.obj", quiet(&w));
  EXPECT_EQ(s.triangle_count(), 1u);
  ASSERT_FALSE(w.empty());
  EXPECT_NE(w[0].find("nothere.mtl"), std::string::npos) << w[0];
  fs::remove_all(d);
}

TEST(LoadNaN, TrianglesWithNonFiniteVerticesAreDroppedWithOneWarning) {
  const fs::path d = test::temp_dir("nan");
  write_text(d / "n.obj", "v 0 0 0 # banana\nv 1 0 0\nv 0 1 0\nv nan 0 0\nv 0 -1e999 0\n"
                          "f 1 2 3\nf 1 2 4\nf 4 5 1\nf 3 2 1\n");
  std::vector<std::string> w;
  const Scene s = load_obj(d / "n.obj", quiet(&w));
  EXPECT_EQ(s.triangle_count(), 2u);
  EXPECT_EQ(s.positions.size(), 3u);
  ASSERT_EQ(w.size(), 1u);
  EXPECT_NE(w[0].find("dropped 2 triangles"), std::string::npos) << w[0];
  for (const Vec3& n : s.normals) EXPECT_TRUE(is_finite(n));
  // Same through PLY.
  write_text(d / "n.ply", "ply\nformat ascii 1.0\nelement vertex 4\nproperty float x\nproperty float y\n"
                          "property float z\nelement face 2\nproperty list uchar int vertex_indices\nend_header\n"
                          "0 0 0\n1 0 0\n0 1 0\nnan 0 0\n3 0 1 2\n3 0 1 3\n");
  w.clear();
  const Scene p = load_ply(d / "n.ply", quiet(&w));
  EXPECT_EQ(p.triangle_count(), 1u);
  EXPECT_EQ(w.size(), 1u);
  fs::remove_all(d);
}

TEST(LoadDegenerate, ZeroAreaTrianglesAreKeptButAFileOfNothingElseIsAnError) {
  const fs::path d = test::temp_dir("degenerate");
  // One good triangle among degenerate ones (collinear, repeated vertex): all kept, file order.
  write_text(d / "some.obj", "v 0 0 0\nv 1 1 1\nv 2 2 2\nv 1 0 0\nv 0 1 0\nf 1 2 3\nf 1 1 4\nf 1 4 5\n");
  EXPECT_EQ(load_obj(d / "some.obj", quiet()).triangle_count(), 3u);
  // Only degenerate ones: no surface.
  write_text(d / "line.obj", "v 0 0 0\nv 1 1 1\nv 2 2 2\nf 1 2 3\nf 3 2 1\n");
  try {
    (void)load_scene((d / "line.obj").string(), quiet());
    ADD_FAILURE() << "a file of zero-area triangles loaded";
  } catch (const Error& e) {
    const std::string msg = e.what();
    EXPECT_NE(msg.find("line.obj"), std::string::npos) << msg;
    EXPECT_NE(msg.find("all 2 triangles have zero area"), std::string::npos) << msg;
  }
  write_text(d / "line.ply", "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
                             "property float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n"
                             "0 0 0\n1 0 0\n2 0 0\n3 0 1 2\n");
  EXPECT_THROW((void)load_scene((d / "line.ply").string(), quiet()), Error);
  fs::remove_all(d);
}

TEST(ObjLoader, ExponentsOfTenOrMoreDigitsAreRefusedWithTheirLine) {
  // tinyobjloader overflows an int reading them (fuzz_obj); shorter ones, zero-padded ones
  // included, load as usual.
  const fs::path d = test::temp_dir("exponent");
  write_text(d / "ok.obj", "v 0 0 0\nv 1e0 0 0\nv 0 1.0E-000000000001 +2.5e+2\nf 1 2 3\n");
  EXPECT_EQ(load_obj(d / "ok.obj", quiet()).triangle_count(), 1u);
  write_text(d / "bad.obj", "v 0 0 0\nv 1 0 0\nv 0 2e-2147483648 0\nf 1 2 3\n");
  const std::string m = test::error_of([&] { load_obj(d / "bad.obj", quiet()); });
  EXPECT_NE(m.find("bad.obj"), std::string::npos) << m;
  EXPECT_NE(m.find("line 3"), std::string::npos) << m;
  EXPECT_NE(m.find("'2e-2147483648'"), std::string::npos) << m;
  write_text(d / "m.mtl", "newmtl red\nKd 1 0 .5e99999999999\n");
  write_text(d / "m.obj", "mtllib m.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nusemtl red\nf 1 2 3\n");
  const std::string mtl = test::error_of([&] { load_obj(d / "m.obj", quiet()); });
  EXPECT_NE(mtl.find("mtllib 'm.mtl': line 2"), std::string::npos) << mtl;
  fs::remove_all(d);
}

TEST(PlyLoader, TriStripsAlternateWindingAndRestart) {
  const fs::path d = test::temp_dir("strip");
  write_text(d / "s.ply", "ply\nformat binary_little_endian 1.0\nelement vertex 5\nproperty float x\n"
                          "property float y\nproperty float z\nelement tristrips 1\n"
                          "property list int int vertex_indices\nend_header\n");
  std::vector<uint8_t> b;
  for (int i = 0; i < 5; ++i) {
    put<float>(b, static_cast<float>(i % 2));
    put<float>(b, static_cast<float>(i / 2));  // NOLINT(bugprone-integer-division): rows 0, 0, 1, 1, 2
    put<float>(b, 0.0f);
  }
  const int32_t strip[] = {0, 1, 2, 3, 4, -1, 4, 3, 2};
  put<int32_t>(b, 9);
  for (int32_t v : strip) put<int32_t>(b, v);
  std::ofstream(d / "s.ply", std::ios::binary | std::ios::app).write(reinterpret_cast<const char*>(b.data()), static_cast<std::streamsize>(b.size()));
  const Scene s = load_ply(d / "s.ply", quiet());
  const std::vector<uint32_t> want{0, 1, 2, 2, 1, 3, 2, 3, 4, 4, 3, 2};
  EXPECT_EQ(s.indices, want);
  fs::remove_all(d);
}

TEST(PlyLoader, ErrorsNameElementAndIndex) {
  const fs::path d = test::temp_dir("plyerr");
  write_text(d / "e.ply", "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
                          "property float z\nelement face 2\nproperty list uchar int vertex_indices\nend_header\n"
                          "0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n3 0 1 5\n");
  const std::string msg = test::error_of([&] { load_ply(d / "e.ply", quiet()); });
  EXPECT_NE(msg.find("e.ply"), std::string::npos) << msg;
  EXPECT_NE(msg.find("element 'face' 1"), std::string::npos) << msg;
  EXPECT_NE(msg.find("vertex index 5"), std::string::npos) << msg;
  EXPECT_NE(msg.find("line 14"), std::string::npos) << msg;
  fs::remove_all(d);
}

TEST(PlyLoader, VertexNormalsAreRead) {
  const fs::path d = test::temp_dir("plyn");
  write_text(d / "n.ply", "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
                          "property float z\nproperty float nx\nproperty float ny\nproperty float nz\n"
                          "element face 1\nproperty list uchar int vertex_indices\nend_header\n"
                          "0 0 0 1 0 0\n1 0 0 0 1 0\n0 1 0 0 0 2\n3 0 1 2\n");
  const Scene s = load_ply(d / "n.ply", quiet());
  EXPECT_EQ(s.normals[0], (Vec3{1, 0, 0}));
  EXPECT_EQ(s.normals[1], (Vec3{0, 1, 0}));
  EXPECT_EQ(s.normals[2], (Vec3{0, 0, 1}));
  fs::remove_all(d);
}

TEST(GltfLoader, MaterialsLightsAndCamerasFieldByField) {
  const fs::path d = test::temp_dir("gltfmat");
  const std::string materials =
      ",\"materials\":["
      "{\"name\":\"glass\",\"pbrMetallicRoughness\":{\"baseColorFactor\":[0.9,0.8,0.7,1],\"metallicFactor\":0,\"roughnessFactor\":0},"
      "\"extensions\":{\"KHR_materials_transmission\":{\"transmissionFactor\":0.9},\"KHR_materials_ior\":{\"ior\":1.33},"
      "\"KHR_materials_volume\":{\"attenuationColor\":[0.5,0.25,1.0],\"attenuationDistance\":2.0}}},"
      "{\"name\":\"gold\",\"pbrMetallicRoughness\":{\"baseColorFactor\":[1,0.75,0.25,1],\"metallicFactor\":1,\"roughnessFactor\":0.5},"
      "\"emissiveFactor\":[0.5,0.25,0],\"extensions\":{\"KHR_materials_emissive_strength\":{\"emissiveStrength\":4}}}],"
      "\"cameras\":[{\"name\":\"cam\",\"type\":\"perspective\",\"perspective\":{\"yfov\":0.5,\"znear\":0.1}}],"
      "\"extensionsUsed\":[\"KHR_lights_punctual\",\"KHR_materials_transmission\",\"KHR_materials_ior\",\"KHR_materials_volume\",\"KHR_materials_emissive_strength\"],"
      "\"extensions\":{\"KHR_lights_punctual\":{\"lights\":[{\"name\":\"sun\",\"type\":\"directional\",\"color\":[1,0.9,0.8],\"intensity\":3},"
      "{\"name\":\"bulb\",\"type\":\"point\",\"intensity\":20}]}}";
  std::string js = gltf_json(data_uri(gltf_buffer()), 96, materials, ",\"material\":0");
  // Add a second mesh instance with material 1, a camera node and two light nodes.
  const std::string nodes_old = "\"scenes\":[{\"nodes\":[0]}],\"nodes\":[{\"mesh\":0}],";
  const std::string nodes_new =
      "\"scenes\":[{\"nodes\":[0,1,2,3,4]}],\"nodes\":[{\"mesh\":0},{\"mesh\":1,\"translation\":[10,0,0]},"
      "{\"camera\":0,\"translation\":[0,1,5]},"
      "{\"rotation\":[-0.7071068,0,0,0.7071068],\"extensions\":{\"KHR_lights_punctual\":{\"light\":0}}},"
      "{\"translation\":[1,2,3],\"extensions\":{\"KHR_lights_punctual\":{\"light\":1}}}],";
  js.replace(js.find(nodes_old), nodes_old.size(), nodes_new);
  const std::string mesh_old = "}]}],\"buffers\"";
  js.replace(js.find(mesh_old), mesh_old.size(),
             "}]},{\"primitives\":[{\"attributes\":{\"POSITION\":0},\"indices\":1,\"material\":1}]}],\"buffers\"");
  write_text(d / "mat.gltf", js);
  std::vector<std::string> w;
  const Scene s = load_gltf(d / "mat.gltf", quiet(&w));
  ASSERT_EQ(s.triangle_count(), 8u);
  const Material& glass = s.materials[s.material_ids[0]];
  const Material& gold = s.materials[s.material_ids[4]];
  EXPECT_EQ(glass.name, "glass");
  EXPECT_EQ(glass.diffuse, (Vec3{0.9f, 0.8f, 0.7f}));
  EXPECT_FLOAT_EQ(glass.transparency, 0.9f);
  EXPECT_FLOAT_EQ(glass.ior, 1.33f);
  EXPECT_NEAR(glass.absorption.x, std::log(2.0f) / 2.0f, 1e-6f);
  EXPECT_NEAR(glass.absorption.y, std::log(4.0f) / 2.0f, 1e-6f);
  EXPECT_NEAR(glass.absorption.z, 0.0f, 1e-6f);
  EXPECT_NEAR(glass.specular.x, 0.04f, 1e-6f);
  EXPECT_LE(glass.reflectivity + glass.transparency, 1.0f);
  EXPECT_EQ(gold.name, "gold");
  EXPECT_EQ(gold.diffuse, Vec3{});
  EXPECT_EQ(gold.specular, (Vec3{1, 0.75f, 0.25f}));
  EXPECT_FLOAT_EQ(gold.reflectivity, 0.25f);  // metallic * (1 - roughness)^2
  EXPECT_EQ(gold.transparency, 0.0f);
  EXPECT_EQ(gold.emission, (Vec3{2, 1, 0}));
  EXPECT_FLOAT_EQ(gold.phong_exponent, 2.0f / (0.25f * 0.25f) - 2.0f);
  EXPECT_EQ(s.positions[s.indices[12]], (Vec3{10, 0, 0}));  // instance translated
  ASSERT_EQ(s.cameras.size(), 1u);
  EXPECT_EQ(s.cameras[0].name, "cam");
  EXPECT_EQ(s.cameras[0].position, (Vec3{0, 1, 5}));
  EXPECT_EQ(s.cameras[0].target, (Vec3{0, 1, 4}));
  EXPECT_EQ(s.cameras[0].up, (Vec3{0, 1, 0}));
  EXPECT_NEAR(s.cameras[0].vfov_degrees, 0.5f * 180.0f / kPi, 1e-4f);
  ASSERT_EQ(s.lights.size(), 2u);
  EXPECT_EQ(s.lights[0].name, "sun");
  EXPECT_EQ(s.lights[0].type, LightType::Directional);
  EXPECT_EQ(s.lights[0].color, (Vec3{1, 0.9f, 0.8f}));
  EXPECT_FLOAT_EQ(s.lights[0].intensity, 3.0f);
  EXPECT_NEAR(s.lights[0].direction.y, -1.0f, 1e-5f);  // -z rotated -90 degrees about x
  EXPECT_EQ(s.lights[1].name, "bulb");
  EXPECT_EQ(s.lights[1].type, LightType::Point);
  EXPECT_EQ(s.lights[1].position, (Vec3{1, 2, 3}));
  EXPECT_FLOAT_EQ(s.lights[1].intensity, 20.0f);
  EXPECT_TRUE(w.empty()) << w[0];
  fs::remove_all(d);
}

TEST(GltfLoader, NodeMatrixHierarchyIsApplied) {
  const fs::path d = test::temp_dir("gltfnode");
  std::string js = gltf_json(data_uri(gltf_buffer()), 96);
  const std::string nodes_old = "\"nodes\":[{\"mesh\":0}],";
  // Parent: column-major matrix translating by (0, 0, -3) and scaling x by 2; child translates by 1 in y.
  js.replace(js.find(nodes_old), nodes_old.size(),
             "\"nodes\":[{\"matrix\":[2,0,0,0, 0,1,0,0, 0,0,1,0, 0,0,-3,1],\"children\":[1]},"
             "{\"mesh\":0,\"translation\":[0,1,0]}],");
  write_text(d / "n.gltf", js);
  const Scene s = load_gltf(d / "n.gltf", quiet());
  ASSERT_EQ(s.positions.size(), kPos.size());
  for (size_t i = 0; i < kPos.size(); ++i)
    EXPECT_EQ(s.positions[i], (Vec3{2 * kPos[i].x, kPos[i].y + 1, kPos[i].z - 3})) << i;
  fs::remove_all(d);
}

TEST(JsonScene, ExampleSceneLoads) {
  const fs::path ex = fs::path(SPECULA_SOURCE_DIR) / "examples" / "scenes";
  ASSERT_TRUE(fs::is_directory(ex)) << ex;
  size_t n = 0;
  for (const auto& e : fs::directory_iterator(ex)) {
    if (e.path().extension() != ".json") continue;
    std::vector<std::string> w;
    const Scene s = load_scene(e.path().string(), quiet(&w));
    EXPECT_GT(s.triangle_count(), 0u) << e.path();
    EXPECT_FALSE(s.cameras.empty()) << e.path();
    EXPECT_TRUE(w.empty()) << e.path() << ": " << (w.empty() ? "" : w[0]);
    ++n;
  }
  EXPECT_GT(n, 0u);
}

TEST(JsonScene, BuiltinShapesTransformsMaterialsLightsCameraSky) {
  const fs::path d = test::temp_dir("json");
  write_text(d / "tri.ply", ply_ascii());
  write_text(d / "s.json", R"({
    "name": "t",
    "materials": {"red": {"diffuse": [1, 0, 0], "reflectivity": 0.25},
                  "glass": {"diffuse": 0, "transparency": 1, "ior": 1.5, "absorption": [0.1, 0.2, 0.3]}},
    "meshes": [
      {"builtin": "plane", "size": [4, 2], "material": "red"},
      {"builtin": "box", "size": 2, "material": "glass", "transform": {"translate": [0, 1, 0]}},
      {"builtin": "sphere", "radius": 0.5, "segments": 8, "material": {"emission": [1, 1, 1]},
       "transform": {"matrix": [1,0,0,5, 0,1,0,0, 0,0,1,0, 0,0,0,1]}},
      {"file": "tri.ply", "name": "tri", "transform": {"rotate": {"axis": [0, 1, 0], "degrees": 90}, "scale": 2}}
    ],
    "lights": [{"type": "sphere", "position": [0, 5, 0], "radius": 0.5, "samples": 8, "intensity": 30},
               {"type": "directional", "direction": [0, -2, 0], "color": [1, 1, 0.5]}],
    "cameras": [{"name": "main", "position": [0, 2, 8], "target": [0, 1, 0], "fov": 50}],
    "sky": {"type": "constant", "color": [0.1, 0.2, 0.3]},
    "ambient": 0.1,
    "colour": "unknown key"
  })");
  std::vector<std::string> w;
  const Scene s = load_scene((d / "s.json").string(), quiet(&w));
  ASSERT_EQ(s.meshes.size(), 4u);
  EXPECT_EQ(s.meshes[0].triangle_count, 2u);
  EXPECT_EQ(s.meshes[1].triangle_count, 12u);
  EXPECT_EQ(s.meshes[2].triangle_count, 2u * 8u * 4u);
  EXPECT_EQ(s.meshes[3].name, "tri");
  EXPECT_EQ(s.meshes[3].triangle_count, 4u);
  EXPECT_EQ(s.materials[s.material_ids[0]].name, "red");
  EXPECT_FLOAT_EQ(s.materials[s.material_ids[0]].reflectivity, 0.25f);
  EXPECT_EQ(s.materials[s.material_ids[2]].absorption, (Vec3{0.1f, 0.2f, 0.3f}));
  EXPECT_EQ(s.materials[s.material_ids[s.meshes[2].first_triangle]].emission, (Vec3{1, 1, 1}));
  // Box spans y in [0, 2] after the translation.
  float ymin = 1e9f, ymax = -1e9f;
  for (uint32_t t = s.meshes[1].first_triangle; t < s.meshes[1].first_triangle + 12; ++t)
    for (int c = 0; c < 3; ++c) {
      const float y = s.positions[s.indices[3 * t + static_cast<uint32_t>(c)]].y;
      ymin = std::min(ymin, y);
      ymax = std::max(ymax, y);
    }
  EXPECT_FLOAT_EQ(ymin, 0.0f);
  EXPECT_FLOAT_EQ(ymax, 2.0f);
  // The PLY vertex (1, 0, 0) rotated 90 degrees about y and scaled by 2 -> (0, 0, -2).
  const Vec3 p = s.positions[s.indices[3 * s.meshes[3].first_triangle + 1]];
  EXPECT_NEAR(p.x, 0.0f, 1e-5f);
  EXPECT_NEAR(p.z, -2.0f, 1e-5f);
  ASSERT_EQ(s.lights.size(), 2u);
  EXPECT_EQ(s.lights[0].type, LightType::Sphere);
  EXPECT_EQ(s.lights[0].samples, 8);
  EXPECT_FLOAT_EQ(s.lights[0].radius, 0.5f);
  EXPECT_EQ(s.lights[1].direction, (Vec3{0, -1, 0}));
  ASSERT_EQ(s.cameras.size(), 1u);
  EXPECT_EQ(s.cameras[0].name, "main");
  EXPECT_FLOAT_EQ(s.cameras[0].vfov_degrees, 50.0f);
  EXPECT_EQ(s.sky.type, SkyType::Constant);
  EXPECT_EQ(s.sky.color, (Vec3{0.1f, 0.2f, 0.3f}));
  EXPECT_EQ(s.ambient, Vec3(0.1f));
  ASSERT_EQ(w.size(), 1u);
  EXPECT_NE(w[0].find("colour"), std::string::npos) << w[0];
  fs::remove_all(d);
}

// Cameras are selected by name (--camera, bench render's camera list): a name given twice would
// hide the second camera. glTF files often repeat names ("Camera"), so the loader renames the
// later ones with a warning; a JSON scene's explicit repeat is an error; Scene::validate refuses
// a scene built in code with two cameras of one name.
TEST(GltfLoader, RepeatedCameraNamesAreMadeUnique) {
  const fs::path d = test::temp_dir("gltfcams");
  std::string js = gltf_json(data_uri(gltf_buffer()), 96,
                             ",\"cameras\":[{\"name\":\"cam\",\"type\":\"perspective\",\"perspective\":{\"yfov\":0.5,\"znear\":0.1}}]");
  const std::string nodes_old = "\"scenes\":[{\"nodes\":[0]}],\"nodes\":[{\"mesh\":0}],";
  js.replace(js.find(nodes_old), nodes_old.size(),
             "\"scenes\":[{\"nodes\":[0,1,2,3]}],\"nodes\":[{\"mesh\":0},{\"camera\":0,\"translation\":[0,1,5]},"
             "{\"camera\":0,\"translation\":[0,1,6]},{\"camera\":0,\"translation\":[0,1,7]}],");
  write_text(d / "cams.gltf", js);
  std::vector<std::string> w;
  const Scene s = load_gltf(d / "cams.gltf", quiet(&w));
  ASSERT_EQ(s.cameras.size(), 3u);
  EXPECT_EQ(s.cameras[0].name, "cam");
  EXPECT_EQ(s.cameras[1].name, "cam#2");
  EXPECT_EQ(s.cameras[2].name, "cam#3");
  EXPECT_EQ(s.cameras[2].position, (Vec3{0, 1, 7}));
  ASSERT_EQ(w.size(), 2u);
  EXPECT_NE(w[0].find("camera name 'cam' is taken by an earlier camera; this one is 'cam#2'"), std::string::npos) << w[0];
  fs::remove_all(d);
}

TEST(JsonScene, RepeatedCameraNameIsAnError) {
  const fs::path d = test::temp_dir("jsoncams");
  write_text(d / "c.json", R"({"meshes": [{"builtin": "box"}],
    "cameras": [{"name": "a", "position": [0, 0, 5]}, {"name": "b", "position": [0, 0, 6]},
                {"name": "a", "position": [0, 0, 7]}]})");
  const std::string msg = test::error_of([&] { load_json_scene(d / "c.json", quiet()); });
  EXPECT_NE(msg.find("c.json"), std::string::npos) << msg;
  EXPECT_NE(msg.find("cameras[2].name: 'a' is already the name of cameras[0]"), std::string::npos) << msg;
  // Unnamed cameras get generated names that never collide with given ones.
  write_text(d / "u.json", R"({"meshes": [{"builtin": "box"}],
    "cameras": [{"name": "camera1", "position": [0, 0, 5]}, {"position": [0, 0, 6]}, {"position": [0, 0, 7]}]})");
  const Scene s = load_json_scene(d / "u.json", quiet());
  ASSERT_EQ(s.cameras.size(), 3u);
  EXPECT_EQ(s.cameras[0].name, "camera1");
  EXPECT_EQ(s.cameras[1].name, "camera1#2");
  EXPECT_EQ(s.cameras[2].name, "camera2");
  fs::remove_all(d);
}

TEST(SceneValidate, RefusesTwoCamerasOfOneName) {
  Scene s = make_builtin_scene("cornell");
  ASSERT_FALSE(s.cameras.empty());
  EXPECT_NO_THROW(s.validate());
  s.cameras.push_back(s.cameras.front());
  const std::string msg = test::error_of([&] { s.validate(); });
  EXPECT_NE(msg.find("are both named '" + s.cameras.front().name + "'"), std::string::npos) << msg;
}

TEST(JsonScene, ErrorsNameTheKeyPathAndPosition) {
  const fs::path d = test::temp_dir("jsonerr");
  write_text(d / "t.json", R"({"meshes": [{"builtin": "box"}, {"builtin": "box", "transform": {"scale": "big"}}]})");
  std::string msg = test::error_of([&] { load_json_scene(d / "t.json", quiet()); });
  EXPECT_NE(msg.find("t.json"), std::string::npos) << msg;
  EXPECT_NE(msg.find("meshes[1].transform.scale"), std::string::npos) << msg;
  write_text(d / "p.json", "{\n  \"meshes\": [\n    {\"builtin\": \"box\",}\n  ]\n}\n");
  msg = test::error_of([&] { load_json_scene(d / "p.json", quiet()); });
  EXPECT_NE(msg.find("p.json: line 3"), std::string::npos) << msg;
  EXPECT_NE(msg.find("byte"), std::string::npos) << msg;
  fs::remove_all(d);
}

TEST(JsonScene, AReferenceToAFolderIsNotAFile) {
  const fs::path d = test::temp_dir("jsonfolder");
  fs::create_directories(d / "sky.png");
  fs::create_directories(d / "mesh.obj");
  write_text(d / "s.json", R"({"meshes": [{"builtin": "box"}], "sky": {"type": "image", "image": "sky.png"}})");
  std::string msg = test::error_of([&] { load_json_scene(d / "s.json", quiet()); });
  EXPECT_NE(msg.find("sky.image: 'sky.png' is not a regular file"), std::string::npos) << msg;
  write_text(d / "m.json", R"({"meshes": [{"file": "mesh.obj"}]})");
  msg = test::error_of([&] { load_json_scene(d / "m.json", quiet()); });
  EXPECT_NE(msg.find("'mesh.obj' is not a regular file"), std::string::npos) << msg;
  write_text(d / "n.json", R"({"meshes": [{"file": "none.obj"}]})");
  msg = test::error_of([&] { load_json_scene(d / "n.json", quiet()); });
  EXPECT_NE(msg.find("'none.obj' not found"), std::string::npos) << msg;
  fs::remove_all(d);
}

TEST(LoadScene, DispatchesByCaseInsensitiveExtensionAndNamesTheFile) {
  const fs::path d = test::temp_dir("dispatch");
  write_text(d / "UP.OBJ", obj_text());
  EXPECT_EQ(load_scene((d / "UP.OBJ").string(), quiet()).triangle_count(), 4u);
  write_text(d / "x.stl", "solid x\n");
  std::string msg = test::error_of([&] { load_scene((d / "x.stl").string(), quiet()); });
  EXPECT_NE(msg.find("x.stl"), std::string::npos) << msg;
  msg = test::error_of([&] { load_scene((d / "missing.ply").string(), quiet()); });
  EXPECT_NE(msg.find("missing.ply"), std::string::npos) << msg;
  EXPECT_NE(msg.find("not found"), std::string::npos) << msg;
  msg = test::error_of([&] { load_scene("no-such-builtin", quiet()); });
  EXPECT_NE(msg.find("no-such-builtin"), std::string::npos) << msg;
  fs::remove_all(d);
}

TEST(LoadDataPaths, SearchOrderCliThenEnvThenSourceTree) {
  const fs::path a = test::temp_dir("dpa"), b = test::temp_dir("dpb");
  write_text(a / "only_a.obj", obj_text());
  write_text(b / "only_a.obj", obj_text());
  write_text(b / "only_b.obj", obj_text());
  const char* old = std::getenv("SPECULA_DATA");
  const std::string saved = old ? old : "";
  ::setenv("SPECULA_DATA", b.c_str(), 1);
  DataPaths dp;
  dp.cli_dir = a.string();
  const auto sp = dp.search_path();
  ASSERT_GE(sp.size(), 3u);
  EXPECT_EQ(sp[0], a);
  EXPECT_EQ(sp[1], b);
  EXPECT_NE(sp[2].string().find("shared/data/meshes"), std::string::npos);
  EXPECT_EQ(dp.find("only_a.obj"), a / "only_a.obj");
  EXPECT_EQ(dp.find("only_b.obj"), b / "only_b.obj");
  EXPECT_TRUE(dp.find("nowhere.obj").empty());
  EXPECT_NE(dp.describe().find(a.string() + ":" + b.string()), std::string::npos);
  if (old) ::setenv("SPECULA_DATA", saved.c_str(), 1);
  else ::unsetenv("SPECULA_DATA");
  fs::remove_all(a);
  fs::remove_all(b);
}

TEST(LoadWarn, DefaultWarnPrintsToStderr) {
  const fs::path d = test::temp_dir("warn");
  write_text(d / "m.obj", "mtllib nothere.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n");
  ::testing::internal::CaptureStderr();
  load_obj(d / "m.obj");
  const std::string err = ::testing::internal::GetCapturedStderr();
  EXPECT_NE(err.find("warning: "), std::string::npos) << err;
  fs::remove_all(d);
}

TEST(JsonScene, DataMeshesAreFoundThroughDataPaths) {
  SPECULA_REQUIRE_MESH(bunny, "stanford-bunny.obj");
  const fs::path d = test::temp_dir("jsondata");
  write_text(d / "b.json", R"({"meshes": [{"data": "stanford-bunny.obj", "material": {"diffuse": [1, 1, 1]},
                                          "transform": {"scale": 10}}]})");
  LoadOptions o = quiet();
  o.data.cli_dir = bunny.parent_path().string();
  const Scene s = load_scene((d / "b.json").string(), o);
  EXPECT_EQ(s.triangle_count(), 69451u);
  o.data.cli_dir = d.string();
  write_text(d / "m.json", R"({"meshes": [{"data": "no-such-mesh.obj"}]})");
  const std::string msg = test::error_of([&] { load_scene((d / "m.json").string(), o); });
  EXPECT_NE(msg.find("m.json"), std::string::npos) << msg;
  EXPECT_NE(msg.find("no-such-mesh.obj"), std::string::npos) << msg;
  EXPECT_NE(msg.find(d.string()), std::string::npos) << msg;  // names the search path
  fs::remove_all(d);
}

TEST(LoadTiming, BinaryAndAsciiPlyOfTheBunny) {
  SPECULA_REQUIRE_MESH(bunny, "stanford-bunny.obj");
  const Scene src = load_obj(bunny, quiet());
  const fs::path d = test::temp_dir("plytime");
  std::vector<uint8_t> bin;
  const std::string h = "ply\nformat binary_little_endian 1.0\nelement vertex " + std::to_string(src.positions.size()) +
                        "\nproperty float x\nproperty float y\nproperty float z\nelement face " +
                        std::to_string(src.triangle_count()) + "\nproperty list uchar int vertex_indices\nend_header\n";
  bin.assign(h.begin(), h.end());
  std::ostringstream ascii;
  ascii << "ply\nformat ascii 1.0\nelement vertex " << src.positions.size()
        << "\nproperty float x\nproperty float y\nproperty float z\nelement face " << src.triangle_count()
        << "\nproperty list uchar int vertex_indices\nend_header\n";
  ascii.precision(9);
  for (const Vec3& p : src.positions) {
    put<float>(bin, p.x);
    put<float>(bin, p.y);
    put<float>(bin, p.z);
    ascii << p.x << ' ' << p.y << ' ' << p.z << '\n';
  }
  for (size_t t = 0; t < src.triangle_count(); ++t) {
    put<uint8_t>(bin, 3);
    ascii << 3;
    for (int c = 0; c < 3; ++c) {
      put<int32_t>(bin, static_cast<int32_t>(src.indices[3 * t + static_cast<size_t>(c)]));
      ascii << ' ' << src.indices[3 * t + static_cast<size_t>(c)];
    }
    ascii << '\n';
  }
  write_bytes(d / "b.ply", bin);
  write_text(d / "a.ply", ascii.str());
  for (const char* f : {"b.ply", "a.ply"}) {
    const auto t0 = std::chrono::steady_clock::now();
    const Scene s = load_ply(d / f, quiet());
    const double ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
    EXPECT_EQ(s.indices, src.indices) << f;
    EXPECT_EQ(s.positions, src.positions) << f;
    std::printf("  bunny as %s: %.1f ms\n", f, ms);
  }
  fs::remove_all(d);
}

TEST(JsonScene, AFilePlacedTwiceSharesItsMaterials) {
  const fs::path d = test::temp_dir("jsontwice");
  write_text(d / "a.mtl", "newmtl red\nKd 1 0 0\n");
  write_text(d / "t.obj", "mtllib a.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nusemtl red\nf 1 2 3\n");
  write_text(d / "s.json", R"({"meshes": [{"file": "t.obj"}, {"file": "./t.obj", "transform": {"translate": [0, 0, 2]}},
                                         {"file": "t.obj", "material": {"diffuse": [0, 1, 0]}}]})");
  const Scene s = load_json_scene(d / "s.json", quiet());
  ASSERT_EQ(s.triangle_count(), 3u);
  EXPECT_EQ(s.material_ids[0], s.material_ids[1]);
  EXPECT_EQ(s.materials[s.material_ids[0]].name, "red");
  EXPECT_EQ(s.materials[s.material_ids[2]].diffuse, (Vec3{0, 1, 0}));
  EXPECT_EQ(s.positions[s.indices[3]], (Vec3{0, 0, 2}));
  fs::remove_all(d);
}
