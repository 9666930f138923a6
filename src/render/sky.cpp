// Sky radiance: constant, vertical gradient (inline in sky.h), equirectangular image (owner:
// render).
#include "render/sky.h"

#include <algorithm>
#include <cmath>

namespace specula {

Vec3 SkyEval::image_radiance(const Vec3& dir) const {
  // radiance() answers the constant and gradient skies itself.
  const int w = sky_.image_width, h = sky_.image_height;
  if (sky_.type != SkyType::Image || w <= 0 || h <= 0 ||
      sky_.image.size() < static_cast<size_t>(w) * static_cast<size_t>(h))
    return sky_.color * sky_.intensity;  // image not loaded: behave like a constant sky
  const Vec3 d = normalize(dir);
  const float u = 0.5f + std::atan2(d.x, -d.z) * (0.5f / kPi);
  const float v = std::acos(std::clamp(d.y, -1.0f, 1.0f)) / kPi;
  // Bilinear lookup, wrapping horizontally and clamping vertically.
  const float fx = u * static_cast<float>(w) - 0.5f, fy = v * static_cast<float>(h) - 0.5f;
  const float x0f = std::floor(fx), y0f = std::floor(fy);
  const float ax = fx - x0f, ay = fy - y0f;
  auto wrap_x = [w](long x) { return static_cast<size_t>(((x % w) + w) % w); };
  auto clamp_y = [h](long y) { return static_cast<size_t>(std::clamp<long>(y, 0, h - 1)); };
  const long xi = static_cast<long>(x0f), yi = static_cast<long>(y0f);
  const size_t xa = wrap_x(xi), xb = wrap_x(xi + 1), ya = clamp_y(yi), yb = clamp_y(yi + 1);
  const size_t sw = static_cast<size_t>(w);
  const Vec3 top = lerp(sky_.image[ya * sw + xa], sky_.image[ya * sw + xb], ax);
  const Vec3 bottom = lerp(sky_.image[yb * sw + xa], sky_.image[yb * sw + xb], ax);
  return lerp(top, bottom, ay) * sky_.intensity;
}

}  // namespace specula
