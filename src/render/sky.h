/// \file sky.h
/// Radiance arriving from the sky for rays that leave the scene (internal to src/render).
#pragma once

#include <algorithm>
#include <cmath>

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
    if (sky_.type == SkyType::Gradient) {
      // Horizon colour at and below the horizon, blending to the zenith colour; the square
      // root keeps a visible horizon band instead of a linear ramp.
      const float t = std::sqrt(std::clamp(normalize(dir).y, 0.0f, 1.0f));
      return lerp(sky_.horizon, sky_.color, t) * sky_.intensity;
    }
    return image_radiance(dir);
  }

 private:
  Vec3 image_radiance(const Vec3& dir) const;
  const Sky& sky_;
};

}  // namespace specula
