/// \file image_util.h
/// Pixel conversions and in-memory encoders shared by src/io (internal).
#pragma once

#include <cstdint>
#include <span>
#include <vector>

#include "specula/image.h"
#include "specula/math.h"

namespace specula {

/// sRGB transfer function (IEC 61966-2-1); clamps to [0, 1], NaN -> 0.
float linear_to_srgb(float c);
float srgb_to_linear(float c);
/// Linear RGB -> interleaved 8-bit sRGB (tonemapped first when asked).
std::vector<uint8_t> to_srgb8(std::span<const Vec3> linear_rgb, Tonemap tonemap);
/// Encodes interleaved 8-bit RGB as PNG in memory.
std::vector<uint8_t> encode_png_srgb8(int width, int height, std::span<const uint8_t> rgb8);
/// Encodes linear RGB as a half-float EXR in memory.
std::vector<uint8_t> encode_exr(int width, int height, std::span<const Vec3> linear_rgb);

}  // namespace specula
