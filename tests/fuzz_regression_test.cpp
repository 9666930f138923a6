// Fuzz regressions: every input under tests/data/fuzz-regressions/<target>/ (crashes the
// libFuzzer targets found, see docs/SECURITY.md) and every seed of fuzz/corpus/<target>/ is
// replayed exactly as the fuzz target runs it (fuzz/fuzz_targets.h). Each must load cleanly or
// be refused with specula::Error; a broken invariant or any other exception fails the test, and
// under the asan preset a memory error or leak fails it too. Seeds not named "broken_*" are
// valid files and must load (so the fuzzers start from inputs that reach deep).
#include <gtest/gtest.h>

#include <algorithm>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <string>
#include <vector>

#include "fuzz_targets.h"
#include "specula/error.h"
#include "specula/image.h"
#include "specula/load.h"
#include "test_util.h"

namespace fs = std::filesystem;

namespace {

struct Input {
  std::string target;
  fs::path file;
};

/// Every regular file of ROOT/<target>/ for each known target; files in folders that name no
/// target are reported as failures (a crasher filed in the wrong place would never run).
std::vector<Input> inputs_under(const fs::path& root, std::vector<std::string>* stray) {
  std::vector<Input> out;
  std::error_code ec;
  if (!fs::is_directory(root, ec)) return out;
  for (const auto& dir : fs::directory_iterator(root)) {
    if (!dir.is_directory()) continue;
    const std::string target = dir.path().filename().string();
    const bool known = specula::fuzz::targets().count(target) != 0;
    for (const auto& f : fs::directory_iterator(dir.path())) {
      if (!f.is_regular_file()) continue;
      if (!known) {
        if (stray) stray->push_back(f.path().string());
        continue;
      }
      out.push_back({target, f.path()});
    }
  }
  std::sort(out.begin(), out.end(), [](const Input& a, const Input& b) { return a.file < b.file; });
  return out;
}

std::string slurp(const fs::path& p) {
  std::ifstream in(p, std::ios::binary);
  return std::string(std::istreambuf_iterator<char>(in), {});
}

/// Replays every input; returns how many loaded and how many were refused. With
/// \p valid_unless_broken, inputs whose names do not start with "broken_" must load.
std::pair<size_t, size_t> replay(const std::vector<Input>& inputs, bool valid_unless_broken = false) {
  size_t loaded = 0, refused = 0;
  for (const Input& in : inputs) {
    const std::string data = slurp(in.file);
    try {
      specula::fuzz::targets().at(in.target)(data);
      ++loaded;
    } catch (const specula::Error& e) {
      ++refused;
      if (valid_unless_broken && in.file.filename().string().rfind("broken_", 0) != 0)
        ADD_FAILURE() << in.file << " (" << in.target << "): a valid seed was refused: " << e.what();
    } catch (const specula::fuzz::Bug& e) {
      ADD_FAILURE() << in.file << " (" << in.target << "): " << e.what();
    } catch (const std::exception& e) {
      ADD_FAILURE() << in.file << " (" << in.target << "): non-specula exception: " << e.what();
    }
  }
  return {loaded, refused};
}

}  // namespace

TEST(FuzzRegression, EveryCrasherLoadsOrIsRefusedCleanly) {
  std::vector<std::string> stray;
  const auto inputs = inputs_under(fs::path(SPECULA_TEST_DATA_DIR) / "fuzz-regressions", &stray);
  for (const std::string& s : stray) ADD_FAILURE() << s << ": not in a folder named after a fuzz target";
  const auto [loaded, refused] = replay(inputs);
  std::printf("  fuzz regressions: %zu files, loaded %zu, refused %zu\n", inputs.size(), loaded, refused);
}

TEST(FuzzRegression, EverySeedLoadsOrIsRefusedCleanly) {
  std::vector<std::string> stray;
  const auto inputs = inputs_under(fs::path(SPECULA_SOURCE_DIR) / "fuzz" / "corpus", &stray);
  for (const std::string& s : stray) ADD_FAILURE() << s << ": not in a folder named after a fuzz target";
  EXPECT_GE(inputs.size(), specula::fuzz::targets().size());
  const auto [loaded, refused] = replay(inputs, /*valid_unless_broken=*/true);
  std::printf("  fuzz seeds: %zu files, loaded %zu, refused %zu\n", inputs.size(), loaded, refused);
  EXPECT_GT(loaded, 0u);
}

// ---------------------------------------------------------------------------------------------
// The findings one by one (docs/SECURITY.md, "Findings so far"), beyond the replay above.

namespace {

fs::path findings_dir() {
  const fs::path dir = fs::temp_directory_path() /
                       ("specula-findings-" + std::to_string(::testing::UnitTest::GetInstance()->random_seed()) +
                        "-" + ::testing::UnitTest::GetInstance()->current_test_info()->name());
  fs::remove_all(dir);
  fs::create_directories(dir);
  return dir;
}

/// tests/data/fuzz-regressions/TARGET/NAME: a finding's input (tests copy it under a name whose
/// extension picks the loader).
fs::path regression_file(const char* target, const char* name) {
  return fs::path(SPECULA_TEST_DATA_DIR) / "fuzz-regressions" / target / name;
}

std::string load_error(const fs::path& p) {
  return specula::test::error_of([&] {
    specula::LoadOptions o;
    o.warn = [](const std::string&) {};
    (void)specula::load_scene(p.string(), o);
  });
}

/// The message of read_image()'s refusal of \p p, or "(no specula::Error thrown)".
std::string image_error(const fs::path& p) {
  return specula::test::error_of([&] {
    int w = 0, h = 0;
    (void)specula::read_image(p.string(), w, h);
  });
}

}  // namespace

// fuzz_ply, UBSan float-cast-overflow: an ascii list count beyond 2^64 (1e308, inf) was
// converted to uint64_t before it was compared with the bytes left in the file.
TEST(FuzzFindings, PlyListCountBeyondAnIntegerIsRefusedNamingTheCount) {
  const fs::path dir = findings_dir();
  for (const char* count : {"1e308", "inf", "18446744073709551616"}) {
    const fs::path p = dir / "huge_list.ply";
    std::ofstream(p, std::ios::binary)
        << "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
           "element face 1\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n0 1 0\n"
        << count << " 0 1 2\n";
    const std::string msg = load_error(p);
    EXPECT_NE(msg.find("huge_list.ply: line 13: element 'face' 0: list 'vertex_indices' claims "), std::string::npos)
        << count << ": " << msg;
    EXPECT_NE(msg.find("more than the rest of the file holds"), std::string::npos) << count << ": " << msg;
  }
  fs::remove_all(dir);
}

// fuzz_gltf, UBSan (a one-hour run with a random seed, 2026-12-07): a buffer whose data URI is
// shorter than its byteLength of 1e47 was refused, but the message converted 1e47 to uint64_t
// (undefined behaviour). The refusal must print the number as written.
TEST(FuzzFindings, GltfHugeByteLengthOfADataUriIsRefusedNamingIt) {
  const fs::path dir = findings_dir();
  fs::copy_file(regression_file("fuzz_gltf", "crash-c0992f59-data-uri-bytelength-1e47"),
                dir / "huge.gltf");
  const std::string msg = load_error(dir / "huge.gltf");
  EXPECT_NE(msg.find("buffers[0].uri: byteLength 1e+47 exceeds what the data URI holds (45 bytes at most)"),
            std::string::npos)
      << msg;
  fs::remove_all(dir);
}

// fuzz_sky_image, out of memory (a 14-minute run with a random seed, 2026-12-07): tinyexr sizes
// a scanline EXR's offset table by its chunkCount attribute unchecked; 527 bytes claiming 1.8
// billion chunks made it allocate 14 GB. The table must fit in the file.
TEST(FuzzFindings, ExrChunkCountBeyondTheFileIsRefusedBeforeAllocating) {
  const fs::path dir = findings_dir();
  fs::copy_file(regression_file("fuzz_sky_image", "oom-6db908c9-exr-chunkcount-huge"),
                dir / "chunks.exr");
  const std::string msg = image_error(dir / "chunks.exr");
  EXPECT_NE(msg.find("cannot read EXR: chunkCount "), std::string::npos) << msg;
  EXPECT_NE(msg.find(" claims more chunk offsets than the file holds (527 bytes)"), std::string::npos) << msg;
  fs::remove_all(dir);
}

// fuzz_sky_image, LeakSanitizer: tinyexr's LoadEXR leaked the channel buffers of an EXR whose
// pixel data fails to decode. The error must name the file (the leak itself is caught by the
// asan stage replaying the regression file).
TEST(FuzzFindings, ExrWithCorruptPixelDataIsAnError) {
  const fs::path dir = findings_dir();
  const fs::path src = regression_file("fuzz_sky_image", "leak-08ad273b-exr-bad-pixel-data");
  ASSERT_TRUE(fs::is_regular_file(src));
  fs::copy_file(src, dir / "sky.exr");
  const std::string msg = image_error(dir / "sky.exr");
  EXPECT_NE(msg.find("sky.exr: cannot read EXR: "), std::string::npos) << msg;
  fs::remove_all(dir);
}

// The EXR reader that replaced LoadEXR assembles tiled images itself: every pixel of a 5x3
// image in 2x2 tiles (partial tiles at the right and bottom) lands where LoadEXR put it.
TEST(FuzzFindings, TiledExrPixelsAreAssembledFromTheirTiles) {
  const fs::path p = fs::path(SPECULA_SOURCE_DIR) / "fuzz" / "corpus" / "fuzz_sky_image" / "tiled_5x3.exr";
  int w = 0, h = 0;
  const std::vector<specula::Vec3> px = specula::read_image(p.string(), w, h);
  ASSERT_EQ(w, 5);
  ASSERT_EQ(h, 3);
  ASSERT_EQ(px.size(), 15u);
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x) {
      const float r = static_cast<float>(x + 10 * y);
      const specula::Vec3 want{r, r + 100.0f, r + 200.0f};
      EXPECT_EQ(px[static_cast<size_t>(y * w + x)], want) << x << "," << y;
    }
}

// fuzz_obj, UBSan float-cast-overflow inside tinyobjloader: a skin-weight line ("vw 9 1e990")
// has its joint id converted from float to int unchecked. specula does not use skin weights, so
// those lines are comments to the library now; the rest of the file loads as before.
TEST(FuzzFindings, ObjSkinWeightLinesAreIgnored) {
  const fs::path dir = findings_dir();
  const fs::path p = dir / "vw.obj";
  std::ofstream(p, std::ios::binary) << "v 0 0 0\nv 1 0 0\r  vw 9 1e990 inf\t1\nv 0 1 0\nvw\t1 inf 2 0.5\r\nf 1 2 3\n";
  specula::LoadOptions o;
  o.warn = [](const std::string&) {};
  const specula::Scene s = specula::load_scene(p.string(), o);
  EXPECT_EQ(s.triangle_count(), 1u);
  fs::remove_all(dir);
}

// fuzz_sky_image, timeout: stb_image 2.27 loops forever on a Radiance RLE scanline cut short by
// the end of the file (CVE-2021-42715). specula decodes .hdr itself: truncated or corrupt RLE
// data and headers claiming more pixels than the file holds are errors, before allocating.
TEST(FuzzFindings, RadianceHdrTruncatedOrBombIsAnError) {
  const fs::path dir = findings_dir();
  const std::string rle_head = "#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y 2 +X 8\n";
  const std::string rle_line = std::string("\x02\x02\x00\x08\x88\x64\x88\x32\x88\x19\x88\x82", 12);
  const std::vector<std::pair<std::string, std::string>> cases{
      {"truncated_rle.hdr", rle_head + rle_line + rle_line.substr(0, 7)},
      {"zero_run.hdr", rle_head + rle_line + std::string("\x02\x02\x00\x08\x00\x00\x00\x00\x00\x00\x00\x00", 12)},
      {"bomb_flat.hdr", "#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y 16000000 +X 7\n"},
      {"bomb_rle.hdr", "#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y 16000 +X 16000\n" + rle_line},
      {"xyze.hdr", "#?RADIANCE\nFORMAT=32-bit_rle_xyze\n\n-Y 1 +X 1\n\x80\x80\x80\x80"},
      {"flipped.hdr", "#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n+Y 1 +X 1\n\x80\x80\x80\x80"},
  };
  for (const auto& [name, bytes] : cases) {
    std::ofstream(dir / name, std::ios::binary) << bytes;
    const std::string msg = image_error(dir / name);
    EXPECT_NE(msg.find(name + ": cannot read Radiance HDR: "), std::string::npos) << msg;
  }
  // The complete file decodes: two RLE scanlines of 8 pixels, (100, 50, 25) * 2^(130 - 136).
  std::ofstream(dir / "ok.hdr", std::ios::binary) << rle_head + rle_line + rle_line;
  int w = 0, h = 0;
  const std::vector<specula::Vec3> px = specula::read_image((dir / "ok.hdr").string(), w, h);
  ASSERT_EQ(w, 8);
  ASSERT_EQ(h, 2);
  for (const specula::Vec3& c : px) EXPECT_EQ(c, (specula::Vec3{100.0f / 64, 50.0f / 64, 25.0f / 64}));
  fs::remove_all(dir);
}

// fuzz_sky_image, UBSan signed overflow inside tinyexr: a tiled EXR chunk with tile x = -2^31 is
// multiplied by the tile size in int. Tile coordinates are now checked before tinyexr decodes.
TEST(FuzzFindings, ExrTileCoordinatesOutOfRangeAreAnError) {
  const fs::path dir = findings_dir();
  std::string exr = slurp(fs::path(SPECULA_SOURCE_DIR) / "fuzz" / "corpus" / "fuzz_sky_image" / "tiled_5x3.exr");
  // The offset table follows the header, whose last attribute is "tiles" (a 9-byte tiledesc)
  // and which ends with a NUL.
  const size_t tiles = exr.find(std::string("tiledesc\0", 9));
  ASSERT_NE(tiles, std::string::npos);
  const size_t table = tiles + 9 + 4 + 9 + 1;
  uint64_t first = 0;
  for (int i = 7; i >= 0; --i) first = first << 8 | static_cast<unsigned char>(exr[table + static_cast<size_t>(i)]);
  ASSERT_LT(first + 4, exr.size());
  exr.replace(static_cast<size_t>(first), 4, std::string("\x00\x00\x00\x80", 4));  // tile x = INT_MIN
  std::ofstream(dir / "tile.exr", std::ios::binary) << exr;
  const std::string msg = image_error(dir / "tile.exr");
  EXPECT_NE(msg.find("tile.exr: cannot read EXR: tile 0: coordinates (-2147483648, 0"), std::string::npos) << msg;
  fs::remove_all(dir);
}

// fuzz_sky_image, std::out_of_range escaping tinyexr: a "tiles" attribute shorter than its 9
// bytes made tinyexr read past it. The header's attributes are checked before tinyexr parses.
TEST(FuzzFindings, ExrShortTilesAttributeIsAnError) {
  const fs::path dir = findings_dir();
  std::string exr = slurp(fs::path(SPECULA_SOURCE_DIR) / "fuzz" / "corpus" / "fuzz_sky_image" / "tiled_5x3.exr");
  const size_t tiles = exr.find(std::string("tiledesc\0", 9));
  ASSERT_NE(tiles, std::string::npos);
  exr[tiles + 9] = 4;  // size 9 -> 4; the other 5 bytes now read as the next attribute
  std::ofstream(dir / "tiles.exr", std::ios::binary) << exr;
  const std::string msg = image_error(dir / "tiles.exr");
  EXPECT_NE(msg.find("tiles.exr: cannot read EXR: byte "), std::string::npos) << msg;
  EXPECT_NE(msg.find("attribute 'tiles' has 4 bytes, expected 9"), std::string::npos) << msg;
  fs::remove_all(dir);
}

// fuzz_sky_image, UBSan inside stb_image: a zero-length first IDAT chunk (legal PNG) is copied
// with memcpy from a null buffer. Empty IDAT chunks are dropped before stb_image decodes; a
// valid PNG that has one still loads with the right pixels.
TEST(FuzzFindings, PngWithEmptyIdatLoads) {
  const fs::path p = fs::path(SPECULA_SOURCE_DIR) / "fuzz" / "corpus" / "fuzz_sky_image" / "empty_idat_2x1.png";
  int w = 0, h = 0;
  const std::vector<specula::Vec3> px = specula::read_image(p.string(), w, h);
  ASSERT_EQ(w, 2);
  ASSERT_EQ(h, 1);
  EXPECT_EQ(px[0], (specula::Vec3{1.0f, 0.0f, 0.0f}));
  EXPECT_EQ(px[1], (specula::Vec3{0.0f, 0.0f, 1.0f}));
}

// fuzz_sky_image, out of memory: a 142-byte PNG whose second IDAT chunk claims 1.7 GB made
// stb_image grow its IDAT buffer to 2 GiB before reading. Every chunk length is checked against
// the bytes left first; a valid PNG with data after IEND still loads.
TEST(FuzzFindings, PngChunkLongerThanTheFileIsRefusedBeforeAllocating) {
  const fs::path dir = findings_dir();
  fs::copy_file(regression_file("fuzz_sky_image", "oom-16ae1b3d-png-idat-length-beyond-file"),
                dir / "bomb.png");
  const std::string msg = image_error(dir / "bomb.png");
  EXPECT_NE(msg.find("bomb.png: cannot read PNG: byte 63: chunk 'IDAT' claims 1700986898 bytes, "
                     "the file has 67 left (truncated or corrupt)"),
            std::string::npos)
      << msg;
  const fs::path ok = fs::path(SPECULA_SOURCE_DIR) / "fuzz" / "corpus" / "fuzz_sky_image" / "empty_idat_2x1.png";
  std::ifstream in(ok, std::ios::binary);
  std::string png((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  png += "trailing bytes after IEND \xff\xff\xff\xff";
  std::ofstream(dir / "trailing.png", std::ios::binary) << png;
  int w = 0, h = 0;
  EXPECT_EQ(specula::read_image((dir / "trailing.png").string(), w, h).size(), 2u);
  fs::remove_all(dir);
}

// fuzz_sky_image, out of memory: a 570-byte tiled EXR claiming huge tiles made tinyexr allocate
// 3 GB. The decoding memory is estimated from the header first and refused over the budget.
TEST(FuzzFindings, ExrClaimingHugeTilesIsRefusedBeforeAllocating) {
  const fs::path dir = findings_dir();
  fs::copy_file(regression_file("fuzz_sky_image", "oom-05721490-exr-huge-tiles"),
                dir / "huge.exr");
  const std::string msg = image_error(dir / "huge.exr");
  EXPECT_NE(msg.find("to decode, over the limit of 1 GiB (--max-image-memory raises it)"), std::string::npos) << msg;
  fs::remove_all(dir);
}
