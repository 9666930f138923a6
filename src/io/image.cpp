// PNG / EXR output, image input and sky loading (owner: render).
// stb_image(_write) and tinyexr come as prebuilt libraries (Debian's libstb.so and
// libtinyexr.so), so only their declarations are included here.
#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <string>
#include <vector>

#pragma GCC diagnostic push
#pragma GCC diagnostic ignored "-Wconversion"
#pragma GCC diagnostic ignored "-Wshadow"
#pragma GCC diagnostic ignored "-Wunused-parameter"
#pragma GCC diagnostic ignored "-Wsign-compare"
#include <stb_image.h>
#include <stb_image_write.h>
#include <tinyexr.h>
#pragma GCC diagnostic pop

#include "io/image_util.h"
#include "specula/error.h"
#include "specula/image.h"

namespace specula {

namespace fs = std::filesystem;

namespace {

std::string lower_extension(const std::string& path) {
  std::string ext = fs::path(path).extension().string();
  for (char& c : ext) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
  return ext;
}

void check_size(const std::string& path, int width, int height, size_t pixels) {
  if (width <= 0 || height <= 0)
    throw file_error(path, "invalid image size " + std::to_string(width) + "x" + std::to_string(height));
  if (pixels != static_cast<size_t>(width) * static_cast<size_t>(height))
    throw file_error(path, "pixel count " + std::to_string(pixels) + " does not match " +
                               std::to_string(width) + "x" + std::to_string(height));
}

void append_bytes(void* context, void* data, int size) {
  auto* out = static_cast<std::vector<uint8_t>*>(context);
  const auto* p = static_cast<const uint8_t*>(data);
  out->insert(out->end(), p, p + size);
}

}  // namespace

float linear_to_srgb(float c) {
  if (!(c > 0.0f)) return 0.0f;  // also maps NaN to 0
  if (c >= 1.0f) return 1.0f;
  return c <= 0.0031308f ? 12.92f * c : 1.055f * std::pow(c, 1.0f / 2.4f) - 0.055f;
}

float srgb_to_linear(float c) {
  return c <= 0.04045f ? c / 12.92f : std::pow((c + 0.055f) / 1.055f, 2.4f);
}

std::vector<uint8_t> to_srgb8(std::span<const Vec3> linear_rgb, Tonemap tonemap) {
  std::vector<uint8_t> px(linear_rgb.size() * 3);
  for (size_t i = 0; i < linear_rgb.size(); ++i) {
    for (int c = 0; c < 3; ++c) {
      float v = linear_rgb[i][c];
      if (std::isnan(v)) v = 0.0f;
      if (tonemap == Tonemap::Reinhard && v > 0.0f) v = std::isinf(v) ? 1.0f : v / (1.0f + v);
      px[3 * i + static_cast<size_t>(c)] = static_cast<uint8_t>(std::lround(linear_to_srgb(v) * 255.0f));
    }
  }
  return px;
}

std::vector<uint8_t> encode_png_srgb8(int width, int height, std::span<const uint8_t> rgb8) {
  std::vector<uint8_t> bytes;
  const int ok = stbi_write_png_to_func(append_bytes, &bytes, width, height, 3, rgb8.data(), width * 3);
  if (!ok) throw Error("PNG encoding failed");
  return bytes;
}

void write_png(const std::string& path, int width, int height, std::span<const Vec3> linear_rgb,
               Tonemap tonemap) {
  check_size(path, width, height, linear_rgb.size());
  const std::vector<uint8_t> px = to_srgb8(linear_rgb, tonemap);
  write_file_atomic(path, encode_png_srgb8(width, height, px));
}

std::vector<uint8_t> encode_exr(int width, int height, std::span<const Vec3> linear_rgb) {
  // Planar channels in the B, G, R order most EXR readers expect; float in, half stored.
  const size_t n = linear_rgb.size();
  std::vector<float> planes[3];
  for (auto& p : planes) p.resize(n);
  for (size_t i = 0; i < n; ++i) {
    planes[0][i] = linear_rgb[i].z;
    planes[1][i] = linear_rgb[i].y;
    planes[2][i] = linear_rgb[i].x;
  }
  unsigned char* image_ptrs[3] = {reinterpret_cast<unsigned char*>(planes[0].data()),
                                  reinterpret_cast<unsigned char*>(planes[1].data()),
                                  reinterpret_cast<unsigned char*>(planes[2].data())};
  EXRImage image;
  InitEXRImage(&image);
  image.num_channels = 3;
  image.images = image_ptrs;
  image.width = width;
  image.height = height;

  EXRHeader header;
  InitEXRHeader(&header);
  EXRChannelInfo channels[3];
  std::memset(channels, 0, sizeof channels);
  std::strcpy(channels[0].name, "B");
  std::strcpy(channels[1].name, "G");
  std::strcpy(channels[2].name, "R");
  int pixel_types[3] = {TINYEXR_PIXELTYPE_FLOAT, TINYEXR_PIXELTYPE_FLOAT, TINYEXR_PIXELTYPE_FLOAT};
  int requested[3] = {TINYEXR_PIXELTYPE_HALF, TINYEXR_PIXELTYPE_HALF, TINYEXR_PIXELTYPE_HALF};
  header.num_channels = 3;
  header.channels = channels;
  header.pixel_types = pixel_types;
  header.requested_pixel_types = requested;
  header.compression_type = TINYEXR_COMPRESSIONTYPE_ZIP;

  unsigned char* mem = nullptr;
  const char* err = nullptr;
  size_t size = SaveEXRImageToMemory(&image, &header, &mem, &err);
  if (size == 0) {  // retry uncompressed in case this tinyexr build lacks zlib
    if (err) FreeEXRErrorMessage(err);
    err = nullptr;
    header.compression_type = TINYEXR_COMPRESSIONTYPE_NONE;
    size = SaveEXRImageToMemory(&image, &header, &mem, &err);
  }
  if (size == 0) {
    const std::string msg = err ? err : "unknown error";
    if (err) FreeEXRErrorMessage(err);
    throw Error("EXR encoding failed: " + msg);
  }
  std::vector<uint8_t> bytes(mem, mem + size);
  std::free(mem);
  return bytes;
}

void write_exr(const std::string& path, int width, int height, std::span<const Vec3> linear_rgb) {
  check_size(path, width, height, linear_rgb.size());
  std::vector<uint8_t> bytes;
  try {
    bytes = encode_exr(width, height, linear_rgb);
  } catch (const Error& e) {
    throw file_error(path, e.what());
  }
  write_file_atomic(path, bytes);
}

void write_image(const std::string& path, int width, int height, std::span<const Vec3> linear_rgb,
                 Tonemap tonemap) {
  const std::string ext = lower_extension(path);
  if (ext == ".png") return write_png(path, width, height, linear_rgb, tonemap);
  if (ext == ".exr") return write_exr(path, width, height, linear_rgb);
  throw file_error(path, "unsupported image format '" + ext + "' (use .png or .exr)");
}

std::vector<Vec3> read_image(const std::string& path, int& width, int& height) {
  if (!fs::exists(path)) throw file_error(path, "no such file");
  const std::string ext = lower_extension(path);
  std::vector<Vec3> out;
  if (ext == ".exr") {
    float* rgba = nullptr;
    const char* err = nullptr;
    if (LoadEXR(&rgba, &width, &height, path.c_str(), &err) != TINYEXR_SUCCESS) {
      const std::string msg = err ? err : "unknown error";
      if (err) FreeEXRErrorMessage(err);
      throw file_error(path, "cannot read EXR: " + msg);
    }
    const size_t n = static_cast<size_t>(width) * static_cast<size_t>(height);
    out.resize(n);
    for (size_t i = 0; i < n; ++i) out[i] = {rgba[4 * i], rgba[4 * i + 1], rgba[4 * i + 2]};
    std::free(rgba);
    return out;
  }
  int channels = 0;
  if (stbi_is_hdr(path.c_str())) {  // Radiance .hdr: already linear
    float* data = stbi_loadf(path.c_str(), &width, &height, &channels, 3);
    if (!data) throw file_error(path, std::string("cannot read image: ") + stbi_failure_reason());
    const size_t n = static_cast<size_t>(width) * static_cast<size_t>(height);
    out.resize(n);
    for (size_t i = 0; i < n; ++i) out[i] = {data[3 * i], data[3 * i + 1], data[3 * i + 2]};
    stbi_image_free(data);
    return out;
  }
  unsigned char* data = stbi_load(path.c_str(), &width, &height, &channels, 3);
  if (!data) throw file_error(path, std::string("cannot read image: ") + stbi_failure_reason());
  float lut[256];
  for (int i = 0; i < 256; ++i) lut[i] = srgb_to_linear(static_cast<float>(i) / 255.0f);
  const size_t n = static_cast<size_t>(width) * static_cast<size_t>(height);
  out.resize(n);
  for (size_t i = 0; i < n; ++i) out[i] = {lut[data[3 * i]], lut[data[3 * i + 1]], lut[data[3 * i + 2]]};
  stbi_image_free(data);
  return out;
}

void load_sky_image(Sky& sky) {
  if (sky.type != SkyType::Image) return;
  if (sky.image_path.empty()) throw Error("sky: type is image but no image path is given");
  int w = 0, h = 0;
  std::vector<Vec3> img = read_image(sky.image_path, w, h);
  for (Vec3& c : img)
    if (!is_finite(c)) c = Vec3{};
  sky.image = std::move(img);
  sky.image_width = w;
  sky.image_height = h;
}

}  // namespace specula
