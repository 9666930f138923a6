// Image output: PNG/EXR round trips, AOV files, sky images and atomic writing.
#include <gtest/gtest.h>
#include <signal.h>
#include <sys/resource.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cmath>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <vector>

#include <stb_image_write.h>
#include <tinyexr.h>

#include "specula/accel.h"
#include "specula/error.h"
#include "specula/image.h"
#include "io/image_util.h"
#include "specula/render.h"
#include "test_util.h"

using namespace specula;
namespace fs = std::filesystem;

namespace {

std::vector<uint8_t> slurp(const fs::path& p) {
  std::ifstream in(p, std::ios::binary);
  return {std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
}

/// Files in \p dir whose name contains ".tmp-" (leftovers of write_file_atomic).
std::vector<std::string> temp_leftovers(const fs::path& dir) {
  std::vector<std::string> out;
  for (const auto& e : fs::directory_iterator(dir))
    if (e.path().filename().string().find(".tmp-") != std::string::npos) out.push_back(e.path().string());
  return out;
}

float srgb_decode_for_test(float v) { return std::pow((v + 0.055f) / 1.055f, 2.4f); }

std::vector<Vec3> gradient_image(int w, int h) {
  std::vector<Vec3> img(static_cast<size_t>(w * h));
  for (size_t y = 0; y < static_cast<size_t>(h); ++y)
    for (size_t x = 0; x < static_cast<size_t>(w); ++x)
      img[y * static_cast<size_t>(w) + x] = {static_cast<float>(x) / static_cast<float>(w - 1),
                                             static_cast<float>(y) / static_cast<float>(h - 1), 0.25f};
  return img;
}

}  // namespace

TEST(Image, PngRoundTripIsSrgbEncoded) {
  const auto dir = test::temp_dir("png");
  const int w = 17, h = 9;
  const auto img = gradient_image(w, h);
  write_png((dir / "a.png").string(), w, h, img);
  int rw = 0, rh = 0;
  const auto back = read_image((dir / "a.png").string(), rw, rh);
  ASSERT_EQ(rw, w);
  ASSERT_EQ(rh, h);
  for (size_t i = 0; i < img.size(); ++i)
    for (int c = 0; c < 3; ++c) {
      // One 8-bit sRGB step is at most ~0.013 in linear units near 1.
      EXPECT_NEAR(back[i][c], img[i][c], 0.007f) << i;
    }
  // Linear 0.5 is stored as sRGB 188, not 128.
  const std::vector<Vec3> grey(1, Vec3{0.5f});
  write_png((dir / "g.png").string(), 1, 1, grey);
  const auto bytes = slurp(dir / "g.png");
  ASSERT_GT(bytes.size(), 8u);
  EXPECT_EQ(bytes[1], 'P');
  int gw = 0, gh = 0;
  const auto g = read_image((dir / "g.png").string(), gw, gh);
  EXPECT_NEAR(g[0].x, 0.5f, 0.003f);
}

TEST(Image, PngClampsAndReinhardCompresses) {
  const auto dir = test::temp_dir("tonemap");
  const std::vector<Vec3> hdr{{4.0f, 1.0f, -1.0f}, {std::nanf(""), 0.0f, 0.0f}};
  write_png((dir / "c.png").string(), 2, 1, hdr, Tonemap::Clamp);
  write_png((dir / "r.png").string(), 2, 1, hdr, Tonemap::Reinhard);
  int w = 0, h = 0;
  const auto c = read_image((dir / "c.png").string(), w, h);
  const auto r = read_image((dir / "r.png").string(), w, h);
  EXPECT_NEAR(c[0].x, 1.0f, 1e-6f);
  EXPECT_NEAR(c[0].z, 0.0f, 1e-6f);
  EXPECT_NEAR(c[1].x, 0.0f, 1e-6f);      // NaN -> black
  EXPECT_NEAR(r[0].x, 0.8f, 0.01f);      // 4 / (1 + 4)
  EXPECT_NEAR(r[0].y, 0.5f, 0.01f);      // 1 / (1 + 1)
}

TEST(Image, ExrWithoutRgbChannelsIsRefusedNotReadOutOfBounds) {
  // Two float channels named A and Z: no R, G or B to take (used to index channel -1).
  const auto dir = test::temp_dir("exr_az");
  const int w = 4, h = 2;
  std::vector<float> a(size_t{w} * size_t{h}, 0.5f), z(size_t{w} * size_t{h}, 2.0f);
  float* planes[2] = {a.data(), z.data()};
  EXRHeader header;
  InitEXRHeader(&header);
  EXRImage image;
  InitEXRImage(&image);
  image.num_channels = 2;
  image.images = reinterpret_cast<unsigned char**>(planes);
  image.width = w;
  image.height = h;
  EXRChannelInfo channels[2];
  std::memset(channels, 0, sizeof channels);
  std::strcpy(channels[0].name, "A");
  std::strcpy(channels[1].name, "Z");
  int types[2] = {TINYEXR_PIXELTYPE_FLOAT, TINYEXR_PIXELTYPE_FLOAT};
  header.num_channels = 2;
  header.channels = channels;
  header.pixel_types = types;
  header.requested_pixel_types = types;
  const std::string path = (dir / "az.exr").string();
  const char* err = nullptr;
  ASSERT_EQ(SaveEXRImageToFile(&image, &header, path.c_str(), &err), TINYEXR_SUCCESS) << (err ? err : "");
  int rw = 0, rh = 0;
  try {
    read_image(path, rw, rh);
    FAIL() << "an EXR without RGB channels was accepted";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("no R, G and B channels"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("az.exr"), std::string::npos) << e.what();
  }
  fs::remove_all(dir);
}

TEST(Image, ExrRoundTripIsLinearHalf) {
  const auto dir = test::temp_dir("exr");
  const int w = 8, h = 4;
  auto img = gradient_image(w, h);
  img[3] = {100.0f, 0.001f, 7.5f};  // HDR values survive
  write_exr((dir / "a.exr").string(), w, h, img);
  int rw = 0, rh = 0;
  const auto back = read_image((dir / "a.exr").string(), rw, rh);
  ASSERT_EQ(rw, w);
  ASSERT_EQ(rh, h);
  for (size_t i = 0; i < img.size(); ++i)
    for (int c = 0; c < 3; ++c) EXPECT_NEAR(back[i][c], img[i][c], std::max(1e-3f, 1e-3f * img[i][c])) << i;
}

TEST(Image, WriteImagePicksFormatByExtension) {
  const auto dir = test::temp_dir("ext");
  const auto img = gradient_image(4, 4);
  write_image((dir / "x.PNG").string(), 4, 4, img);
  write_image((dir / "x.exr").string(), 4, 4, img);
  EXPECT_TRUE(fs::exists(dir / "x.PNG"));
  EXPECT_TRUE(fs::exists(dir / "x.exr"));
  EXPECT_THROW(write_image((dir / "x.jpg").string(), 4, 4, img), Error);
  EXPECT_THROW(write_image((dir / "x").string(), 4, 4, img), Error);
  EXPECT_FALSE(fs::exists(dir / "x.jpg"));
  // Size mismatch is an error, not a crash.
  EXPECT_THROW(write_png((dir / "bad.png").string(), 5, 4, img), Error);
}

TEST(Image, ReadImageRejectsGarbage) {
  const auto dir = test::temp_dir("garbage");
  std::ofstream(dir / "junk.png") << "not a png at all";
  std::ofstream(dir / "junk.exr") << "not an exr";
  int w = 0, h = 0;
  EXPECT_THROW(read_image((dir / "junk.png").string(), w, h), Error);
  EXPECT_THROW(read_image((dir / "junk.exr").string(), w, h), Error);
  EXPECT_THROW(read_image((dir / "missing.png").string(), w, h), Error);
}

TEST(Image, JpegLoadsAndTruncatedOrOtherStbFormatsAreRefused) {
  const auto dir = test::temp_dir("jpeg");
  // A 16x8 JPEG of one colour, written by stb_image_write.
  std::vector<unsigned char> rgb(16 * 8 * 3);
  for (size_t i = 0; i < rgb.size(); i += 3) rgb[i] = 200, rgb[i + 1] = 100, rgb[i + 2] = 50;
  std::string jpg;
  ASSERT_NE(stbi_write_jpg_to_func(
                [](void* ctx, void* data, int size) { static_cast<std::string*>(ctx)->append(static_cast<char*>(data), size); },
                &jpg, 16, 8, 3, rgb.data(), 95),
            0);
  auto put = [&](const std::string& name, const std::string& bytes) {
    std::ofstream(dir / name, std::ios::binary) << bytes;
    return (dir / name).string();
  };
  int w = 0, h = 0;
  const std::vector<Vec3> px = read_image(put("ok.jpg", jpg), w, h);
  EXPECT_EQ(w, 16);
  EXPECT_EQ(h, 8);
  ASSERT_EQ(px.size(), 128u);
  EXPECT_NEAR(px[0].x, srgb_to_linear(200.0f / 255.0f), 0.02f);
  EXPECT_NEAR(px[0].z, srgb_to_linear(50.0f / 255.0f), 0.02f);
  // Cut short (no end-of-image marker): stb_image would decode zeros past the end.
  const std::string cut = test::error_of([&] { read_image(put("cut.jpg", jpg.substr(0, jpg.size() - 20)), w, h); });
  EXPECT_NE(cut.find("cut.jpg"), std::string::npos) << cut;
  EXPECT_NE(cut.find("truncated"), std::string::npos) << cut;
  // An end-of-image marker with no scan before it (the frame's segments, then EOI).
  const size_t sos = jpg.find("\xff\xda");
  ASSERT_NE(sos, std::string::npos);
  const std::string noscan = test::error_of([&] { read_image(put("noscan.jpg", jpg.substr(0, sos) + "\xff\xd9"), w, h); });
  EXPECT_NE(noscan.find("no end-of-image marker after the image data"), std::string::npos) << noscan;
  // The same header declaring 60000x60000 pixels (SOF0 height and width fields).
  std::string big = jpg;
  const size_t sof = big.find("\xff\xc0");
  ASSERT_NE(sof, std::string::npos);
  big[sof + 5] = big[sof + 7] = '\xea';
  big[sof + 6] = big[sof + 8] = '\x60';
  const std::string huge = test::error_of([&] { read_image(put("huge.jpg", big), w, h); });
  EXPECT_NE(huge.find("60000x60000 image needs at least"), std::string::npos) << huge;
  // A Huffman table of 300 symbols (a JPEG table has at most 256; stb_image writes one byte per
  // symbol into a 257-byte array, found by fuzz_sky_image), whole and well framed, before the
  // frame header and, as progressive JPEGs define tables, after the first scan.
  std::string dht300("\xff\xc4\x01\x3f\x00", 5);
  dht300 += std::string(14, '\0') + "\x96\x96" + std::string(300, '\x01');
  ASSERT_EQ(dht300.size(), 2u + 0x13fu);
  const size_t eoi = jpg.rfind("\xff\xd9");
  ASSERT_NE(eoi, std::string::npos);
  for (const std::string& bad : {jpg.substr(0, 2) + dht300 + jpg.substr(2), jpg.substr(0, eoi) + dht300 + jpg.substr(eoi)}) {
    const std::string m = test::error_of([&] { read_image(put("dht.jpg", bad), w, h); });
    EXPECT_NE(m.find("Huffman table of 300 symbols (at most 256)"), std::string::npos) << m;
  }
  // A table that runs past its segment, and a segment that runs past the end of the file.
  std::string overrun("\xff\xc4\x00\x20\x00", 5);  // 200 symbols in a 32-byte segment
  overrun += std::string(14, '\0') + "\x64\x64" + std::string(13, '\x01');
  const std::string m1 = test::error_of([&] { read_image(put("dht.jpg", jpg.substr(0, 2) + overrun + jpg.substr(2)), w, h); });
  EXPECT_NE(m1.find("Huffman table runs past its segment"), std::string::npos) << m1;
  const std::string m2 = test::error_of([&] { read_image(put("dht.jpg", jpg.substr(0, 2) + dht300.substr(0, 40)), w, h); });
  EXPECT_NE(m2.find("truncated or corrupt"), std::string::npos) << m2;
  // A TGA (no magic number; what fuzz_sky_image turned a 156-byte file into: 21504x2560
  // pixels of zeros), a BMP: not handed to stb_image, whatever the extension says.
  const std::string tga("\0\0\x0a\0\0\0\0\0\0\0\0\0\0\x54\0\x0a\x08\0", 18);
  for (const char* name : {"sky.png", "sky.tga"}) {
    const std::string m = test::error_of([&] { read_image(put(name, tga), w, h); });
    EXPECT_NE(m.find("not a PNG, JPEG, Radiance (.hdr) or OpenEXR (.exr) file"), std::string::npos) << m;
  }
  EXPECT_THROW(read_image(put("sky.bmp", "BM" + std::string(60, '\0')), w, h), Error);
}

TEST(AtomicWrite, ReplacesAnExistingFileWhole) {
  const auto dir = test::temp_dir("atomic");
  const fs::path p = dir / "out.bin";
  std::vector<uint8_t> big(100000, 0xAB), small_bytes{1, 2, 3};
  write_file_atomic(p.string(), big);
  EXPECT_EQ(slurp(p), big);
  write_file_atomic(p.string(), small_bytes);
  EXPECT_EQ(slurp(p), small_bytes);  // no tail of the old content
  EXPECT_TRUE(temp_leftovers(dir).empty());
  // Refuses to overwrite the protected input.
  EXPECT_THROW(write_file_atomic(p.string(), big, p.string()), Error);
  EXPECT_EQ(slurp(p), small_bytes);
}

TEST(AtomicWrite, MissingOrNonDirectoryFolderThrowsWithoutTempFiles) {
  const auto dir = test::temp_dir("atomic-missing");
  const std::vector<uint8_t> bytes{1, 2, 3};
  EXPECT_THROW(write_file_atomic((dir / "no" / "such" / "out.png").string(), bytes), Error);
  std::ofstream(dir / "plainfile") << "x";
  EXPECT_THROW(write_file_atomic((dir / "plainfile" / "out.png").string(), bytes), Error);
  EXPECT_THROW(write_file_atomic(dir.string(), bytes), Error);  // a directory as target
  EXPECT_TRUE(temp_leftovers(dir).empty());
  // A folder nobody may create files in, not even root.
  if (fs::is_directory("/proc")) {
    EXPECT_THROW(write_file_atomic("/proc/specula-atomic-test.png", bytes), Error);
    EXPECT_TRUE(temp_leftovers("/proc").empty());
  }
}

TEST(AtomicWrite, UnwritableFolderThrowsAndLeavesNothing) {
  if (::geteuid() == 0) GTEST_SKIP() << "running as root: folder permissions are not enforced";
  const auto dir = test::temp_dir("atomic-ro");
  const fs::path ro = dir / "ro";
  fs::create_directories(ro);
  ::chmod(ro.c_str(), 0555);
  const std::vector<uint8_t> bytes{1, 2, 3};
  EXPECT_THROW(write_file_atomic((ro / "out.png").string(), bytes), Error);
  ::chmod(ro.c_str(), 0755);
  EXPECT_TRUE(fs::is_empty(ro));
}

TEST(AtomicWrite, FailedWriteRemovesTempAndKeepsOldFile) {
  // A file-size limit makes write() fail half way (EFBIG) after the temp file exists:
  // the temp must be removed and the previous file left intact.
  const auto dir = test::temp_dir("atomic-efbig");
  const fs::path p = dir / "out.bin";
  const std::vector<uint8_t> old_bytes{9, 8, 7};
  write_file_atomic(p.string(), old_bytes);
  rlimit saved{};
  ASSERT_EQ(::getrlimit(RLIMIT_FSIZE, &saved), 0);
  auto* const old_handler = ::signal(SIGXFSZ, SIG_IGN);
  rlimit lim = saved;
  lim.rlim_cur = 4096;
  ASSERT_EQ(::setrlimit(RLIMIT_FSIZE, &lim), 0);
  const std::vector<uint8_t> big(1 << 20, 0x55);
  bool threw = false;
  try {
    write_file_atomic(p.string(), big);
  } catch (const Error&) {
    threw = true;
  }
  ::setrlimit(RLIMIT_FSIZE, &saved);
  ::signal(SIGXFSZ, old_handler);
  EXPECT_TRUE(threw);
  EXPECT_EQ(slurp(p), old_bytes);
  EXPECT_TRUE(temp_leftovers(dir).empty());
}

TEST(Aovs, WritesOneFilePerPlaneNextToTheBase) {
  const auto dir = test::temp_dir("aovs");
  Film f;
  f.width = 4;
  f.height = 2;
  f.color.assign(8, Vec3{0.5f});
  f.depth = {1, 2, 3, 4, kInf, 2, 2, 2};
  f.normal.assign(8, Vec3{0, 1, 0});
  f.normal[4] = Vec3{};
  f.prim_id = {0, 1, 2, 3, kNoHit, 5, 5, 5};
  f.cost = {1, 2, 3, 4, 5, 6, 7, 100};
  const auto written = write_aovs((dir / "out.png").string(), f);
  ASSERT_EQ(written.size(), 4u);
  for (const char* n : {"out.depth.png", "out.normal.png", "out.prim.png", "out.cost.png"})
    EXPECT_TRUE(fs::exists(dir / n)) << n;
  int w = 0, h = 0;
  const auto normal = read_image((dir / "out.normal.png").string(), w, h);
  ASSERT_EQ(w, 4);
  // n * 0.5 + 0.5 stored as display values: (0.5, 1, 0.5) -> sRGB-decoded 0.214 / 1.
  EXPECT_NEAR(normal[0].y, 1.0f, 1e-3f);
  EXPECT_NEAR(normal[0].x, srgb_decode_for_test(0.5f), 5e-3f);
  const auto depth = read_image((dir / "out.depth.png").string(), w, h);
  EXPECT_GT(depth[0].x, depth[3].x);  // nearer is brighter
  EXPECT_EQ(depth[4].x, 0.0f);        // miss is black
  const auto prim = read_image((dir / "out.prim.png").string(), w, h);
  EXPECT_EQ(prim[5], prim[6]);        // same id, same colour
  EXPECT_NE(prim[0], prim[1]);
  EXPECT_EQ(prim[4], Vec3{});

  const auto exr = write_aovs((dir / "lin.exr").string(), f);
  ASSERT_EQ(exr.size(), 4u);
  const auto d = read_image((dir / "lin.depth.exr").string(), w, h);
  EXPECT_NEAR(d[2].x, 3.0f, 1e-3f);  // linear values, not a picture
  const auto n = read_image((dir / "lin.normal.exr").string(), w, h);
  EXPECT_NEAR(n[0].y, 1.0f, 1e-3f);
  EXPECT_NEAR(n[0].x, 0.0f, 1e-3f);

  Film none;
  none.width = 4;
  none.height = 2;
  none.color.assign(8, Vec3{});
  EXPECT_TRUE(write_aovs((dir / "none.png").string(), none).empty());
}

TEST(Sky, EquirectangularImageIsSampledByDirection) {
  const auto dir = test::temp_dir("sky");
  // 8x4 image: left half red, right half green; top row blue.
  const int w = 8, h = 4;
  std::vector<Vec3> img(static_cast<size_t>(w * h));
  for (size_t y = 0; y < static_cast<size_t>(h); ++y)
    for (size_t x = 0; x < static_cast<size_t>(w); ++x)
      img[y * static_cast<size_t>(w) + x] = y == 0 ? Vec3{0, 0, 4} : (x < static_cast<size_t>(w) / 2 ? Vec3{2, 0, 0} : Vec3{0, 2, 0});
  write_exr((dir / "sky.exr").string(), w, h, img);
  Scene s;
  s.sky.type = SkyType::Image;
  s.sky.image_path = (dir / "sky.exr").string();
  load_sky_image(s.sky);
  ASSERT_EQ(s.sky.image_width, w);
  ASSERT_EQ(s.sky.image_height, h);
  EXPECT_NEAR(s.sky.image[0].z, 4.0f, 1e-3f);

  // -x maps to the left quarter (red), +x to the right (green), straight up to blue.
  auto render_dir = [&s](Vec3 dir_target) {
    s.cameras.clear();
    Camera c;
    c.position = {0, 0, 0};
    c.target = dir_target;
    c.up = std::fabs(dir_target.y) > 0.9f ? Vec3{0, 0, -1} : Vec3{0, 1, 0};
    c.vfov_degrees = 1.0f;
    s.cameras.push_back(c);
    const std::vector<Vec3> p;
    const std::vector<uint32_t> idx;
    const auto tracer = build_tracer(AccelKind::Brute, TriangleInput{p, idx, {}});
    RenderOptions o;
    o.width = 1;
    o.height = 1;
    o.threads = 1;
    return render_whitted(s, *tracer, o).color[0];
  };
  const Vec3 left = render_dir({-1, -0.2f, 0}), right = render_dir({1, -0.2f, 0}), up = render_dir({0, 1, 0});
  EXPECT_GT(left.x, 1.5f);
  EXPECT_LT(left.y, 0.5f);
  EXPECT_GT(right.y, 1.5f);
  EXPECT_LT(right.x, 0.5f);
  EXPECT_GT(up.z, 3.0f);

  Sky missing;
  missing.type = SkyType::Image;
  missing.image_path = (dir / "nope.hdr").string();
  EXPECT_THROW(load_sky_image(missing), Error);
}

TEST(Sky, RadianceHdrLoadsLinear) {
  // A 4x2 uncompressed Radiance file: top row (2, 0, 0), bottom row (0, 0.5, 0).
  const auto dir = test::temp_dir("hdr");
  const fs::path p = dir / "sky.hdr";
  {
    std::ofstream out(p, std::ios::binary);
    out << "#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y 2 +X 4\n";
    // RGBE: value = byte * 2^(E - 136). 2.0 = 128 * 2^(130-136); 0.5 = 128 * 2^(128-136).
    for (int i = 0; i < 4; ++i) out.write("\x80\x00\x00\x82", 4);
    for (int i = 0; i < 4; ++i) out.write("\x00\x80\x00\x80", 4);
  }
  Sky sky;
  sky.type = SkyType::Image;
  sky.image_path = p.string();
  load_sky_image(sky);
  ASSERT_EQ(sky.image_width, 4);
  ASSERT_EQ(sky.image_height, 2);
  EXPECT_NEAR(sky.image[0].x, 2.0f, 1e-5f);
  EXPECT_NEAR(sky.image[4].y, 0.5f, 1e-5f);
  EXPECT_NEAR(sky.image[4].x, 0.0f, 1e-5f);
  // Not an image sky: nothing happens.
  Sky gradient;
  gradient.image_path = p.string();
  load_sky_image(gradient);
  EXPECT_TRUE(gradient.image.empty());
}
