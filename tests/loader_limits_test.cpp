// Input limits (InputLimits, docs/SECURITY.md "Limits"): each is refused on a small file when
// lowered below what the file needs, with a message naming the file, the value, the limit and
// the flag that raises it, and accepted at the default. Plus the size parser behind the flags.
#include <gtest/gtest.h>

#include <cstdint>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "specula/error.h"
#include "specula/image.h"
#include "specula/load.h"
#include "test_util.h"

using namespace specula;
namespace fs = std::filesystem;

namespace {

const fs::path kSamples = fs::path(SPECULA_TEST_DATA_DIR) / "samples";

LoadOptions with_limits(const InputLimits& limits) {
  LoadOptions o;
  o.limits = limits;
  o.warn = [](const std::string&) {};
  return o;
}

/// Loads \p path with \p limits and returns the error message ("" if it loaded).
std::string refusal(const fs::path& path, const InputLimits& limits) {
  try {
    (void)load_scene(path.string(), with_limits(limits));
  } catch (const Error& e) {
    return e.what();
  }
  return {};
}

std::string read_text(const fs::path& p) {
  std::ifstream in(p, std::ios::binary);
  return std::string(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
}

bool contains(const std::string& s, const std::string& part) { return s.find(part) != std::string::npos; }

class LoaderLimits : public ::testing::Test {
 protected:
  void SetUp() override { dir_ = test::temp_dir(::testing::UnitTest::GetInstance()->current_test_info()->name()); }
  void TearDown() override { fs::remove_all(dir_); }
  fs::path copy(const std::string& sample) {
    fs::copy_file(kSamples / sample, dir_ / sample, fs::copy_options::overwrite_existing);
    return dir_ / sample;
  }
  fs::path write(const std::string& name, const std::string& bytes) {
    std::ofstream(dir_ / name, std::ios::binary) << bytes;
    return dir_ / name;
  }
  /// A JSON scene with a 4x2 image sky (PNG written by write_png) over the sample cube.
  fs::path sky_scene() {
    const std::vector<Vec3> px(8, Vec3{0.5f, 0.25f, 1.0f});
    write_png((dir_ / "sky.png").string(), 4, 2, px);
    copy("cube.obj");
    copy("cube.mtl");
    return write("sky.json", R"({"meshes": [{"file": "cube.obj"}], "sky": {"type": "image", "image": "sky.png"}})");
  }
  fs::path dir_;
};

}  // namespace

// ---------------------------------------------------------------------------------------------
// max_file_bytes (--max-file-size)

TEST_F(LoaderLimits, FileSizeLimitAppliesToEveryFormat) {
  for (const char* name : {"cube.obj", "cube_le.ply", "cube_ascii.ply", "cube.glb", "cube_embedded.gltf", "scene.json"}) {
    const fs::path p = kSamples / name;
    const uint64_t size = fs::file_size(p);
    InputLimits small;
    small.max_file_bytes = size - 1;
    const std::string why = refusal(p, small);
    EXPECT_TRUE(contains(why, name)) << why;
    EXPECT_TRUE(contains(why, "file is " + format_bytes(size, true) + ", over the limit of " +
                                  format_bytes(size - 1, true)))
        << why;
    EXPECT_TRUE(contains(why, "--max-file-size")) << why;
    InputLimits exact;
    exact.max_file_bytes = size;
    EXPECT_EQ(refusal(p, exact), "") << name;
    EXPECT_EQ(refusal(p, InputLimits{}), "") << name;
  }
}

TEST_F(LoaderLimits, ReferencedFileOverTheLimitIsRefusedEvenWhenTheSceneIsSmall) {
  // A tiny OBJ naming a 2000-byte MTL: the OBJ passes a 1000-byte limit, the MTL does not.
  std::string mtl = "newmtl red\nKd 1 0 0\n";
  while (mtl.size() < 2000) mtl += "# padding padding padding padding padding\n";
  write("big.mtl", mtl);
  const fs::path obj = write("small.obj", "mtllib big.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nusemtl red\nf 1 2 3\n");
  InputLimits limits;
  limits.max_file_bytes = 1000;
  const std::string why = refusal(obj, limits);
  EXPECT_TRUE(contains(why, "small.obj")) << why;
  EXPECT_TRUE(contains(why, "mtllib 'big.mtl'")) << why;
  EXPECT_TRUE(contains(why, "over the limit of 1000 bytes (--max-file-size raises it)")) << why;
  limits.max_file_bytes = 2000 + mtl.size();
  EXPECT_EQ(refusal(obj, limits), "");
}

TEST_F(LoaderLimits, GltfBufferOverTheLimitIsRefused) {
  // The sample's buffer grown to 4096 bytes (declared and on disk; the views use the first
  // bytes), so the .gltf (about 2 KiB) fits a 3000-byte limit and its buffer does not.
  nlohmann::json doc = nlohmann::json::parse(read_text(kSamples / "cube_external.gltf"));
  const uint64_t used = doc["buffers"][0]["byteLength"].get<uint64_t>();
  ASSERT_LT(used, 4096u);
  doc["buffers"][0]["byteLength"] = 4096;
  const fs::path gltf = write("big_buffer.gltf", doc.dump());
  std::string bin = read_text(kSamples / "cube_external.bin");
  bin.resize(4096, '\0');
  write("cube_external.bin", bin);
  ASSERT_LT(fs::file_size(gltf), 3000u);
  InputLimits limits;
  limits.max_file_bytes = 3000;
  const std::string why = refusal(gltf, limits);
  EXPECT_TRUE(contains(why, "big_buffer.gltf")) << why;
  EXPECT_TRUE(contains(why, "cube_external.bin")) << why;
  EXPECT_TRUE(contains(why, "file is 4 KiB, over the limit of 3,000 bytes (2.93 KiB) (--max-file-size raises it)")) << why;
  EXPECT_EQ(refusal(gltf, InputLimits{}), "");
}

// ---------------------------------------------------------------------------------------------
// max_elements (--max-elements)

TEST_F(LoaderLimits, ElementLimitAppliesToEveryFormat) {
  for (const char* name : {"cube.obj", "cube_le.ply", "cube_be.ply", "cube_ascii.ply", "cube.glb", "cube_embedded.gltf",
                           "cube_external.gltf", "scene.json"}) {
    const fs::path p = kSamples / name;
    const Scene s = load_scene(p.string(), with_limits({}));
    const uint64_t need = std::max<uint64_t>(s.positions.size(), s.indices.size());
    InputLimits limits;
    limits.max_elements = need - 1;
    const std::string why = refusal(p, limits);
    EXPECT_TRUE(contains(why, name)) << why;
    EXPECT_TRUE(contains(why, "over the limit of " + std::to_string(need - 1))) << why;
    EXPECT_TRUE(contains(why, "of scene memory; --max-elements raises the limit")) << why;
    limits.max_elements = need;
    EXPECT_EQ(refusal(p, limits), "") << name;
  }
}

TEST_F(LoaderLimits, PlyVertexCountIsCheckedInTheHeader) {
  // The header claims 5 vertices; the limit is checked before the body is read.
  const fs::path p = write("v.ply",
                           "ply\nformat ascii 1.0\nelement vertex 5\nproperty float x\nproperty float y\nproperty "
                           "float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n"
                           "0 0 0\n1 0 0\n0 1 0\n0 0 1\n1 1 1\n3 0 1 2\n");
  InputLimits limits;
  limits.max_elements = 4;
  const std::string why = refusal(p, limits);
  EXPECT_TRUE(contains(why, "v.ply: element 'vertex': 5 vertices, over the limit of 4")) << why;
  limits.max_elements = 5;
  EXPECT_EQ(refusal(p, limits), "");
}

TEST_F(LoaderLimits, ObjVertexLinesAreCountedBeforeParsing) {
  const fs::path p = write("v.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 5 5 5\nv 6 6 6\nf 1 2 3\n");
  InputLimits limits;
  limits.max_elements = 4;
  const std::string why = refusal(p, limits);
  EXPECT_TRUE(contains(why, "v.obj: 5 vertices, over the limit of 4 (about 120 bytes of scene memory")) << why;
  limits.max_elements = 5;
  EXPECT_EQ(refusal(p, limits), "");
}

TEST_F(LoaderLimits, ObjFannedIndicesAreCounted) {
  // One hexagon: 6 vertices, 4 triangles after fanning = 12 indices.
  const fs::path p = write("hex.obj", "v 0 0 0\nv 1 0 0\nv 2 1 0\nv 1 2 0\nv 0 2 0\nv -1 1 0\nf 1 2 3 4 5 6\n");
  InputLimits limits;
  limits.max_elements = 11;
  const std::string why = refusal(p, limits);
  EXPECT_TRUE(contains(why, "hex.obj: 12 triangle indices, over the limit of 11")) << why;
  limits.max_elements = 12;
  EXPECT_EQ(refusal(p, limits), "");
}

TEST_F(LoaderLimits, CeilingIsBelowThe32BitIndexRange) {
  EXPECT_EQ(kMaxElementsCeiling, 0xFFFFFFF0u);
  EXPECT_EQ(InputLimits{}.max_elements, uint64_t{1} << 31);
  EXPECT_LE(InputLimits{}.max_elements, kMaxElementsCeiling);
}

// ---------------------------------------------------------------------------------------------
// max_image_bytes (--max-image-memory)

TEST_F(LoaderLimits, ImageDecodeMemoryLimitRefusesWithTheEstimate) {
  const fs::path json = sky_scene();
  // 4x2 pixels: 4 bytes (stb_image's RGB(A) buffer) + 12 (our RGB copy) a pixel = 128 bytes.
  InputLimits limits;
  limits.max_image_bytes = 127;
  const std::string why = refusal(json, limits);
  EXPECT_TRUE(contains(why, "sky.json")) << why;
  EXPECT_TRUE(contains(why, "sky.png: 4x2 image needs about 128 bytes to decode, over the limit of 127 bytes "
                            "(--max-image-memory raises it)"))
      << why;
  limits.max_image_bytes = 128;
  EXPECT_EQ(refusal(json, limits), "");
  EXPECT_EQ(refusal(json, InputLimits{}), "");
}

TEST_F(LoaderLimits, ReadImageTakesTheLimits) {
  const std::vector<Vec3> px(8, Vec3{0.5f, 0.25f, 1.0f});
  write_png((dir_ / "a.png").string(), 4, 2, px);
  int w = 0, h = 0;
  InputLimits limits;
  limits.max_image_bytes = 100;
  EXPECT_THROW((void)read_image((dir_ / "a.png").string(), w, h, limits), Error);
  limits = {};
  limits.max_file_bytes = 10;
  try {
    (void)read_image((dir_ / "a.png").string(), w, h, limits);
    ADD_FAILURE() << "read despite the file size limit";
  } catch (const Error& e) {
    EXPECT_TRUE(contains(e.what(), "a.png: file is")) << e.what();
    EXPECT_TRUE(contains(e.what(), "--max-file-size")) << e.what();
  }
  EXPECT_EQ(read_image((dir_ / "a.png").string(), w, h).size(), 8u);
}

// ---------------------------------------------------------------------------------------------
// Sizes on the command line

TEST(ByteSize, ParsesUnitsAsPowersOf1024) {
  EXPECT_EQ(parse_byte_size("1"), 1u);
  EXPECT_EQ(parse_byte_size("4294967296"), uint64_t{1} << 32);
  EXPECT_EQ(parse_byte_size("100b"), 100u);
  EXPECT_EQ(parse_byte_size("64k"), uint64_t{64} << 10);
  EXPECT_EQ(parse_byte_size("64KiB"), uint64_t{64} << 10);
  EXPECT_EQ(parse_byte_size("64KB"), uint64_t{64} << 10);
  EXPECT_EQ(parse_byte_size("512MiB"), uint64_t{512} << 20);
  EXPECT_EQ(parse_byte_size("8GiB"), uint64_t{8} << 30);
  EXPECT_EQ(parse_byte_size("8g"), uint64_t{8} << 30);
  EXPECT_EQ(parse_byte_size("8 GiB"), uint64_t{8} << 30);
  EXPECT_EQ(parse_byte_size("2T"), uint64_t{2} << 40);
  EXPECT_EQ(parse_byte_size("1.5G"), uint64_t{3} << 29);
  EXPECT_EQ(parse_byte_size("0.5k"), 512u);
  EXPECT_EQ(parse_byte_size("18446744073709551615"), UINT64_MAX);
}

TEST(ByteSize, RefusesWhatItCannotReadClearly) {
  for (const char* bad : {"", "G", "-1", "0", "0GiB", "1e9", "8XB", "8 G B", "1.2.3", ".", "8GiBs", "0x10",
                          "18446744073709551616", "16777216T", "99999999999999999999999"}) {
    try {
      (void)parse_byte_size(bad);
      ADD_FAILURE() << "accepted '" << bad << "'";
    } catch (const Error& e) {
      EXPECT_TRUE(contains(e.what(), std::string("'") + bad + "'")) << e.what();
      EXPECT_TRUE(contains(e.what(), "powers of 1024")) << e.what();
    }
  }
}

TEST(ByteSize, FormatsForMessages) {
  EXPECT_EQ(format_bytes(0), "0 bytes");
  EXPECT_EQ(format_bytes(1), "1 byte");
  EXPECT_EQ(format_bytes(1023), "1023 bytes");
  EXPECT_EQ(format_bytes(1024), "1 KiB");
  EXPECT_EQ(format_bytes(uint64_t{1} << 30), "1 GiB");
  EXPECT_EQ(format_bytes(uint64_t{4} << 30), "4 GiB");
  EXPECT_EQ(format_bytes(uint64_t{3} << 29), "1.50 GiB");
  EXPECT_EQ(format_bytes(uint64_t{300} << 20), "300 MiB");
  EXPECT_EQ(format_bytes(UINT64_MAX), "16.00 EiB");
  EXPECT_EQ(format_bytes(1744, true), "1,744 bytes (1.70 KiB)");
  EXPECT_EQ(format_bytes(1023, true), "1023 bytes");
  EXPECT_EQ(format_bytes(uint64_t{4} << 30, true), "4 GiB");
  for (uint64_t v : {uint64_t{1} << 30, uint64_t{4} << 30, uint64_t{300} << 20, uint64_t{2} << 40})
    EXPECT_EQ(parse_byte_size(format_bytes(v)), v) << format_bytes(v);
}
