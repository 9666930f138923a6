/// \file sky.h
/// Radiance arriving from the sky for rays that leave the scene (internal to src/render).
#pragma once

#include "specula/math.h"
#include "specula/scene.h"

namespace specula {

/// Evaluates a Sky for unit (or any non-zero) directions. Equirectangular images map
/// direction -z to the image centre, +x to three quarters of the width, +y to the top row.
class SkyEval {
 public:
  explicit SkyEval(const Sky& sky) : sky_(sky) {}
  Vec3 radiance(const Vec3& dir) const;

 private:
  const Sky& sky_;
};

}  // namespace specula
