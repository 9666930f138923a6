/// \file sky.h
/// Radiance arriving from the sky for rays that leave the scene (internal to src/render).
#pragma once

#include <algorithm>
#include <cmath>
#include <cstring>

#include "render/lanes.h"
#include "specula/math.h"
#include "specula/scene.h"

namespace specula {

/// Evaluates a Sky for unit (or any non-zero) directions. Equirectangular images map
/// direction -z to the image centre, +x to three quarters of the width, +y to the top row.
class SkyEval {
 public:
  explicit SkyEval(const Sky& sky) : sky_(sky) {}
  /// Constant and gradient skies inline (the integrator calls this for every ray that leaves
  /// the scene), images out of line.
  Vec3 radiance(const Vec3& dir) const {
    if (sky_.type == SkyType::Constant) return sky_.color * sky_.intensity;
    if (sky_.type == SkyType::Gradient) return gradient_radiance(gradient_t(dir));
    return image_radiance(dir);
  }

  /// Whether this is a gradient sky, whose radiance() the integrator computes in two steps for
  /// blocks of directions: gradient_radiance(gradient_t(dir)) is radiance(dir).
  bool gradient() const { return sky_.type == SkyType::Gradient; }
  /// The gradient's blend from the horizon colour (at and below the horizon) to the zenith
  /// colour for direction \p dir; the square root keeps a visible horizon band instead of a
  /// linear ramp.
  static float gradient_t(const Vec3& dir) { return std::sqrt(std::clamp(normalize(dir).y, 0.0f, 1.0f)); }
  Vec3 gradient_radiance(float t) const { return lerp(sky_.horizon, sky_.color, t) * sky_.intensity; }

 private:
  Vec3 image_radiance(const Vec3& dir) const;
  const Sky& sky_;
};

namespace render {

/// Rows of a block of gradient-sky directions (x, y, z; then gradient_t_block()'s t), stored
/// block by block: row r of direction i at block_offset<kSkyRows>(r, i).
inline constexpr int kSkyRows = 4;

/// SkyEval::gradient_t() for one block of kBlock directions (\p block points at its row 0):
/// writes row 3. Lane by lane the same normalisation, clamp and square root, so the same bits
/// (tests/lighting_test.cpp).
inline void gradient_t_block(float* block) {
  using namespace lanes;
  Fv dx = load(block), dy = load(block + kBlock), dz = load(block + 2 * kBlock);
  normalize_lanes(dx, dy, dz);
  const Fv t = sqrt_lanes(clamp_lanes(dy, splat(0.0f), splat(1.0f)));
  std::memcpy(block + 3 * kBlock, &t, sizeof t);
}

}  // namespace render
}  // namespace specula
